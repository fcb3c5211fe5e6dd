"""Coordinate frames: a transform buffer and measurements expressed in the filter's frames (no ROS).

Inputs arrive in their own frames (an IMU in ``imu_link``, a twist in ``base_footprint``, a
camera's pose in ``map``); the filter wants poses of ``base_link`` in the world frame and
twists / IMU data in ``base_link``. :class:`TransformBuffer` holds the frame tree (fed from
tf2, from ``/tf`` and ``/tf_static`` messages live or in a bag, and from the
``static_transforms`` parameter) and :func:`to_filter_frames` rewrites a measurement part.

Conventions (REP-103): ``T_ab`` maps coordinates in frame b to frame a (``p_a = R_ab·p_b + t_ab``),
so it is the pose of b in a, i.e. tf's transform with parent a and child b. A pose
covariance is over position and rotation about the *fixed* axes of the frame it is expressed
in (geometry_msgs/PoseWithCovariance): a perturbation ``R -> exp([δθ]×)·R``.

* **Twist** of sensor frame s (body axes) -> base b, with ``T_bs = (R, t)``:
  ``ω_b = R·ω_s``, ``v_b = R·(v_s − ω_s × r_s)`` with the lever arm ``r_s = Rᵀ·t``, i.e.
  ``v_b = R·v_s + t × ω_b``; linear, so the covariance is ``J·C·Jᵀ`` with
  ``J = [[R, [t]×·R], [0, R]]``.
* **IMU** (REP-145): orientation ``R_ref,b = R_ref,s·R_bsᵀ`` (the fixed-axis covariance is
  unchanged by a right factor), angular velocity and linear acceleration rotated by ``R``
  (the acceleration's lever-arm terms, ω×(ω×r) and α×r, are not added: the rates they need
  are not measured).
* **Pose** of sensor s in frame f -> pose of b in world w:
  ``T_wb = T_wf·T_fs·T_bs⁻¹``; with ``u = R_fs·t_sb`` (``t_sb`` = translation of ``T_bs⁻¹``)
  the Jacobian over (position, fixed-axis rotation) is ``J = [[R_wf, −R_wf·[u]×], [0, R_wf]]``
  (:func:`pose_transform_jacobian`, checked against finite differences in the tests).

A Jacobian entry that is exactly zero does not propagate a NaN (a NaN in a field the
transform does not mix into a fused field stays harmless, as without a transform).
"""

from __future__ import annotations

from bisect import bisect_left
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ekf_localization.core.angles import matrix_to_rpy, quaternion_to_matrix, rpy_to_matrix
from ekf_localization.core.measurements import MeasurementPart

_ORIGIN = np.zeros(3)
_EYE = np.eye(3)


def skew(v: np.ndarray) -> np.ndarray:
    """[v]×: skew(v)·a = v × a."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass(frozen=True, eq=False)
class RigidTransform:
    """``T_ab``: p_a = rotation·p_b + translation (the pose of frame b in frame a)."""

    rotation: np.ndarray = field(default_factory=lambda: _EYE)
    translation: np.ndarray = field(default_factory=lambda: _ORIGIN)

    @classmethod
    def from_quaternion(cls, translation, quaternion) -> RigidTransform:
        """From a translation (3,) and a quaternion (x, y, z, w), as in geometry_msgs/Transform."""
        return cls(quaternion_to_matrix(*(float(q) for q in quaternion)),
                   np.array([float(v) for v in translation]))

    @classmethod
    def from_xyz_ypr(cls, x: float, y: float, z: float, yaw: float, pitch: float,
                     roll: float) -> RigidTransform:
        """``static_transform_publisher``'s argument order: x y z yaw pitch roll."""
        return cls(rpy_to_matrix(roll, pitch, yaw), np.array([x, y, z], dtype=float))

    def compose(self, other: RigidTransform) -> RigidTransform:
        """T_ab.compose(T_bc) = T_ac."""
        return RigidTransform(self.rotation @ other.rotation,
                              self.rotation @ other.translation + self.translation)

    def inverse(self) -> RigidTransform:
        Rt = self.rotation.T
        return RigidTransform(Rt, -(Rt @ self.translation))

    def is_identity(self) -> bool:
        return bool(np.array_equal(self.rotation, _EYE) and not np.any(self.translation))


