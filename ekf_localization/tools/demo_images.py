"""The demo's ``--camera images`` mode: camera images in, field poses fused.

sim_node renders the field's AprilTags (config/sim.yaml ``camera_images``: camera/image_raw,
camera/camera_info and the static TF base_link -> camera_optical) instead of handing out
finished camera poses (``camera.enabled`` false), and tag_localizer (config/tag_localizer.yaml)
detects the tags, solves PnP against the layout and publishes camera/pose, the topic
ekf_node's pose0 fuses. The images themselves are not recorded (640x480 at 20 Hz is 6 MB/s):
the bag holds tag_localizer's poses and its /diagnostics, from which the demo prints
``tag fixes: N accepted, M rejected``.

``--cameras 2``: sim_node renders a second camera too (config/sim.yaml ``camera1``: camera1/image_raw,
camera1/camera_info, frame camera1_optical), a second tag_localizer in namespace ``camera1`` turns
its images into camera1/pose, and ekf_node fuses both (config/ekf_two_cameras.yaml: pose0 and pose1).

A single tag is handled as config/tag_localizer.yaml's ``single_tag`` says (``--single-tag``
overrides it). With ``corners`` tag_localizer sends a lone tag's corner pixels instead of a pose,
and ekf_node gets one ``tag_cornersN`` input per layout tag and camera (:func:`ekf_overrides`,
sim_robot/ros/sim_corner_inputs.py, tools/tag_corner_inputs.py), its intrinsics and mount those
of the simulator's camera (config/sim.yaml ``camera_images``, ``camera1``) and its corner noise
tag_localizer's.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml

from ekf_localization.ros.launch_description import CAMERAS, SECOND_CAMERA_TOPICS  # sim.launch.py's too
from ekf_localization.vision.heading_prior import CORNERS

NODE = "tag_localizer"
MODULE = "ekf_localization.nodes.tag_localizer_node"
LAYOUT = Path("tags") / "ftc_seed000.yaml"  # under config/: the tags sim_node renders


def image_topics(cameras: int = 1) -> tuple[str, ...]:
    """The image and CameraInfo topics of ``cameras`` cameras (not recorded)."""
    return tuple(f"/{c}/{t}" for c in CAMERAS[:cameras] for t in ("image_raw", "camera_info"))


def pose_topics(cameras: int = 1) -> tuple[str, ...]:
    return tuple(f"/{c}/pose" for c in CAMERAS[:cameras])


def subscribed_before_start(images: bool, cameras: int = 1) -> tuple[tuple[str, int], ...]:
    """(topic, subscriptions) before sim time starts, beyond the one-camera demo's: each
    tag_localizer subscribes its image topics (the recorder does not), and ekf_node and the
    recorder the second camera's poses."""
    return (*((t, 1) for t in (image_topics(cameras) if images else ())),
            *((t, 2) for t in pose_topics(cameras)[1:]))


def sim_arguments(cfg: Path) -> list[str]:
    """sim_node's ``-p`` overrides: images of the layout's tags, no finished camera poses."""
    return ["-p", "camera.enabled:=false", "-p", "camera_images.enabled:=true",
            "-p", f"camera_images.tag_layout:={cfg / LAYOUT}"]


def node_arguments(cfg: Path, camera: int = 0, single_tag: str | None = None) -> list[str]:
    """tag_localizer's ROS arguments for camera ``camera`` (0 or 1): the shipped YAML on sim time,
    the layout by absolute path, ``single_tag`` if given; the second camera's in namespace
    camera1, reading camera1/*."""
    args = ["--params-file", str(cfg / "tag_localizer.yaml"), "-p", "use_sim_time:=true",
            "-p", f"layout_file:={cfg / LAYOUT}"]
    if single_tag is not None:
        args += ["-p", f"single_tag:={single_tag}"]
    if camera:
        args += ["-r", f"__ns:=/{CAMERAS[camera]}"]
        args += [a for k, v in SECOND_CAMERA_TOPICS.items() for a in ("-p", f"{k}:={v}")]
    return args


def tag_localizer_settings(cfg: Path, single_tag: str | None = None):
    """The demo's tag_localizer settings (ros/tag_localizer_parameters.py): the shipped YAML with
    the demo's layout and ``single_tag`` if given."""
    from ekf_localization.ros.parameters import parameters_from_yaml
    from ekf_localization.ros.tag_localizer_parameters import NODE_NAME, parse_settings

    values = parameters_from_yaml(cfg / "tag_localizer.yaml", NODE_NAME)
    values["layout_file"] = str(cfg / LAYOUT)
    if single_tag is not None:
        values["single_tag"] = single_tag
    return parse_settings(values)


