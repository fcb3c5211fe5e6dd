"""Run one of the package's launch files as ``ros2 launch`` does, with Jazzy's real ``launch``.

    python test/helpers/launch_runner.py PREFIX LAUNCH_FILE [name:=value ...]

PREFIX is an install prefix laid out by :func:`layout_prefix` (put first on AMENT_PREFIX_PATH, so
launch_ros finds ``lib/ekf_localization/<executable>`` and the share directory). ``launch`` and
``launch_ros`` are the system's on a ROS 2 install, else the sources vendored at
``<repo>/../shared/vendor/ros2_launch`` (:func:`launch_problem` says why neither can be used).
SIGINT stops the launch and its nodes, as Ctrl-C stops ``ros2 launch``.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
VENDORED = REPO.parent / "shared" / "vendor" / "ros2_launch"
EXECUTABLES = ("ekf_node", "sim_node", "pure_pursuit_node", "tag_localizer")
STARTED = re.compile(r"\[INFO\] \[(\w+)-\d+\]: process started with pid \[(\d+)\]")


def _system_launch() -> bool:
    """Whether a real ``launch`` + ``launch_ros`` is importable (not the repo's launch/ folder)."""
    spec = importlib.util.find_spec("launch")
    return spec is not None and spec.origin is not None and importlib.util.find_spec("launch_ros") is not None


def launch_path() -> list[str]:
    """What to append to sys.path / PYTHONPATH for ``launch`` and ``launch_ros``."""
    return [] if _system_launch() else [str(VENDORED)]


def launch_problem() -> str | None:
    """Why no launch file can be run here (a skip reason), or None."""
    if not _system_launch() and not (VENDORED / "launch_ros").is_dir():
        return (f"no ROS 2 'launch'/'launch_ros' here and no vendored copy at {VENDORED} (Jazzy's "
                "sources are kept there on the development machines and in CI; on a ROS 2 install the "
                "system's are used)")
    missing = [m for m in ("osrf_pycommon", "lark", "yaml") if importlib.util.find_spec(m) is None]
    if missing:
        return f"launch needs {', '.join(missing)}: pip install -r requirements.txt (osrf-pycommon, lark)"
    return None


def layout_prefix(prefix: Path) -> Path:
    """An install prefix with this checkout as package ekf_localization (what colcon installs, as links)."""
    share = prefix / "share" / "ekf_localization"
    share.mkdir(parents=True)
    for name in ("config", "launch", "package.xml"):
        (share / name).symlink_to(REPO / name)
    index = prefix / "share" / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True)
    (index / "ekf_localization").write_text("")
    lib = prefix / "lib" / "ekf_localization"
    lib.mkdir(parents=True)
    for exe in EXECUTABLES:
        found = shutil.which(exe)
        if found:
            (lib / exe).symlink_to(found)
        else:  # no console script: run the module with this interpreter
            module = {"ekf_node": "ekf_localization.nodes.ekf_node", "sim_node": "sim_robot.ros.sim_node",
                      "pure_pursuit_node": "ekf_localization.nodes.pure_pursuit_node",
                      "tag_localizer": "ekf_localization.nodes.tag_localizer_node"}[exe]
            (lib / exe).write_text(f"#!/bin/sh\nexec {sys.executable} -m {module} \"$@\"\n")
            (lib / exe).chmod(0o755)
    return prefix


def runner_env(prefix: Path) -> dict[str, str]:
    """The environment a runner process needs besides the test's own."""
    paths = [str(REPO), *[p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]]
    ament = [str(prefix), *[p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]]
    return {"PYTHONPATH": os.pathsep.join(dict.fromkeys(paths)), "AMENT_PREFIX_PATH": os.pathsep.join(ament)}


def runner_command(prefix: Path, launch_file: str, **arguments: str) -> list[str]:
    return [sys.executable, __file__, str(prefix), str(REPO / "launch" / launch_file),
            *(f"{k}:={v}" for k, v in arguments.items())]


def started(log: Path) -> dict[str, int]:
    """The processes launch reported started: executable -> pid (the last, for one started twice)."""
    return dict(started_all(log))


def started_all(log: Path) -> list[tuple[str, int]]:
    """Every process launch reported started, in order: (executable, pid)."""
    return [(name, int(pid)) for name, pid in STARTED.findall(log.read_text())]


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie does not)."""
    try:
        os.kill(pid, 0)
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except (ProcessLookupError, FileNotFoundError):
        return False


@contextmanager
def launched(prefix: Path, tmp_path: Path, launch_file: str, name: str = "launch",
             **arguments: str) -> Iterator[Path]:
    """Run ``launch_file`` with ``arguments``; yield its log; stop it as Ctrl-C does and check
    that it and every process it started ended (AssertionError otherwise)."""
    log = tmp_path / f"{name}.log"
    env = {**os.environ, **runner_env(prefix), "ROS_LOG_DIR": str(tmp_path / "ros_log")}
    with open(log, "w") as out:
        proc = subprocess.Popen(runner_command(prefix, launch_file, **arguments), stdout=out,
                                stderr=subprocess.STDOUT, env=env, cwd=str(tmp_path), start_new_session=True)
    try:
        yield log
    finally:
        pids = started_all(log)
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)
                raise AssertionError(f"{launch_file} did not stop on SIGINT:\n{log.read_text()[-3000:]}") \
                    from None
    deadline = time.monotonic() + 10.0
    while any(alive(p) for _, p in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [n for n, p in pids if alive(p)], log.read_text()[-3000:]


def main(argv: list[str]) -> int:
    prefix, launch_file, *args = argv
    others = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p and p != prefix]
    os.environ["AMENT_PREFIX_PATH"] = os.pathsep.join([prefix, *others])
    sys.path.extend(p for p in launch_path() if p not in sys.path)
    from launch.actions import IncludeLaunchDescription
    from launch.launch_description_sources import PythonLaunchDescriptionSource

    from launch import LaunchDescription, LaunchService

    arguments = [tuple(a.split(":=", 1)) for a in args]
    service = LaunchService(argv=args)
    service.include_launch_description(LaunchDescription([
        IncludeLaunchDescription(PythonLaunchDescriptionSource(launch_file), launch_arguments=arguments)]))
    return service.run()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
