"""Camera landmark sensor: the robot's field pose from a wall image (seed 000, eq. 28 and 32).

An image is seen when it is *fully* in view (seed 000: 70° field of view):

* both end points of the image segment lie inside the horizontal field of view,
  ``|bearing| <= field_of_view / 2`` measured from the camera's optical axis
  (the boundary counts as inside);
* the camera is in front of the image (on the side its normal points to);
* the distance from the camera to the image centre is at most ``max_range``.

If several images are seen, the nearest one is used. The measurement is the robot
(``base_link``) pose in the field plus Gaussian noise of variance ``a·d² + b`` per
component (eq. 32, ``CameraNoise``), with separate (a, b) for position and yaw because
eq. 32 is not unit-invariant (yaw is in rad whatever the length unit). With
probability ``outlier_probability`` a visible measurement is additionally displaced by
``N(0, outlier_position_std²)`` per axis and ``N(0, outlier_yaw_std²)`` in yaw; the
reported covariance stays nominal (the camera does not know it is wrong).

Latency: the reading is stamped with the capture time and delivered ``latency_ns``
later (``arrival_ns``). The camera is mounted at ``mount_pose`` = [x, y, yaw] in
``base_link``; d is measured from the camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.units import METRES_PER_INCH
from ekf_localization.models.sensors.camera import CameraNoise
from sim_robot.world.field import Field


@dataclass(frozen=True)
class CameraConfig:
    """Camera rate, latency (ns), field of view (rad), range, mount, noise; SI defaults (seed 000)."""

    period_ns: int = 10_000_000
    latency_ns: int = 0
    field_of_view: float = math.radians(70.0)
    max_range: float = math.inf
    mount_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    position_noise: CameraNoise = field(
        default_factory=lambda: CameraNoise(0.001, 0.001 * METRES_PER_INCH**2))
    yaw_noise: CameraNoise = field(
        default_factory=lambda: CameraNoise(0.001 / METRES_PER_INCH**2, 0.001))
    outlier_probability: float = 0.0
    outlier_position_std: float = 0.5
    outlier_yaw_std: float = 0.5
    enabled: bool = True

    def __post_init__(self) -> None:
        if not (isinstance(self.period_ns, int) and self.period_ns > 0):
            raise ValueError(f"camera period_ns must be a positive int, got {self.period_ns!r}")
        if not (isinstance(self.latency_ns, int) and self.latency_ns >= 0):
            raise ValueError(f"camera latency_ns must be an int >= 0, got {self.latency_ns!r}")
        if not (0.0 < self.field_of_view < math.pi):
            raise ValueError(f"camera field_of_view must be in (0, pi) rad, got {self.field_of_view!r}")
        if not (self.max_range > 0.0):
            raise ValueError(f"camera max_range must be > 0, got {self.max_range!r}")
        if len(self.mount_pose) != 3 or not all(math.isfinite(v) for v in self.mount_pose):
            raise ValueError(f"camera mount_pose must be 3 finite numbers, got {self.mount_pose!r}")
        if not (0.0 <= self.outlier_probability <= 1.0):
            raise ValueError(f"outlier_probability must be in [0, 1], got {self.outlier_probability!r}")
        for name in ("outlier_position_std", "outlier_yaw_std"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")


@dataclass(frozen=True)
class CameraReading:
    """One capture for N trials; where ``visible`` is False the values are NaN / -1."""

    stamp_ns: int  # capture time
    arrival_ns: int  # capture time + latency: when the measurement is available
    visible: np.ndarray  # (N,) bool
    pose: np.ndarray  # (N, 3) measured robot pose [x y θ] in the field frame
    cov: np.ndarray  # (N, 3, 3) diagonal, a·d² + b
    image_index: np.ndarray  # (N,) int, index into Field.images, -1 when none
    distance: np.ndarray  # (N,) camera to image centre
    outlier: np.ndarray  # (N,) bool, for evaluation only


def camera_poses(robot_pose: np.ndarray, mount_pose: tuple[float, float, float]) -> np.ndarray:
    """(N, 3) camera poses in the field from robot poses and the mount pose in base_link."""
    p = np.asarray(robot_pose, dtype=float)
    mx, my, myaw = mount_pose
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    return np.column_stack([p[:, 0] + c * mx - s * my, p[:, 1] + s * mx + c * my, p[:, 2] + myaw])


def image_visibility(cam_pose: np.ndarray, field: Field, field_of_view: float,
                     max_range: float) -> tuple[np.ndarray, np.ndarray]:
    """(N, M) "fully in view" flags and (N, M) camera-to-image-centre distances."""
    cam = np.asarray(cam_pose, dtype=float)
    centres, normals, ends = field.image_arrays()
    fwd = np.column_stack([np.cos(cam[:, 2]), np.sin(cam[:, 2])])  # (N, 2)
    rel_c = centres[None, :, :] - cam[:, None, :2]  # (N, M, 2)
    distance = np.hypot(rel_c[..., 0], rel_c[..., 1])
    in_front = np.einsum("nmk,mk->nm", -rel_c, normals) > 0.0
    half = 0.5 * field_of_view
    inside = np.ones(distance.shape, dtype=bool)
    for e in range(2):
        rel = ends[None, :, e, :] - cam[:, None, :2]
        along = rel[..., 0] * fwd[:, None, 0] + rel[..., 1] * fwd[:, None, 1]
        across = fwd[:, None, 0] * rel[..., 1] - fwd[:, None, 1] * rel[..., 0]
        inside &= np.abs(np.arctan2(across, along)) <= half
    return inside & in_front & (distance <= max_range), distance


class CameraSensor:
    """Captures noisy pose measurements of the nearest fully visible image."""

    def __init__(self, config: CameraConfig, field: Field, n_trials: int,
                 rng: np.random.Generator) -> None:
        self.config = config
        self.field = field
        self.n = n_trials
        self._rng = rng

    def capture(self, t_ns: int, robot_pose: np.ndarray) -> CameraReading:
        cfg = self.config
        N = self.n
        # Fixed number of draws per capture: the random stream does not depend on visibility.
        z = self._rng.standard_normal((N, 3))
        u = self._rng.random(N)
        z_out = self._rng.standard_normal((N, 3))
        if not self.field.images:
            vis = np.zeros((N, 0), dtype=bool)
            dist = np.zeros((N, 0))
        else:
            vis, dist = image_visibility(camera_poses(robot_pose, cfg.mount_pose), self.field,
                                         cfg.field_of_view, cfg.max_range)
        visible = vis.any(axis=1)
        masked = np.where(vis, dist, np.inf)
        index = np.where(visible, np.argmin(masked, axis=1) if vis.shape[1] else -1, -1)
        d = np.where(visible, masked[np.arange(N), np.maximum(index, 0)] if vis.shape[1] else np.nan,
                     np.nan)
        var = np.column_stack([cfg.position_noise.variance(d), cfg.position_noise.variance(d),
                               cfg.yaw_noise.variance(d)])  # eq. 32
        outlier = visible & (u < cfg.outlier_probability)
        extra = z_out * np.array([cfg.outlier_position_std, cfg.outlier_position_std, cfg.outlier_yaw_std])
        pose = robot_pose + np.sqrt(var) * z + np.where(outlier[:, None], extra, 0.0)
        pose[:, 2] = wrap_angles(pose[:, 2])
        cov = np.zeros((N, 3, 3))
        idx = np.arange(3)
        cov[:, idx, idx] = var
        pose[~visible] = np.nan
        cov[~visible] = np.nan
        return CameraReading(t_ns, t_ns + cfg.latency_ns, visible, pose, cov,
                             index.astype(np.int64), d, outlier)
