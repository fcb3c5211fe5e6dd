"""``ekf_calibrate``'s camera mount: which mount the camera's fixes go through, the fixes turned into
base_link's through it, and the fitted mount written back as a ``static_transforms`` entry
(docs/ekf_calibrate.md, "The camera mount"; the fit: tools/mount_calibration.py).

A poseN input with ``poseN_pose_frame`` set gives the pose of that frame (the camera's); ekf_node
turns it into base_link's through the transform base_link -> frame of its ``static_transforms``
parameter (pinned: a /tf_static message does not replace it), or else of /tf_static. The
fixes are turned the same way here, and the pods' or driven wheels' fit finds the offset Δ of the
true mount from that one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ekf_localization.core.angles import matrix_to_rpy
from ekf_localization.core.config import EkfConfig
from ekf_localization.inputs import KINDS
from ekf_localization.ros.conversions import transforms_in_message
from ekf_localization.tools import bag_io, pod_calibration
from ekf_localization.tools import mount_calibration as mc
from ekf_localization.tools.replay import abs_topic

TF_STATIC = "/tf_static"
MAX_OFFSET = (0.5, 0.5)  # m, rad: a fitted offset beyond these is not a mount error (wrong fixes)


class MountError(Exception):
    """The camera's fixes cannot be turned into base_link's (one line, exit 2)."""


@dataclass(frozen=True)
class CameraMount:
    """The mount base_link -> ``frame`` that the poseN input ``input_name``'s fixes go through:
    x y z yaw pitch roll as ekf_node has it, and where it came from (``static_transforms`` or
    ``/tf_static``)."""

    input_name: str
    topic: str
    parent: str
    frame: str
    xyz_ypr: tuple[float, ...]
    source: str

    @property
    def planar(self) -> np.ndarray:
        """[x y yaw]: the part of the mount a pose in the plane sees."""
        return np.array([self.xyz_ypr[0], self.xyz_ypr[1], self.xyz_ypr[3]])

    def names(self) -> list[str]:
        return [f"static_transforms[{self.parent} {self.frame}].{k}" for k in mc.MOUNT_NAMES]


def _from_tf_static(bags: list[Path], parent: str, frame: str) -> tuple[float, ...] | None:
    found = None
    for bag in bags:
        for m in bag_io.iter_messages(bag, [TF_STATIC]):
            for p, c, T, _ in transforms_in_message(m.msg):
                if p.strip("/") == parent and c.strip("/") == frame:
                    ypr = matrix_to_rpy(T.rotation)[::-1]
                    found = (*(float(v) for v in T.translation), *(float(a) for a in ypr))
    return found


def camera_mount(config: EkfConfig, bags: list[Path], fix_topics: list[str]) -> CameraMount | None:
    """The mount of the one poseN input that gives a camera frame's pose (None: its fixes are
    base_link's). Raises MountError when ekf_node would have no transform for it, or several
    poseN inputs have a pose frame (one mount is fitted at a time)."""
    cams = [i for i in config.inputs if KINDS[i.kind].absolute_pose and abs_topic(i.topic) in fix_topics
            and getattr(i.settings, "pose_frame", "")]
    if not cams:
        return None
    if len(cams) > 1:
        raise MountError(f"{', '.join(i.name for i in cams)} each give a camera frame's pose: calibrate one "
                         "camera at a time (a params file with one of them)")
    inp, parent = cams[0], config.base_link_frame.strip("/")
    frame = inp.settings.pose_frame.strip("/")
    for p, c, xyz_ypr in config.static_transforms:
        if p == parent and c == frame:
            return CameraMount(inp.name, abs_topic(inp.topic), parent, frame, tuple(xyz_ypr),
                               "static_transforms")
    published = _from_tf_static(bags, parent, frame)
    if published is not None:
        return CameraMount(inp.name, abs_topic(inp.topic), parent, frame, published, TF_STATIC)
    raise MountError(f"{inp.name}_pose_frame is {frame}, but neither static_transforms nor the bags' "
                     f"/tf_static has the transform {parent} -> {frame}: its fixes cannot be turned into "
                     f"{parent}'s")


def to_base(pose: np.ndarray, var: np.ndarray, mount: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fixes of the camera frame (N, 3) -> base_link's through the believed ``mount`` [x y yaw]
    (F = C ∘ M₀⁻¹), the position variance grown by the lever arm's (|t|²·var yaw)."""
    base = mc.at_mount(pose, mc.inverse(mount))
    base[:, 2] = np.remainder(base[:, 2] + math.pi, 2 * math.pi) - math.pi
    grown = var.copy()
    grown[:, :2] += float(mount[0] ** 2 + mount[1] ** 2) * var[:, 2:3]
    return base, grown


