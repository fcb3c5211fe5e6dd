"""Camera landmark sensor: the robot's field pose from a wall image (seed 000, eq. 28 and 32).

An image is seen when it is *fully* in view (seed 000: 70° field of view):

* both end points of the image segment lie inside the horizontal field of view,
  ``|bearing| <= field_of_view / 2`` measured from the camera's optical axis
  (the boundary counts as inside);
* the camera is in front of the image (on the side its normal points to);
* the distance from the camera to the image centre is at most ``max_range``.

If several images are seen, the nearest one is used. The measurement is the robot
(``base_link``) pose in the field (with ``pose_of_camera``: the camera's own pose, at its true
mount, as a camera pipeline that knows nothing of the robot reports it; the robot's software
turns it into base_link's through the mount it believes) plus Gaussian noise of variance ``a·d² + b`` per
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
    pose_of_camera: bool = False  # measure the camera's pose (at mount_pose), not base_link's

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
    camera: int = 0  # which camera: 0 the first (``camera``), 1 the second (``camera1``)


def image_visibility(cam_pose: np.ndarray, field: Field, field_of_view: float,
                     max_range: float) -> tuple[np.ndarray, np.ndarray]:
    """(N, M) "fully in view" flags and (N, M) camera-to-image-centre distances of cameras at
    the (N, 3) poses [x y yaw] (the tests of the module docstring)."""
    cam = np.asarray(cam_pose, dtype=float)
    centres, normals, ends = field.image_arrays()
    r = centres - cam[:, None, :2]  # (N, M, 2) camera -> image centre
    distance = np.hypot(r[..., 0], r[..., 1])
    in_front = -(r[..., 0] * normals[:, 0] + r[..., 1] * normals[:, 1]) > 0.0
    fx, fy = np.cos(cam[:, 2])[:, None, None], np.sin(cam[:, 2])[:, None, None]  # optical axis
    e = ends - cam[:, None, None, :2]  # (N, M, 2 ends, 2) camera -> end points
    bearing = np.arctan2(fx * e[..., 1] - fy * e[..., 0], e[..., 0] * fx + e[..., 1] * fy)
    in_fov = np.all(np.abs(bearing) <= 0.5 * field_of_view, axis=-1)
    return in_front & in_fov & (distance <= max_range), distance


class CameraSensor:
    """Captures noisy pose measurements of the nearest fully visible image."""

    def __init__(self, config: CameraConfig, field: Field, n_trials: int,
                 rng: np.random.Generator, index: int = 0) -> None:
        self.config = config
        self.index = index  # the readings' ``camera``
        self.field = field
        self.n = n_trials
        self._rng = rng
        self._mount = np.array(config.mount_pose, dtype=float)
        self._outlier_std = np.array([config.outlier_position_std, config.outlier_position_std,
                                      config.outlier_yaw_std])

    def capture(self, t_ns: int, robot_pose: np.ndarray) -> CameraReading:
        """The reading of a capture at ``t_ns`` by the robots at the (N, 3) poses ``robot_pose``."""
        cfg = self.config
        N = self.n
        # Fixed number of draws per capture: the random stream does not depend on visibility.
        z = self._rng.standard_normal((N, 3))
        u = self._rng.random(N)
        z_out = self._rng.standard_normal((N, 3))
        pose = np.asarray(robot_pose, dtype=float)
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        mx, my, myaw = self._mount
        cam = np.column_stack([pose[:, 0] + c * mx - s * my, pose[:, 1] + s * mx + c * my,
                               pose[:, 2] + myaw])  # the camera in the field
        seen, distance = image_visibility(cam, self.field, cfg.field_of_view, cfg.max_range)
        seen_distance = np.where(seen, distance, np.inf)
        visible = seen.any(axis=1)
        d = np.where(visible, np.min(seen_distance, axis=1, initial=np.inf), np.nan)  # the nearest
        nearest = np.argmin(seen_distance, axis=1) if seen.shape[1] else np.zeros(N, dtype=np.intp)
        index = np.where(visible, nearest, -1)  # the first of equally near ones
        var = np.column_stack([cfg.position_noise.variance(d), cfg.position_noise.variance(d),
                               cfg.yaw_noise.variance(d)])  # eq. 32 per x, y, θ
        outlier = visible & (u < cfg.outlier_probability)
        measured = (cam if cfg.pose_of_camera else pose) + np.sqrt(var) * z  # eq. 28 + noise
        measured = np.where(outlier[:, None], measured + z_out * self._outlier_std, measured)
        measured[:, 2] = wrap_angles(measured[:, 2])
        cov = var[:, :, None] * np.eye(3)  # NaN where not visible, as the pose
        return CameraReading(t_ns, t_ns + cfg.latency_ns, visible, measured, cov, index, d, outlier,
                             self.index)
