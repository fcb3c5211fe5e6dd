"""The demo's ``--camera images`` mode: camera images in, field poses fused.

sim_node renders the field's AprilTags (config/sim.yaml ``camera_images``: camera/image_raw,
camera/camera_info and the static TF base_link -> camera_optical) instead of handing out
finished camera poses (``camera.enabled`` false), and tag_localizer (config/tag_localizer.yaml)
detects the tags, solves PnP against the layout and publishes camera/pose, the topic
ekf_node's pose0 fuses. The images themselves are not recorded (640x480 at 20 Hz is 6 MB/s):
the bag holds tag_localizer's poses and its /diagnostics, from which the demo prints
``tag fixes: N accepted, M rejected``.
"""

from __future__ import annotations

from pathlib import Path

NODE = "tag_localizer"
MODULE = "ekf_localization.nodes.tag_localizer_node"
LAYOUT = Path("tags") / "ftc_seed000.yaml"  # under config/: the tags sim_node renders
IMAGE_TOPICS = ("/camera/image_raw", "/camera/camera_info")
POSE_TOPIC = "/camera/pose"  # tag_localizer's fixes (ekf_node's pose0)
# before sim time starts: tag_localizer subscribes both image topics (the recorder does not)
SUBSCRIBED_BEFORE_START = tuple((t, 1) for t in IMAGE_TOPICS)
DIAGNOSTICS_NAME = f"{NODE}: tag fixes"


def sim_arguments(cfg: Path) -> list[str]:
    """sim_node's ``-p`` overrides: images of the layout's tags, no finished camera poses."""
    return ["-p", "camera.enabled:=false", "-p", "camera_images.enabled:=true",
            "-p", f"camera_images.tag_layout:={cfg / LAYOUT}"]


def node_arguments(cfg: Path) -> list[str]:
    """tag_localizer's ROS arguments: the shipped YAML on sim time, the layout by absolute path."""
    return ["--params-file", str(cfg / "tag_localizer.yaml"), "-p", "use_sim_time:=true",
            "-p", f"layout_file:={cfg / LAYOUT}"]


def tag_fix_counts(bag: Path) -> dict[str, int] | None:
    """tag_localizer's counters in its last /diagnostics of ``bag`` (None: none recorded)."""
    from ekf_localization.tools import bag_io

    last = None
    for m in bag_io.iter_messages(bag, ["/diagnostics"]):
        for st in m.msg.status:
            if st.name.endswith(DIAGNOSTICS_NAME):
                last = st
    if last is None:
        return None
    return {kv.key: int(kv.value) for kv in last.values if kv.value.lstrip("-").isdigit()}


def tag_fix_line(bag: Path) -> str:
    """``tag fixes: N accepted, M rejected (reason n, ...)`` for the demo's report."""
    counts = tag_fix_counts(bag)
    if counts is None:
        return "tag fixes: no tag_localizer diagnostics recorded"
    reasons = sorted((k.removeprefix("rejected_"), n) for k, n in counts.items()
                     if k.startswith("rejected_") and n)
    detail = f" ({', '.join(f'{r} {n}' for r, n in reasons)})" if reasons else ""
    return (f"tag fixes: {counts.get('fixes_accepted', 0)} accepted, {counts.get('fixes_rejected', 0)} "
            f"rejected{detail} of {counts.get('frames_received', 0)} frames (tag_localizer's last "
            "/diagnostics)")


def tag_fix_nees_line(bag: Path, truth) -> str:
    """``tag fixes NEES mean X``: tag_localizer's (x, y, θ) fixes on camera/pose against the
    truth ``truth`` (a Trajectory) at their capture stamps, with the covariance each published
    (χ²(3); the band treats the fixes, one per frame, as independent)."""
    import numpy as np

    from ekf_localization.tools import bag_io
    from ekf_localization.tools.consistency import mean_chi2_band, pose_nees
    from ekf_localization.tools.evaluation import Trajectory

    fixes = [bag_io.pose_stamped_state(m.msg) for m in bag_io.iter_messages(bag, [POSE_TOPIC])]
    if not fixes:
        return "tag fixes NEES: no fix recorded"
    t, poses, covs = (np.array(v) for v in zip(*fixes, strict=True))
    nees = pose_nees(Trajectory(t, poses, covs), truth)
    lo, hi = mean_chi2_band(3, max(1, nees.nees.size))
    return (f"tag fixes NEES mean {nees.mean:.2f} (chi2(3), {nees.nees.size} fixes of {POSE_TOPIC} against "
            f"the truth; 95 % band of the mean [{lo:.2f}, {hi:.2f}])")
