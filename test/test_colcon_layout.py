"""`colcon build` of this package lays out what `ros2 run` / `ros2 launch` rely on."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.ros_helpers import REPO, spin_until

EXECUTABLES = ["ekf_node", "sim_node", "pure_pursuit_node", "bag_recorder", "bag_replay",
               "ekf_demo", "ekf_experiments", "field_view"]
SKIP_DIRS = {".venv", ".git", "build", "install", "log", "output", "__pycache__", ".pytest_cache",
             ".ruff_cache"}


def _copy_package(dst: Path) -> None:
    def ignore(_dir: str, names: list[str]) -> set[str]:
        return {n for n in names if n in SKIP_DIRS or n.endswith(".egg-info")}

    shutil.copytree(REPO, dst, ignore=ignore)


@pytest.fixture(scope="module")
def colcon_ws(tmp_path_factory) -> Path:
    colcon = shutil.which("colcon")
    if colcon is None:
        pytest.skip("colcon not installed (scripts/setup_env.sh installs it)")
    ws = tmp_path_factory.mktemp("colcon_ws")
    _copy_package(ws / "src" / "ekf_localization")
    env = dict(os.environ, AMENT_PREFIX_PATH=sys.prefix)
    res = subprocess.run([colcon, "build", "--event-handlers", "console_direct-"], cwd=ws, env=env,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    return ws


def test_colcon_lists_ament_python(colcon_ws: Path) -> None:
    res = subprocess.run([shutil.which("colcon"), "list"], cwd=colcon_ws, capture_output=True,
                         text=True, timeout=60, check=True)
    fields = res.stdout.split()
    assert fields[0] == "ekf_localization"
    # interfaces/tf2_msgs (COLCON_IGNORE) must never shadow the system tf2_msgs
    assert len(res.stdout.splitlines()) == 1
    assert "(ros.ament_python)" in fields


def test_install_layout(colcon_ws: Path) -> None:
    prefix = colcon_ws / "install" / "ekf_localization"
    for exe in EXECUTABLES:
        path = prefix / "lib" / "ekf_localization" / exe
        assert path.is_file() and os.access(path, os.X_OK), f"missing executable {path}"
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "ekf_localization").is_file()
    share = prefix / "share" / "ekf_localization"
    assert (share / "package.xml").is_file()
    configs = sorted(p.name for p in (REPO / "config").iterdir() if p.suffix in (".yaml", ".rviz", ".json"))
    assert configs, "no config YAMLs in the repo"
    for name in configs:
        assert (share / "config" / name).is_file(), f"config/{name} not installed"
    for p in (REPO / "config" / "paths").glob("*.yaml"):
        assert (share / "config" / "paths" / p.name).is_file(), f"config/paths/{p.name} not installed"
    for p in (REPO / "launch").glob("*.py"):
        assert (share / "launch" / p.name).is_file(), f"launch/{p.name} not installed"
    # field_view's page: in the share directory and next to the installed package (package data)
    web = sorted(p.name for p in (REPO / "ekf_localization" / "web").iterdir())
    assert web == ["field_view.css", "field_view.js", "index.html"]
    installed = list(prefix.glob("lib/python*/site-packages/ekf_localization/web"))
    assert len(installed) == 1, "ekf_localization/web not installed with the package"
    for name in web:
        assert (share / "web" / name).is_file(), f"web/{name} not in share/"
        assert (installed[0] / name).is_file(), f"web/{name} not installed with the package"


@pytest.mark.ros
def test_installed_executable_comes_up(colcon_ws: Path, ros_context, tmp_path: Path) -> None:
    """Source the workspace, start the installed ekf_node with its installed YAML, see it advertise."""
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    share = colcon_ws / "install" / "ekf_localization" / "share" / "ekf_localization"
    script = (f"source '{colcon_ws}/install/setup.bash' && "
              "python -c 'import ekf_localization, sys; print(ekf_localization.__file__)' && "
              f"exec ekf_node --ros-args --params-file '{share}/config/ekf.yaml'")
    node = Node("colcon_probe", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    got: list[Odometry] = []
    sub = node.create_subscription(Odometry, "/odometry/filtered", got.append, 10)
    log = tmp_path / "ekf_node.log"
    env = dict(os.environ, AMENT_PREFIX_PATH=sys.prefix,
               PATH=f"{colcon_ws}/install/ekf_localization/lib/ekf_localization:{os.environ['PATH']}")
    with open(log, "w") as fh:
        proc = subprocess.Popen(["bash", "-c", script], stdout=fh, stderr=subprocess.STDOUT, env=env,
                                cwd=tmp_path)
        try:
            # a fresh install starts in about a second (plain numpy, nothing to compile); the bound
            # leaves room for a loaded machine
            assert spin_until(ex, lambda: sub.get_publisher_count() >= 1 or proc.poll() is not None,
                              timeout=60.0), log.read_text()
            assert proc.poll() is None, log.read_text()
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
    first_line = log.read_text().splitlines()[0]
    assert str(colcon_ws / "install") in first_line, "imported the package from outside the install space"
    ex.shutdown()
    node.destroy_node()