def ekf_overrides(cfg: Path, sim_yaml: Path, cameras: int = 1,
                  single_tag: str | None = None) -> dict[str, Any]:
    """ekf_node's extra parameters for the images demo: with ``single_tag`` corners one
    ``tag_cornersN`` per layout tag and camera (sim_robot/ros/sim_corner_inputs.py, run as a
    process: the simulator's camera model is the simulator's); else none."""
    if tag_localizer_settings(cfg, single_tag).single_tag != CORNERS:
        return {}
    cmd = [sys.executable, "-m", "sim_robot.ros.sim_corner_inputs", "--config", str(cfg),
           "--sim-params", str(sim_yaml), "--cameras", str(cameras)]
    if single_tag is not None:
        cmd += ["--single-tag", single_tag]
    run = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if run.returncode:
        raise ValueError(run.stderr.strip() or f"sim_corner_inputs exited {run.returncode}")
    return yaml.safe_load(run.stdout) or {}


def node_label(camera: int = 0) -> str:
    """The demo's name for camera ``camera``'s tag_localizer (its log: the name with _ for /)."""
    return f"{CAMERAS[camera]}/{NODE}" if camera else NODE


def _head(camera: int) -> str:
    """The report lines' start: ``tag fixes``, ``camera1 tag fixes``."""
    return f"{CAMERAS[camera]} tag fixes" if camera else "tag fixes"


def diagnostics_name(camera: int = 0) -> str:
    """tag_localizer's status name on /diagnostics: its namespace first for the second camera."""
    return f"{node_label(camera)}: tag fixes"


def tag_fix_counts(bag: Path, camera: int = 0) -> dict[str, int] | None:
    """Camera ``camera``'s tag_localizer's counters in its last /diagnostics of ``bag`` (None: none
    recorded)."""
    from ekf_localization.tools import bag_io

    name = diagnostics_name(camera)
    last = None
    for m in bag_io.iter_messages(bag, ["/diagnostics"]):
        for st in m.msg.status:
            if st.name == name:
                last = st
    if last is None:
        return None
    return {kv.key: int(kv.value) for kv in last.values if kv.value.lstrip("-").isdigit()}


def tag_fix_line(bag: Path, camera: int = 0) -> str:
    """``tag fixes: N accepted, M rejected (reason n, ...)`` for the demo's report (the second
    camera's: ``camera1 tag fixes: ...``)."""
    counts = tag_fix_counts(bag, camera)
    head = _head(camera)
    if counts is None:
        return f"{head}: no tag_localizer diagnostics recorded"
    reasons = sorted((k.removeprefix("rejected_"), n) for k, n in counts.items()
                     if k.startswith("rejected_") and n)
    detail = f" ({', '.join(f'{r} {n}' for r, n in reasons)})" if reasons else ""
    corners = (f", {counts['corner_frames']} single-tag frames sent as corners" if "corner_frames" in counts
               else "")
    return (f"{head}: {counts.get('fixes_accepted', 0)} accepted, {counts.get('fixes_rejected', 0)} "
            f"rejected{detail}{corners} of {counts.get('frames_received', 0)} frames (tag_localizer's last "
            "/diagnostics)")


def tag_fix_nees_line(bag: Path, truth, camera: int = 0) -> str:
    """``tag fixes NEES mean X``: tag_localizer's (x, y, θ) fixes on camera/pose (camera1/pose)
    against the truth ``truth`` (a Trajectory) at their capture stamps, with the covariance each published
    (χ²(3); the band treats the fixes, one per frame, as independent)."""
    import numpy as np

    from ekf_localization.tools import bag_io
    from ekf_localization.tools.consistency import mean_chi2_band, pose_nees
    from ekf_localization.tools.evaluation import Trajectory

    topic = pose_topics(camera + 1)[camera]
    head = _head(camera)
    fixes = [bag_io.pose_stamped_state(m.msg) for m in bag_io.iter_messages(bag, [topic])]
    if not fixes:
        return f"{head} NEES: no fix recorded"
    t, poses, covs = (np.array(v) for v in zip(*fixes, strict=True))
    nees = pose_nees(Trajectory(t, poses, covs), truth)
    lo, hi = mean_chi2_band(3, max(1, nees.nees.size))
    return (f"{head} NEES mean {nees.mean:.2f} (chi2(3), {nees.nees.size} fixes of {topic} against "
            f"the truth; 95 % band of the mean [{lo:.2f}, {hi:.2f}])")
