"""A free ROS_DOMAIN_ID on this machine, so that two runs (two demos) never mix their topics.

A domain is free when

- no other run of this picker holds its lock file (``/tmp/ekf_localization-domain-<id>.lock``,
  an ``flock`` held for the life of the process and released by the kernel when it exits, even
  on a crash), and
- no DDS participant on this machine has bound one of the domain's UDP ports (RTPS port
  mapping: ``7400 + 250 * id`` up to ``+ 250``; Fast DDS and Cyclone DDS both use it), read
  from ``/proc/net/udp`` and ``/proc/net/udp6``. That also avoids the ids that ``ros2`` tools,
  tests or other programs use at the moment.

Ids 1..101 (ROS 2's advice for Linux) keep a domain's ports below Linux's ephemeral range
(32768), where no other program's sockets can be mistaken for a participant.
``EKF_DEMO_DOMAINS=LO:HI`` narrows the range.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

PORT_BASE = 7400
DOMAIN_GAIN = 250
DEFAULT_RANGE = (1, 101)
RANGE_ENV = "EKF_DEMO_DOMAINS"


def domain_ports(domain: int) -> range:
    """The UDP ports the RTPS port mapping gives domain ``domain`` (every participant's)."""
    start = PORT_BASE + DOMAIN_GAIN * domain
    return range(start, start + DOMAIN_GAIN)


def bound_udp_ports(tables: Iterable[str] = ("/proc/net/udp", "/proc/net/udp6")) -> set[int]:
    """Local ports of this network namespace's UDP sockets (empty where /proc is not Linux's)."""
    ports: set[int] = set()
    for table in tables:
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) > 1 and ":" in fields[1]:
                ports.add(int(fields[1].rsplit(":", 1)[1], 16))
    return ports


def domain_in_use(domain: int, ports: set[int]) -> bool:
    """Whether some participant on this machine has bound a port of ``domain``."""
    r = domain_ports(domain)
    return any(p in r for p in ports)


def lock_path(domain: int, lock_dir: Path | None = None) -> Path:
    return Path(lock_dir or tempfile.gettempdir()) / f"ekf_localization-domain-{domain}.lock"


def try_lock(domain: int, lock_dir: Path | None = None) -> int | None:
    """An fd holding ``domain``'s lock (kept open for the life of the run), or None if taken."""
    path = lock_path(domain, lock_dir)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CREAT, 0o644)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def domain_range(env: dict[str, str] | None = None) -> tuple[int, int]:
    """The inclusive id range to pick from: ``EKF_DEMO_DOMAINS=LO:HI`` or 1..101."""
    spec = (os.environ if env is None else env).get(RANGE_ENV, "")
    if not spec:
        return DEFAULT_RANGE
    try:
        lo, hi = (int(v) for v in spec.split(":"))
    except ValueError:
        raise ValueError(f"{RANGE_ENV}={spec!r}: expected LO:HI, e.g. 26:40") from None
    if not 0 <= lo <= hi <= 232:
        raise ValueError(f"{RANGE_ENV}={spec!r}: need 0 <= LO <= HI <= 232")
    return lo, hi


def pick_free_domain(lo: int, hi: int, lock_dir: Path | None = None,
                     scan: Callable[[], set[int]] = bound_udp_ports) -> tuple[int, int]:
    """The first id in ``lo..hi`` that is free, and the fd of its lock (keep it open).
    ``scan`` returns the bound UDP ports (bound_udp_ports; tests pass their own).

    Raises RuntimeError when every id of the range is taken."""
    ports = scan()
    for domain in range(lo, hi + 1):
        if domain_in_use(domain, ports):
            continue
        fd = try_lock(domain, lock_dir)
        if fd is None:
            continue
        # A participant may have started between the port scan and the lock: look again.
        if domain_in_use(domain, scan()):
            os.close(fd)
            continue
        return domain, fd
    raise RuntimeError(f"no free ROS_DOMAIN_ID in {lo}..{hi} (each has DDS participants or another "
                       f"run's lock); set ROS_DOMAIN_ID yourself or {RANGE_ENV}=LO:HI")
