"""Corners or the ambiguity gate on the same drive: a ``single_tag: corners`` run replayed both ways.

A live comparison of two images-demo runs mixes the method with the run: the follower steers by
the estimate, so the drives differ, and so does the machine's load. This replays one run twice
offline, with the same messages but its single-tag frames:

* ``corners``: the bag as recorded (each single-tag frame's corners fused by its ``tag_cornersN``);
* ``ambiguity``: each of those frames solved instead as tag_localizer's gate does (the same
  corner pixels, which are the undistorted detections; ``tag_pnp.localize`` with the shipped
  corner noise and ``max_ambiguity``, the previous fix for the blur) and fused, if accepted, as a
  ``pose0`` fix; rejected frames are dropped.

Everything else (odometry, IMU, cmd_vel, the multi-tag fixes) is the same, fed as ekf_node's
fusion log says (tools/replay.py; a gated fix takes its frame's place in the log), so the
corners replay reproduces the run. Printed per run and pooled: fixes /
frames, (x, y) RMSE and the pose NEES (x, y, θ with the replayed covariance against the truth,
χ²(3)) of both replays.

    python benchmarks/single_tag_paired.py DIR [DIR ...]    # ekf_demo --single-tag corners --out DIR
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ekf_localization.core.units import ns_to_sec_nanosec  # noqa: E402
from ekf_localization.inputs.tag_corners import TagCornerObservation  # noqa: E402
from ekf_localization.ros import fusion_log  # noqa: E402
from ekf_localization.ros.conversions import message_to_measurement  # noqa: E402
from ekf_localization.ros.parameters import parameters_from_yaml  # noqa: E402
from ekf_localization.tools import bag_io  # noqa: E402
from ekf_localization.tools.consistency import pose_nees  # noqa: E402
from ekf_localization.tools.evaluation import rmse  # noqa: E402
from ekf_localization.tools.replay import load_settings, read_replay_input, replay  # noqa: E402
from ekf_localization.vision import tag_pnp  # noqa: E402
from ekf_localization.vision.detection import TagDetection  # noqa: E402
from sim_robot.ros.sim_params import parse_parameters  # noqa: E402
from sim_robot.world.camera_image_sensor import CameraImageSensor  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
POSE = "pose0"


def _pose_msg(fix: tag_pnp.TagFix, stamp_ns: int):
    """The PoseWithCovarianceStamped tag_localizer publishes for ``fix``."""
    from geometry_msgs.msg import PoseWithCovarianceStamped

    from ekf_localization.core.angles import rpy_to_quaternion

    msg = PoseWithCovarianceStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_sec_nanosec(stamp_ns)
    msg.header.frame_id = "map"
    p = msg.pose.pose
    p.position.x, p.position.y, p.position.z = (float(v) for v in fix.pose[:3])
    p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = rpy_to_quaternion(
        *(float(v) for v in fix.pose[3:]))
    msg.pose.covariance = [float(v) for v in tag_pnp.published_covariance(fix).reshape(-1)]
    return msg


def gate_events(events: tuple, corner_inputs: dict[str, int], tag, camera,
                mount) -> tuple[tuple, set[int], int]:
    """``events`` with each corners event replaced by the gate's fix (or dropped); (events, the
    stamps of the fixes, frames). The blur's previous fix is the newest pose0 fix before the
    frame, as in the node."""
    out, previous, fixes, frames = [], None, set(), 0
    for now, name, item in events:
        if name not in corner_inputs:
            if name == POSE and item is not None:
                previous = (item.stamp_ns, np.asarray(item.pose, dtype=float))
            out.append((now, name, item))
            continue
        frames += 1
        obs: TagCornerObservation = item
        det = TagDetection(corner_inputs[name], np.asarray(obs.corners, dtype=float))
        result, _ = tag_pnp.localize([det], tag.layout, camera, mount, tag.corner_noise, tag.max_ambiguity,
                                     tag.field_margin, previous, obs.stamp_ns)
        if isinstance(result, tag_pnp.TagFix) and result.reprojection_rms <= tag.max_reprojection_rms:
            fixes.add(obs.stamp_ns)
            fix = message_to_measurement("pose", _pose_msg(result, obs.stamp_ns))
            previous = (obs.stamp_ns, np.asarray(result.pose, dtype=float))
            out.append((now, POSE, fix))
    return tuple(out), fixes, frames


def gate_log(log: np.ndarray, corner_inputs: dict[str, int], fixes: set[int]) -> np.ndarray:
    """ekf_node's fusion log with each corners row made the pose0 row of the gate's fix at its
    stamp, or dropped when the gate rejected that frame."""
    codes = {fusion_log.source_code(name) for name in corner_inputs}
    pose = fusion_log.source_code(POSE)
    rows = [(now, stamp, pose if code in codes else code) for now, stamp, code in log.tolist()
            if code not in codes or stamp in fixes]
    return np.array(rows, dtype=np.int64).reshape(-1, 3)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path,
                    help="ekf_demo --camera images --single-tag corners --out folders")
    args = ap.parse_args(argv)
    from ekf_localization.tools import demo_images

    cfg = REPO / "config"
    tag = demo_images.tag_localizer_settings(cfg, "ambiguity")
    values = parameters_from_yaml(cfg / "sim.yaml", "sim_node")
    values.update({"camera_images.enabled": True,
                   "camera_images.tag_layout": str(cfg / demo_images.LAYOUT)})
    images = parse_parameters(values)[1].camera_images
    mount = CameraImageSensor(images).base_to_optical()
    pooled = {m: [] for m in ("corners", "ambiguity")}
    print("| run | single-tag frames | gate: fixes | corners: (x, y) RMSE / NEES | ambiguity: (x, y) RMSE / "
          "NEES |")
    print("|---|---|---|---|---|")
    for run in args.runs:
        settings = load_settings(run / "ekf_params.yaml")
        config = settings.config
        corner_inputs = {i.name: int(i.topic.rsplit("_", 1)[1]) for i in config.inputs
                         if i.topic.split("/")[-2:-1] == ["tag_corners"]}
        source = read_replay_input(run / "bag", config)
        gated, fixes, frames = gate_events(source.events, corner_inputs, tag, images.camera, mount)
        truth = bag_io.read_odometry(run / "bag", "/ground_truth/odom")
        row = []
        alt = replace(source, events=gated, log=None if source.log is None
                      else gate_log(source.log, corner_inputs, fixes))
        for method, src in (("corners", source), ("ambiguity", alt)):
            traj = replay(src, settings).trajectory()
            nees = pose_nees(traj, truth)
            xy = rmse(traj, truth)["xy"]
            pooled[method].append((xy, nees.nees))
            row.append(f"{100 * xy:.2f} cm / {nees.mean:.2f}")
        print(f"| {run.name} | {frames} | {len(fixes)} | {row[0]} | {row[1]} |", flush=True)
    for method, rs in pooled.items():
        allnees = np.concatenate([n for _, n in rs])
        print(f"{method}: mean (x, y) RMSE {100 * np.mean([x for x, _ in rs]):.2f} cm, pooled NEES "
              f"{allnees.mean():.2f} ({allnees.size} estimates)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
