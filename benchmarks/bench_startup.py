"""ekf_node cold and warm start: seconds from exec to its "ready" log line (target <= 2 s).

    python benchmarks/bench_startup.py [--colcon] [--doc]

Cases, each a fresh ``ekf_node --params-file config/ekf.yaml`` process stopped once ready:

* venv, cold: numba's cache in an empty directory (``NUMBA_CACHE_DIR``), so every kernel compiles;
* venv, warm: the same directory again (what every later start pays);
* ``--colcon``: ``colcon build`` into a temporary workspace (its install step compiles the
  kernels into the tree, ``tools/warm_kernels.py``), the install tree made read-only
  (``chmod -R a-w``), started by an unprivileged user (``nobody``, via ``setpriv``, when run as
  root: root writes a read-only tree anyway) with an empty ``XDG_CACHE_HOME``: the first start
  of a user who cannot write the tree (``core/kernel_cache.py`` seeds a user cache from it),
  then again (second start).

Also printed: CPU seconds used by then, the node's own "warm-up" figure (kernels compiled or
loaded), and the node module's import alone (``python -X importtime`` breaks it down).
The peer: ``python -c "import rclpy; rclpy.init()"``, the floor any rclpy node pays.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
READY = re.compile(r"ready: (?:.*warm-up ([0-9.]+) s)?")  # a node without kernels reports no warm-up


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


def time_to_ready(cmd: list[str], env: dict[str, str], cwd: Path,
                  timeout: float = 120.0) -> tuple[float, float, float | None]:
    """(seconds to the ready line, CPU seconds the process used by then, the node's warm-up
    seconds or None); the node is then stopped."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    try:
        deadline = t0 + timeout
        for line in proc.stdout:
            m = READY.search(line)
            if m:
                warm = None if m.group(1) is None else float(m.group(1))
                return time.perf_counter() - t0, cpu_seconds(proc.pid), warm
            if time.perf_counter() > deadline:
                break
        raise RuntimeError(f"ekf_node never became ready: {' '.join(cmd)}")
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)


def time_command(cmd: list[str], env: dict[str, str], cwd: Path) -> tuple[float, float, None]:
    """(wall seconds, CPU seconds) of a command run to its end."""
    before = os.times()
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = os.times()
    cpu = after.children_user + after.children_system - before.children_user - before.children_system
    return wall, cpu, None


def as_unprivileged(cmd: list[str]) -> tuple[list[str], str]:
    """``cmd`` run as user nobody when this process is root (setpriv), and how it is run."""
    if os.geteuid() != 0:
        return cmd, "this user"
    if shutil.which("setpriv") is None:
        return cmd, "root (setpriv missing: the read-only tree is writable to root)"
    return ["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups", *cmd], "user nobody"


def colcon_install(ws: Path, env: dict[str, str]) -> Path:
    """colcon build of this package into ``ws``; returns the install prefix."""
    def ignore(_dir: str, names: list[str]) -> set[str]:
        return {n for n in names if n in {".venv", ".git", "output", "build", "install", "log", "__pycache__"}
                or n.endswith(".egg-info")}

    shutil.copytree(REPO, ws / "src" / "ekf_localization", ignore=ignore)
    subprocess.run([shutil.which("colcon"), "build", "--event-handlers", "console_direct-"], cwd=ws,
                   env=dict(env, AMENT_PREFIX_PATH=sys.prefix), check=True, capture_output=True)
    return ws / "install"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--colcon", action="store_true", help="also the read-only colcon install")
    ap.add_argument("--doc", action="store_true", help="write the result into docs/performance.md")
    args = ap.parse_args(argv)
    base = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    base.setdefault("ROS_DOMAIN_ID", "199")
    params = REPO / "config" / "ekf.yaml"
    node = [sys.executable, "-m", "ekf_localization.nodes.ekf_node", "--ros-args",
            "--params-file", str(params)]
    rows: list[tuple[str, float, float, float | None]] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        floor = time_command([sys.executable, "-c", "import rclpy; rclpy.init(); rclpy.shutdown()"],
                             base, tmp)
        imports = time_command([sys.executable, "-c", "import ekf_localization.nodes.ekf_node"], base, tmp)
        rows.append(("peer: python -c 'import rclpy; rclpy.init()'", *floor))
        rows.append(("python -c 'import ekf_localization.nodes.ekf_node'", *imports))
        env = dict(base, NUMBA_CACHE_DIR=str(tmp / "numba_cache"))
        rows.append(("venv, cold numba cache", *time_to_ready(node, env, tmp)))
        rows.append(("venv, warm numba cache", *time_to_ready(node, env, tmp)))
        if args.colcon:
            if shutil.which("colcon") is None:
                rows.append(("colcon: skipped, colcon not installed", math.nan, math.nan, None))
            else:
                t_build = time.perf_counter()
                prefix = colcon_install(tmp / "ws", base)
                t_build = time.perf_counter() - t_build
                subprocess.run(["chmod", "-R", "a-w", str(prefix)], check=True)
                pkg = next(prefix.glob("ekf_localization/lib/python*/site-packages"))
                share = prefix / "ekf_localization" / "share" / "ekf_localization" / "config" / "ekf.yaml"
                cenv = {k: v for k, v in base.items() if k != "NUMBA_CACHE_DIR"}
                home = tmp / "user_home"
                home.mkdir()
                cenv.update(PYTHONPATH=f"{pkg}:{cenv.get('PYTHONPATH', '')}".rstrip(":"),
                            XDG_CACHE_HOME=str(home / ".cache"), HOME=str(home), ROS_HOME=str(home / ".ros"))
                exe = prefix / "ekf_localization" / "lib" / "ekf_localization" / "ekf_node"
                cmd, who = as_unprivileged([str(exe), "--ros-args", "--params-file", str(share)])
                if cmd[0] == "setpriv":
                    tmp.chmod(0o755)
                    shutil.chown(home, "nobody", "nogroup")
                print(f"colcon build (with its kernel step): {t_build:.1f} s wall; nodes started as {who}")
                try:
                    rows.append((f"colcon, read-only install, first start of {who}",
                                 *time_to_ready(cmd, cenv, tmp)))
                    rows.append(("colcon, read-only install, second start", *time_to_ready(cmd, cenv, tmp)))
                finally:
                    subprocess.run(["chmod", "-R", "u+w", str(tmp / "ws")], check=False)
    lines = ["| case | to ready, wall s | CPU s | node's warm-up s | CPU / peer's |", "|---|---|---|---|---|"]
    for name, s, cpu, warm in rows:
        lines.append(f"| {name} | {s:.2f} | {cpu:.2f} | {'-' if warm is None else f'{warm:.1f}'} "
                     f"| x{cpu / floor[1]:.1f} |")
    lines += ["", "Wall time on a loaded machine is mostly waiting for a core: the CPU seconds are "
              "what the start costs (ready <= 2 s on an idle core needs CPU <= 2 s)."]
    text = "\n".join(lines)
    print(text)
    if args.doc:
        from perf_doc import write_section  # benchmarks/ is on sys.path when run as a script

        print(f"wrote {write_section('startup', 'ekf_node start-up (bench_startup.py)', text)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
