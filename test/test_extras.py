"""Without an optional extra (aiohttp, rosbags, pyntcore), the tools that need it say in one line what to
install and exit 2; the modules still import (the nodes never need them)."""

from __future__ import annotations

import subprocess
import sys

import pytest
from helpers.ros_helpers import REPO

from ekf_localization.ros import extras

# console script module, its arguments, the extra it needs
TOOLS = [
    ("ekf_localization.tools.field_view", ["field_view"], "aiohttp"),
    ("ekf_localization.tools.bag_recorder", ["bag_recorder", "-o", "x"], "rosbags"),
    ("ekf_localization.tools.bag_replay", ["no_such_bag"], "rosbags"),
    ("ekf_localization.tools.ekf_tune", ["no_such_bag", "--params", "p.yaml", "--out", "o"], "rosbags"),
    ("sim_robot.ros.sim_bag", ["out"], "rosbags"),
    ("ekf_localization.tools.demo", [], "rosbags"),
    ("ekf_localization.nodes.nt_bridge_node", [], "ntcore"),
]


def _run_without(module: str, argv: list[str], extra: str) -> subprocess.CompletedProcess:
    code = (f"import sys; sys.modules[{extra!r}] = None\n"  # import {extra} now raises ImportError
            f"from {module} import main\n"
            f"sys.exit(main({argv!r}))")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          cwd=str(REPO))


@pytest.mark.parametrize(("module", "argv", "extra"), TOOLS, ids=[t[0].rsplit(".", 1)[1] for t in TOOLS])
def test_a_tool_without_its_extra_says_what_to_install(module: str, argv: list[str], extra: str) -> None:
    res = _run_without(module, argv, extra)
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert f"'{extra}'" in lines[0] and "install" in lines[0], lines[0]


def test_the_hints_name_the_rosdep_key_or_pip() -> None:
    assert "python3-aiohttp" in extras.install_hint("field_view", "aiohttp")
    assert "pip install rosbags" in extras.install_hint("bag_replay", "rosbags")
    assert "pip install pyntcore" in extras.install_hint("nt_bridge", "ntcore")
    assert not extras.missing("yaml") and extras.missing("no_such_module_here")