def judge(problem: pod_calibration.Problem, start, candidates: np.ndarray | None, limits: np.ndarray,
          mount: CameraMount | None, pods: bool):
    """:func:`pod_calibration.observable` of ``start`` with the mount's Δ appended when the fixes go
    through ``mount``: (the geometry to fit, free, formal std, the parameters to report, the
    candidates). With pods the mount's x, y are held (a shift of base_link moves them and every
    pod's offset alike) and, while its yaw is fitted, the parallel pods' mean angle (the gauge)."""
    inner = np.ones(len(start.vector), bool) if candidates is None else np.asarray(candidates, bool)
    if mount is None:
        free, formal = pod_calibration.observable(problem, start, inner, limits)
        return start, free, formal, free, inner
    geom = mc.Mounted(start, tie=mc.pod_gauge(start) if pods else None)
    cands, lim = np.r_[inner, not pods, not pods, True], mc.limits(limits)
    tie = geom.tie if geom.tie is not None and inner[list(geom.tie.others)].any() else None
    c = cands.copy()
    if tie is not None:
        c[tie.index] = False
    free, formal = pod_calibration.observable(problem, geom, c, lim)
    if tie is not None and not free[-1]:  # the yaw held: the pods' angles need no reference
        geom, c = replace(geom, tie=None), cands.copy()
        c[-1] = False
        free, std = pod_calibration.observable(problem, geom, c, lim)
        formal = np.r_[std[:-1], formal[-1]]
    shown = free.copy()
    if tie is not None and free[-1]:
        shown[tie.index] = True
    return geom, free, formal, shown, cands


def report(mount: CameraMount, delta: np.ndarray, std: np.ndarray, free: np.ndarray,
           values: dict) -> list[str]:
    """Print the fitted mount (M = Δ ∘ M₀) per fitted component and put it into ``values``'
    ``static_transforms``; warn when /tf_static publishes it. Raises ValueError for an offset too
    large to be a mount error."""
    if abs(delta[2]) > MAX_OFFSET[1] or math.hypot(delta[0], delta[1]) > MAX_OFFSET[0]:
        raise ValueError(f"{mount.names()[2].rsplit('.', 1)[0]}: the fit moves the camera by "
                         f"{math.hypot(delta[0], delta[1]):.3g} m and {delta[2]:.3g} rad: fixes not of this "
                         "robot or the wrong pose frame; nothing written")
    was = mount.planar
    fitted = mc.corrected_mount(delta, was)
    for i, name in enumerate(mount.names()):
        if free[i]:
            print(f"{name} {fitted[i]:.6g} ± {std[i]:.2g} (was {was[i]:g})")
    x, y, z, yaw, pitch, roll = mount.xyz_ypr
    entry = " ".join(f"{v:.9g}" for v in (fitted[0], fitted[1], z, fitted[2], pitch, roll))
    entry += f" {mount.parent} {mount.frame}"
    kept = [t for t in values.get("static_transforms", []) or []
            if t.split()[6:8] != [mount.parent, mount.frame]]
    values["static_transforms"] = [*kept, entry]
    if mount.source == TF_STATIC:
        print(f"warning: {mount.parent} -> {mount.frame} came from /tf_static in the bag: ekf_node will "
              "use and publish the fitted static_transforms entry, but other nodes (tag_localizer, rviz) "
              "may still get the old value from where it is published: put the fitted mount there (the "
              "URDF or the static_transform_publisher) and drop one of the two")
    return ["static_transforms"]


def not_observable(mount: CameraMount, free: np.ndarray, candidates: np.ndarray, formal: np.ndarray) -> None:
    """One line per mount component the drives cannot give."""
    for i, name in enumerate(mount.names()):
        if not candidates[i]:
            why = "with dead-wheel pods a shift of base_link moves the camera and every pod's offset alike"
            print(f"{name}: held at the file's value ({why}); left unchanged")
        elif not free[i]:
            print(f"{name}: not observable from these drives (its std {formal[i]:.2g} > "
                  f"{mc.MOUNT_MAX_STD[i]:g}: too little turning for x, y or pushing for yaw, or too few "
                  "camera fixes); left unchanged")
