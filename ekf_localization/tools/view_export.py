"""``bag_replay --html``: the field view of a replayed bag as one self-contained HTML file.

The page's own HTML, JavaScript and CSS (``ekf_localization/web``) are inlined, and the run
is embedded as JSON (``window.FIELD_VIEW_EMBEDDED``): frames at ``rate`` Hz of the replayed
estimate with its 95 % ellipse, the ground truth, the recent camera fixes with the replay's
accept/gate decision, plus the path, the position error and the NIS series. The page's
slider steps through the frames; nothing is loaded from anywhere else.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ekf_localization.control.field_path import resolve_config_file
from ekf_localization.core.chi2_bands import mean_chi2_band
from ekf_localization.core.config import EkfConfig
from ekf_localization.core.ellipse import ellipse_points
from ekf_localization.core.units import NS_PER_S
from ekf_localization.inputs import KINDS
from ekf_localization.ros.parameters import ParameterError, Problem
from ekf_localization.tools import bag_io
from ekf_localization.tools.consistency import InnovationLog
from ekf_localization.tools.replay import ReplayResult, abs_topic

FRAME_RATE_HZ = 10.0
RECENT_FIXES = 40  # as ekf_node's marker_fix_count default
PATH_TOPIC = "/pure_pursuit/path"
BODY_BEGIN, BODY_END = "<!--FIELD_VIEW_BODY_BEGIN-->", "<!--FIELD_VIEW_BODY_END-->"
# The simulator's command that prints the drawing data of the field a sim_node parameter file
# describes (JSON): run as a process, like the demo starts sim_node, so that this package never
# imports sim_robot.
FIELD_COMMAND = "sim_robot.ros.field_json"
FIELD_COMMAND_TIMEOUT_S = 120.0


def web_dir() -> Path:
    """The page's static files: in the package (pip, colcon), else the ament share directory."""
    here = Path(__file__).resolve().parents[1] / "web"
    if (here / "index.html").is_file():
        return here
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("ekf_localization")) / "web"
    except Exception:  # no ament index: report the package path
        return here


