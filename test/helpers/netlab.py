"""Hosts on one machine: network namespaces joined by veth pairs to a switch namespace.

Each host namespace has ``lo`` and ``eth0`` (one end of a veth pair, a 10.213.0.0/24 address,
no default route); the other end sits in the switch namespace, where :mod:`helpers.netswitch`
forwards frames between the ports (with seeded delay, jitter and loss on demand). Nothing is
created in the caller's namespace, and no address or route leads out of the machine.
Namespaces are named ``ekfmh-<pid>-<host>``; :meth:`NetLab.close` removes them (and with
them every veth), and a new lab first removes those of processes that are gone.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

PREFIX = "ekfmh-"
SUBNET = "10.213.0"
SWITCH = Path(__file__).with_name("netswitch.py")


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10, check=check)


def unavailable_reason() -> str | None:
    """Why network namespaces cannot be used here (None: they can)."""
    if not sys.platform.startswith("linux"):
        return "network namespaces need Linux"
    if os.geteuid() != 0:
        return "network namespaces need root (ip netns add)"
    if shutil.which("ip") is None:
        return "'ip' not found (install iproute2)"
    probe = f"{PREFIX}{os.getpid()}-probe"
    res = _ip("netns", "add", probe, check=False)
    if res.returncode != 0:
        return f"ip netns add failed: {res.stderr.strip()}"
    try:
        res = _ip("link", "add", "v0", "netns", probe, "type", "veth", "peer", "name", "v1", "netns", probe,
                  check=False)
        if res.returncode != 0:
            return f"veth pairs unavailable: {res.stderr.strip()}"
    finally:
        _ip("netns", "del", probe, check=False)
    return None


def remove_stale() -> None:
    """Delete the namespaces of labs whose process has exited (a killed test run)."""
    res = _ip("netns", "list", check=False)
    for line in res.stdout.splitlines():
        name = line.split()[0] if line.split() else ""
        if not name.startswith(PREFIX):
            continue
        pid = name[len(PREFIX):].split("-")[0]
        if pid.isdigit() and not Path(f"/proc/{pid}").exists():
            _ip("netns", "del", name, check=False)


class NetLab:
    """Host namespaces ``hosts`` on one switch; ``close()`` removes everything."""

    def __init__(self, hosts: list[str], log_dir: Path, seed: int = 0) -> None:
        remove_stale()
        self.hosts = list(hosts)
        self.ns = {h: f"{PREFIX}{os.getpid()}-{h}" for h in hosts}
        self.switch_ns = f"{PREFIX}{os.getpid()}-switch"
        self.address = {h: f"{SUBNET}.{i + 1}" for i, h in enumerate(hosts)}
        self.port = {h: f"p-{h}"[:15] for h in hosts}
        self._made: list[str] = []
        self._switch: subprocess.Popen | None = None
        try:
            self._add_ns(self.switch_ns)
            for h in hosts:
                ns = self.ns[h]
                self._add_ns(ns)
                _ip("link", "add", "eth0", "netns", ns, "type", "veth", "peer", "name", self.port[h],
                    "netns", self.switch_ns)
                _ip("-n", ns, "addr", "add", f"{self.address[h]}/24", "dev", "eth0")
                _ip("-n", ns, "link", "set", "eth0", "up")
                subprocess.run(self.command(h, [sys.executable, str(SWITCH), "--tx-checksum-off", "eth0"]),
                               check=True, timeout=30)
                _ip("-n", self.switch_ns, "link", "set", self.port[h], "up")
            self._switch_log = open(log_dir / "switch.log", "w")  # noqa: SIM115 (closed in close())
            self._switch = subprocess.Popen(
                ["ip", "netns", "exec", self.switch_ns, sys.executable, str(SWITCH), "--seed", str(seed),
                 *self.port.values()],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._switch_log, text=True)
            ready = self._switch.stdout.readline().strip()
            if ready != "ready":
                raise RuntimeError(f"switch did not start: {ready!r} ({log_dir / 'switch.log'})")
        except BaseException:
            self.close()
            raise

    def _add_ns(self, name: str) -> None:
        _ip("netns", "add", name)
        self._made.append(name)
        _ip("-n", name, "link", "set", "lo", "up")

    def command(self, host: str, cmd: list[str]) -> list[str]:
        """``cmd`` run inside ``host``'s namespace."""
        return ["ip", "netns", "exec", self.ns[host], *cmd]

    def static_peers(self, host: str) -> str:
        """ROS_STATIC_PEERS for ``host``: every other host's address."""
        return ";".join(a for h, a in self.address.items() if h != host)

    def routes(self, host: str) -> list[str]:
        """``ip route`` of ``host`` (IPv4 and IPv6), one route a line."""
        out = _ip("-n", self.ns[host], "route", "show").stdout + _ip("-n", self.ns[host], "-6", "route",
                                                                         "show").stdout
        return [line for line in out.splitlines() if line.strip()]

    def set_link(self, host: str, up: bool) -> None:
        """Bring ``host``'s eth0 up or down (a pulled cable)."""
        _ip("-n", self.ns[host], "link", "set", "eth0", "up" if up else "down")

    def _tell(self, line: str) -> str:
        assert self._switch is not None and self._switch.stdin is not None and self._switch.stdout is not None
        self._switch.stdin.write(line + "\n")
        self._switch.stdin.flush()
        out = self._switch.stdout.readline().strip()
        if out != "ok" and line != "stats":
            raise RuntimeError(f"switch: {line!r} -> {out!r}")
        return out

    def impair(self, delay_s: float, jitter_s: float, loss: float, hosts: list[str]) -> None:
        """Frames leaving ``hosts``: delay +- jitter (uniform), lost with probability ``loss``."""
        self._tell(f"impair {delay_s} {jitter_s} {loss} " + " ".join(self.port[h] for h in hosts))

    def stats(self) -> str:
        """The switch's per-port counters (a JSON line)."""
        out = self._tell("stats")
        assert self._switch is not None and self._switch.stdout is not None
        self._switch.stdout.readline()  # ok
        return out

    def close(self) -> None:
        """Stop the switch and delete every namespace made (their veths go with them)."""
        if self._switch is not None:
            try:
                self._switch.stdin.close()
                self._switch.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired):
                self._switch.kill()
                self._switch.wait(timeout=5)
            self._switch_log.close()
            self._switch = None
        for name in reversed(self._made):
            _ip("netns", "del", name, check=False)
        self._made.clear()
