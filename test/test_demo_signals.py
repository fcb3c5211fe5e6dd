"""ekf_demo stopped by a signal: a clean message and exit, its node processes stopped, no traceback.

With rclpy's own SIGINT/SIGTERM handler the context was shut down under the demo's loop, which then
raised from ``spin_once`` and again from ``rclpy.shutdown()``; the demo now stops the way every node
does (ros/node_runner.init_rclpy: the signal ends the loop, then the nodes stop and the bag closes).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers.launch_runner import alive
from helpers.ros_helpers import REPO, allocate_domain

pytestmark = pytest.mark.ros


def _children(pid: int) -> list[int]:
    """PIDs whose parent is ``pid`` (Linux /proc)."""
    kids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid:
            kids.append(int(stat.parent.name))
    return kids


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_signal_stops_the_demo_cleanly(tmp_path, sig):
    cmd = [sys.executable, "-m", "ekf_localization.tools.demo", "--out", str(tmp_path), "--timeout", "60"]
    env = dict(os.environ, ROS_DOMAIN_ID=str(allocate_domain()), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, env=env)
    lines = []
    try:
        for line in proc.stdout:  # the demo prints a progress line each second
            lines.append(line)
            if "along path" in line:  # the nodes run and the recorder records
                break
        nodes = _children(proc.pid)
        assert len(nodes) >= 3, "".join(lines)  # sim_node, ekf_node, pure_pursuit_node
        proc.send_signal(sig)
        rest, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    out = "".join(lines) + rest
    assert "Traceback" not in out + err, out[-3000:] + err[-3000:]
    assert "ekf_demo: interrupted after" in out, out[-3000:] + err[-3000:]
    assert proc.returncode == 1, (proc.returncode, err[-3000:])
    deadline = time.monotonic() + 5.0
    while any(alive(p) for p in nodes) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [p for p in nodes if alive(p)], "node processes outlived the demo"