def load_field(sim_params_file: str | Path, name: str = "sim_params_file",
               what: str = "parameter") -> dict[str, Any]:
    """The drawing data of the field sim_node's parameter file describes, from the simulator's
    :data:`FIELD_COMMAND` (a bad file: a ParameterError naming ``name``)."""
    try:
        path = resolve_config_file(sim_params_file)
    except FileNotFoundError as exc:
        raise ParameterError(Problem(name, str(exc), what)) from None
    try:
        proc = subprocess.run([sys.executable, "-m", FIELD_COMMAND, str(path)], capture_output=True,
                              text=True, timeout=FIELD_COMMAND_TIMEOUT_S, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise ParameterError(Problem(name, f"{path}: the field was not read ({exc})", what)) from None
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines() or [f"{FIELD_COMMAND} exited {proc.returncode}"]
        raise ParameterError(Problem(name, lines[-1], what))
    return json.loads(proc.stdout)


def _r(v: float, digits: int = 4) -> float:
    return round(float(v), digits)


def _nearest(t_ns: np.ndarray, t: int) -> int | None:
    """Index of the newest sample at or before ``t`` (None: none yet)."""
    i = int(np.searchsorted(t_ns, t, side="right")) - 1
    return i if i >= 0 else None


def _fixes(bag: Path, config: EkfConfig,
           innovations: InnovationLog) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stamps (K,), positions (K, 2) and accepted flags (K,) of the pose inputs' fused or gated fixes."""
    per_input = innovations.per_input()
    types = bag_io.topic_types(bag)
    ts, xy, ok = [], [], []
    for inp in config.inputs:
        outcome = per_input.get(f"{inp.name} pose")
        if not KINDS[inp.kind].absolute_pose or outcome is None or abs_topic(inp.topic) not in types:
            continue
        decided = dict(zip(outcome.t_ns.tolist(), outcome.accepted.tolist(), strict=True))
        stamps, poses = bag_io.read_poses(bag, abs_topic(inp.topic))
        for t, p in zip(stamps.tolist(), poses, strict=True):
            if t in decided:  # rejected before the update (stale, non-finite, ...): not a fix
                ts.append(t)
                xy.append(p[:2])
                ok.append(decided[t])
    order = np.argsort(np.array(ts, dtype=np.int64), kind="stable")
    return (np.array(ts, dtype=np.int64)[order], np.array(xy, dtype=float).reshape(-1, 2)[order],
            np.array(ok, dtype=bool)[order])


def _path(bag: Path) -> list[list[float]]:
    if PATH_TOPIC not in bag_io.topic_types(bag):
        return []
    last = None
    for m in bag_io.iter_messages(bag, [PATH_TOPIC]):
        last = m.msg
    return [] if last is None else [[_r(p.pose.position.x), _r(p.pose.position.y)] for p in last.poses]


def view_data(bag: Path | str, config: EkfConfig, result: ReplayResult, innovations: InnovationLog,
              field: dict[str, Any], truth_topic: str = "/ground_truth/odom", rate_hz: float = FRAME_RATE_HZ,
              history_s: float = 30.0) -> dict[str, Any]:
    """The JSON-able run the page replays (module docstring)."""
    bag = Path(bag)
    traj = result.trajectory()
    if len(traj) == 0:
        raise ValueError("the replay produced no estimate")
    truth = None
    if abs_topic(truth_topic) in bag_io.topic_types(bag):
        truth = bag_io.read_odometry(bag, abs_topic(truth_topic))
    fix_t, fix_xy, fix_ok = _fixes(bag, config, innovations)
    t0 = int(traj.t_ns[0])
    step = int(round(NS_PER_S / rate_hz))
    frames, error = [], []
    for t in range(t0, int(traj.t_ns[-1]) + 1, step):
        i = _nearest(traj.t_ns, t)
        s, c = traj.states[i], traj.covariances[i]
        frame: dict[str, Any] = {"t": _r((t - t0) / NS_PER_S, 3), "truth": None, "target": None}
        ring = ellipse_points(s[:2], c[:2, :2], segments=40) if np.all(np.isfinite(c[:2, :2])) else None
        frame["estimate"] = {"x": _r(s[0]), "y": _r(s[1]), "yaw": _r(s[2]),
                             "ellipse": None if ring is None else [[_r(a), _r(b)] for a, b in ring]}
        if truth is not None:
            j = _nearest(truth.t_ns, t)
            if j is not None and t - truth.t_ns[j] < NS_PER_S // 5:
                g = truth.states[j]
                frame["truth"] = {"x": _r(g[0]), "y": _r(g[1]), "yaw": _r(g[2])}
                error.append([frame["t"], _r(math.hypot(s[0] - g[0], s[1] - g[1]), 5)])
        k = int(np.searchsorted(fix_t, t, side="right"))
        recent = slice(max(0, k - RECENT_FIXES), k)
        pts, ok = fix_xy[recent], fix_ok[recent]
        frame["fixes"] = {"accepted": [[_r(a), _r(b)] for a, b in pts[ok]],
                          "gated": [[_r(a), _r(b)] for a, b in pts[~ok]]}
        frames.append(frame)
    nis: dict[str, Any] = {}
    for label, inn in innovations.per_input().items():  # mean per second, as ekf_node's diagnostics
        if inn.nis.size == 0:
            continue
        sec = (inn.t_ns - t0) // NS_PER_S
        points = [[float(b + 1), _r(float(np.mean(inn.nis[sec == b])), 4)] for b in np.unique(sec) if b >= 0]
        per_second = inn.nis.size / max(len(points), 1)  # the band of a mean over that many updates
        band = [_r(v, 3) for v in mean_chi2_band(int(inn.dim), per_second)]
        nis[label.replace(" ", "/")] = {"dof": int(inn.dim), "points": points,
                                        "band": band if all(map(math.isfinite, band)) else None}
    status = {"name": "bag_replay", "level": "OK",
              "message": f"replay of {bag.name}: {len(traj)} estimates, {len(fix_t)} camera fixes "
                         f"({int((~fix_ok).sum())} gated)"}
    return {"field": field, "history": history_s, "rate": rate_hz, "frames": frames, "path": _path(bag),
            "error": error, "nis": nis, "status": status, "statuses": [status]}


def render_html(data: dict[str, Any], web: Path, title: str = "ekf_localization replay") -> str:
    """One HTML document: the page's body, its CSS and JS inlined, ``data`` embedded."""
    page = (web / "index.html").read_text()
    body = page[page.index(BODY_BEGIN) + len(BODY_BEGIN):page.index(BODY_END)]
    css = (web / "field_view.css").read_text()
    js = (web / "field_view.js").read_text().replace("</script", "<\\/script")
    embedded = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            f"<title>{title}</title>\n<style>\n{css}</style>\n</head>\n<body>\n{body}\n"
            f"<script>window.FIELD_VIEW_EMBEDDED = {embedded};</script>\n"
            f"<script>\n{js}</script>\n</body>\n</html>\n")


def write_html(path: Path | str, data: dict[str, Any], web: Path,
               title: str = "ekf_localization replay") -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render_html(data, web, title))
    return path