IDENTITY = RigidTransform()


def _slerp(T0: RigidTransform, T1: RigidTransform, s: float) -> RigidTransform:
    """Interpolate between two transforms: translation linearly, rotation along the geodesic."""
    from scipy.spatial.transform import Rotation

    rel = Rotation.from_matrix(T0.rotation.T @ T1.rotation).as_rotvec()
    R = T0.rotation @ Rotation.from_rotvec(s * rel).as_matrix()
    return RigidTransform(R, (1.0 - s) * T0.translation + s * T1.translation)


class TransformBuffer:
    """The frame tree: one parent per frame, static links and time-stamped dynamic ones.

    ``lookup(target, source, stamp_ns)`` gives ``T_target,source`` at ``stamp_ns``: dynamic
    links are interpolated between their samples, the newest is used after the newest sample
    (robot_localization falls back to the latest transform too), and nothing before the
    oldest; ``stamp_ns`` 0 means the latest. Samples older than ``cache_ns`` behind a link's
    newest are dropped (tf2 keeps 10 s). Frame names come from messages: at most ``max_frames``
    static and ``max_frames`` time-stamped links are kept, the least recently updated of a kind
    forgotten first (``evictions`` counts them), so a flood of /tf frames never pushes out the
    camera's static mount. A link set with ``pinned`` (the ``static_transforms`` parameter) is
    never replaced or forgotten: a message for its child frame is ignored, so that the filter
    uses the value of its own parameters, live and in replay alike.
    """

    def __init__(self, cache_ns: int = 10_000_000_000, max_frames: int = 1000) -> None:
        self.cache_ns = int(cache_ns)
        self.max_frames = int(max_frames)
        self.evictions = 0
        self._recent: dict[bool, OrderedDict[str, None]] = {True: OrderedDict(), False: OrderedDict()}
        self._parent: dict[str, str] = {}
        self._static: dict[str, RigidTransform] = {}
        self._stamps: dict[str, list[int]] = {}
        self._samples: dict[str, list[RigidTransform]] = {}
        self._static_chains: dict[tuple[str, str], RigidTransform | None] = {}
        self._pinned: set[str] = set()

    @staticmethod
    def _name(frame: str) -> str:
        return frame.strip().lstrip("/")

    def __len__(self) -> int:
        """The links held (one per child frame)."""
        return len(self._parent)

    def _touch(self, child: str, static: bool) -> None:
        """``child``'s link was just set; beyond ``max_frames`` of its kind the stalest goes."""
        self._recent[not static].pop(child, None)
        recent = self._recent[static]
        recent[child] = None
        recent.move_to_end(child)
        if len(recent) > self.max_frames:
            old, _ = recent.popitem(last=False)
            for table in (self._parent, self._static, self._stamps, self._samples):
                table.pop(old, None)
            self._static_chains.clear()
            self.evictions += 1

    def set_static(self, parent: str, child: str, transform: RigidTransform, pinned: bool = False) -> None:
        """A fixed link (``/tf_static``; the ``static_transforms`` parameter, ``pinned``): T_parent,child."""
        parent, child = self._name(parent), self._name(child)
        if child in self._pinned and not pinned:
            return
        if pinned:
            self._pinned.add(child)
        self._parent[child] = parent
        self._static[child] = transform
        self._stamps.pop(child, None)
        self._samples.pop(child, None)
        self._static_chains.clear()
        if not pinned:  # a pinned link is not counted against max_frames, never forgotten
            self._touch(child, static=True)

    def add(self, parent: str, child: str, transform: RigidTransform, stamp_ns: int) -> None:
        """A time-stamped link (``/tf``)."""
        parent, child = self._name(parent), self._name(child)
        if child in self._pinned:
            return
        if self._parent.get(child) != parent or child in self._static:
            self._parent[child] = parent
            self._static.pop(child, None)
            self._stamps[child], self._samples[child] = [], []
            self._static_chains.clear()
        stamps, samples = self._stamps[child], self._samples[child]
        i = bisect_left(stamps, stamp_ns)
        if i < len(stamps) and stamps[i] == stamp_ns:
            samples[i] = transform
        else:
            stamps.insert(i, int(stamp_ns))
            samples.insert(i, transform)
        k = bisect_left(stamps, stamps[-1] - self.cache_ns)
        if k > 0:
            del stamps[:k]
            del samples[:k]
        self._touch(child, static=False)

    def frames(self) -> set[str]:
        return set(self._parent) | set(self._parent.values())

    def newest_stamp(self, child: str) -> int | None:
        """The stamp of the newest sample of ``child``'s time-stamped link (None: none, or static)."""
        stamps = self._stamps.get(self._name(child))
        return stamps[-1] if stamps else None

    def _link(self, child: str, stamp_ns: int) -> RigidTransform | None:
        if child in self._static:
            return self._static[child]
        stamps, samples = self._stamps[child], self._samples[child]
        if stamp_ns == 0 or stamp_ns >= stamps[-1]:
            return samples[-1]
        i = bisect_left(stamps, stamp_ns)
        if stamps[i] == stamp_ns:
            return samples[i]
        if i == 0:
            return None
        s = (stamp_ns - stamps[i - 1]) / (stamps[i] - stamps[i - 1])
        return _slerp(samples[i - 1], samples[i], s)

    def _ancestors(self, frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in self._parent and len(chain) <= len(self._parent):
            chain.append(self._parent[chain[-1]])
        return chain

    def _to_ancestor(self, chain: list[str], stamp_ns: int) -> RigidTransform | None:
        """T_{chain[-1], chain[0]} along a chain child -> ... -> ancestor."""
        T = IDENTITY
        for child in chain[:-1]:
            link = self._link(child, stamp_ns)
            if link is None:
                return None
            T = link.compose(T)
        return T

    def lookup(self, target: str, source: str, stamp_ns: int = 0) -> RigidTransform | None:
        """T_target,source, or None when the frames are not connected (or not yet at that time)."""
        target, source = self._name(target), self._name(source)
        if target == source:
            return IDENTITY
        key = (target, source)
        if key in self._static_chains:
            return self._static_chains[key]
        up_s, up_t = self._ancestors(source), self._ancestors(target)
        common = next((f for f in up_s if f in up_t), None)
        if common is None:
            return None
        chain_s = up_s[:up_s.index(common) + 1]
        chain_t = up_t[:up_t.index(common) + 1]
        a_s = self._to_ancestor(chain_s, stamp_ns)
        a_t = self._to_ancestor(chain_t, stamp_ns)
        if a_s is None or a_t is None:
            return None
        T = a_t.inverse().compose(a_s)
        if all(f in self._static for f in chain_s[:-1] + chain_t[:-1]):
            self._static_chains[key] = T
        return T


# --- measurement parts in the filter's frames ---------------------------------------------------


def masked_matmul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A·B where a product with an exact zero factor counts as 0 (so a NaN it meets stays out)."""
    prod = A[:, :, None] * B[None, :, :]
    with np.errstate(invalid="ignore"):
        return np.where((A[:, :, None] != 0.0) & (B[None, :, :] != 0.0), prod, 0.0).sum(axis=1)


def _linear(J: np.ndarray, values: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = masked_matmul(J, np.asarray(values, dtype=float)[:, None])[:, 0]
    return v, masked_matmul(masked_matmul(J, np.asarray(cov, dtype=float)), J.T)


def twist_jacobian(T_bs: RigidTransform) -> np.ndarray:
    """(6, 6) J: body twist [v ω] of frame s -> of frame b (module docstring)."""
    R, t = T_bs.rotation, T_bs.translation
    J = np.zeros((6, 6))
    J[:3, :3] = R
    J[:3, 3:] = skew(t) @ R
    J[3:, 3:] = R
    return J


def transform_twist(twist: np.ndarray, cov: np.ndarray,
                    T_bs: RigidTransform) -> tuple[np.ndarray, np.ndarray]:
    """A body twist [vx vy vz wx wy wz] of sensor frame s, and its 6x6 covariance, as base b's."""
    return _linear(twist_jacobian(T_bs), twist, cov)


def pose_transform_jacobian(T_wf: RigidTransform, T_fs: RigidTransform, T_bs: RigidTransform) -> np.ndarray:
    """(6, 6) J of T_wb = T_wf·T_fs·T_bs⁻¹ over (position, fixed-axis rotation) of T_fs."""
    u = T_fs.rotation @ T_bs.inverse().translation
    Rw = T_wf.rotation
    J = np.zeros((6, 6))
    J[:3, :3] = Rw
    J[:3, 3:] = -Rw @ skew(u)
    J[3:, 3:] = Rw
    return J


def transform_pose(pose: np.ndarray, cov: np.ndarray, T_wf: RigidTransform,
                   T_bs: RigidTransform) -> tuple[np.ndarray, np.ndarray]:
    """Pose [x y z roll pitch yaw] of sensor frame s in frame f (6x6 covariance) -> of base b in w."""
    pose = np.asarray(pose, dtype=float)
    T_fs = RigidTransform(rpy_to_matrix(*pose[3:]), pose[:3].copy())
    T_wb = T_wf.compose(T_fs).compose(T_bs.inverse())
    out = np.concatenate([T_wb.translation, matrix_to_rpy(T_wb.rotation)])
    J = pose_transform_jacobian(T_wf, T_fs, T_bs)
    return out, masked_matmul(masked_matmul(J, np.asarray(cov, dtype=float)), J.T)


def _rotate(R: np.ndarray, values: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return _linear(R, values, cov)


def transform_orientation(rpy: np.ndarray, T_bs: RigidTransform) -> np.ndarray:
    """IMU orientation (roll, pitch, yaw of frame s in its reference) -> of base b."""
    return matrix_to_rpy(rpy_to_matrix(*(float(a) for a in rpy)) @ T_bs.rotation.T)


Lookup = Callable[[str, str, int], RigidTransform | None]


def already_in_filter_frames(part: MeasurementPart, world_frame: str, base_frame: str, pose_of: str) -> bool:
    """Whether ``part`` is already in the frames the filter fuses, by its frame names (an empty
    name is ``base_frame``): a pose of ``base_frame`` in ``world_frame``, anything else in ``base_frame``."""
    frame = part.frame_id.strip().lstrip("/") or base_frame
    if part.name == "pose":
        return frame == world_frame and (pose_of.strip().lstrip("/") or base_frame) == base_frame
    return frame == base_frame


def to_filter_frames(part: MeasurementPart, stamp_ns: int, lookup: Lookup, world_frame: str,
                     base_frame: str, pose_of: str) -> tuple[MeasurementPart | None, tuple[str, str] | None]:
    """``part`` expressed in the frames the filter fuses (pose: of ``base_frame`` in
    ``world_frame``; twist and IMU parts: in ``base_frame``).

    ``pose_of`` is the frame whose pose a pose part gives (Odometry: its child_frame_id).
    Returns (the part, None), or (None, (target, source)) naming a missing transform.
    """
    if not part.provided or already_in_filter_frames(part, world_frame, base_frame, pose_of):
        return part, None
    frame = part.frame_id.strip().lstrip("/") or base_frame
    if part.name == "pose":
        pose_of = pose_of.strip().lstrip("/") or base_frame
        T_wf = lookup(world_frame, frame, stamp_ns)
        if T_wf is None:
            return None, (world_frame, frame)
        T_bs = lookup(base_frame, pose_of, stamp_ns)
        if T_bs is None:
            return None, (base_frame, pose_of)
        values, cov = transform_pose(part.values, part.covariance, T_wf, T_bs)
        return replace(part, frame_id=world_frame, values=values, covariance=cov), None
    T_bs = lookup(base_frame, frame, stamp_ns)
    if T_bs is None:
        return None, (base_frame, frame)
    if T_bs.is_identity():
        return replace(part, frame_id=base_frame), None
    if part.name == "twist":
        values, cov = transform_twist(part.values, part.covariance, T_bs)
    elif part.name == "orientation":
        values, cov = transform_orientation(part.values, T_bs), np.asarray(part.covariance, dtype=float)
    else:  # angular_velocity, linear_acceleration: free vectors
        values, cov = _rotate(T_bs.rotation, part.values, part.covariance)
    return replace(part, frame_id=base_frame, values=values, covariance=cov), None
