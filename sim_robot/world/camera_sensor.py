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

from ekf_localization.core.kernels import njit, source_stamp, wrap
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


@njit(cache=True)
def _in_view(cx: float, cy: float, fx: float, fy: float, centres: np.ndarray, normals: np.ndarray,
             ends: np.ndarray, m: int, half: float,
             max_range: float) -> tuple[bool, float]:  # pragma: no cover - compiled
    """(fully in view, distance to its centre) of image m from a camera at (cx, cy) facing (fx, fy)."""
    rx = centres[m, 0] - cx
    ry = centres[m, 1] - cy
    distance = math.hypot(rx, ry)
    seen = -(rx * normals[m, 0] + ry * normals[m, 1]) > 0.0 and distance <= max_range
    for e in range(2):
        ex = ends[m, e, 0] - cx
        ey = ends[m, e, 1] - cy
        seen = seen and abs(math.atan2(fx * ey - fy * ex, ex * fx + ey * fy)) <= half
    return seen, distance


@njit(cache=True)
def _visibility(cam, centres, normals, ends, half, max_range, vis, dist):  # pragma: no cover - compiled
    for b in range(cam.shape[0]):
        fx = math.cos(cam[b, 2])
        fy = math.sin(cam[b, 2])
        for m in range(centres.shape[0]):
            vis[b, m], dist[b, m] = _in_view(cam[b, 0], cam[b, 1], fx, fy, centres, normals, ends, m, half,
                                             max_range)


def image_visibility(cam_pose: np.ndarray, field: Field, field_of_view: float,
                     max_range: float) -> tuple[np.ndarray, np.ndarray]:
    """(N, M) "fully in view" flags and (N, M) camera-to-image-centre distances."""
    cam = np.ascontiguousarray(cam_pose, dtype=float)
    centres, normals, ends = field.image_arrays()
    vis = np.zeros((cam.shape[0], centres.shape[0]), dtype=np.bool_)
    dist = np.zeros((cam.shape[0], centres.shape[0]))
    _visibility(cam, centres, normals, ends, 0.5 * field_of_view, float(max_range), vis, dist)
    return vis, dist


def _make_capture(stamp: str):
    """The compiled capture of every trial (wraps with core.kernels' wrap: keyed by ``stamp``)."""

    @njit(cache=True)
    def capture(pose, mount, centres, normals, ends, half, max_range, noise, outlier_p, outlier_std, z, u,
                z_out, visible, index, d, out, cov, outlier):  # pragma: no cover - compiled
        """The nearest fully visible image of each trial and its reading (see the module doc)."""
        if len(stamp) < 0:  # never true: references the stamp so that it keys the cache
            return
        cov[:, :, :] = 0.0
        for b in range(pose.shape[0]):
            c = math.cos(pose[b, 2])
            s = math.sin(pose[b, 2])
            cx = pose[b, 0] + c * mount[0] - s * mount[1]  # the camera in the field
            cy = pose[b, 1] + s * mount[0] + c * mount[1]
            cyaw = pose[b, 2] + mount[2]
            fx = math.cos(cyaw)
            fy = math.sin(cyaw)
            index[b] = -1
            best = math.inf
            for m in range(centres.shape[0]):
                seen, dm = _in_view(cx, cy, fx, fy, centres, normals, ends, m, half, max_range)
                if seen and dm < best:  # the nearest; the first of equals
                    best = dm
                    index[b] = m
            visible[b] = index[b] >= 0
            outlier[b] = visible[b] and u[b] < outlier_p
            if not visible[b]:
                d[b] = math.nan
                out[b, :] = math.nan
                cov[b, :, :] = math.nan
                continue
            d[b] = best
            for k in range(3):
                var = noise[k, 0] * best * best + noise[k, 1]  # eq. 32
                v = pose[b, k] + math.sqrt(var) * z[b, k]
                if outlier[b]:
                    v += z_out[b, k] * outlier_std[k]
                out[b, k] = wrap(v) if k == 2 else v
                cov[b, k, k] = var

    return capture


_capture = _make_capture(source_stamp(__file__))


class CameraSensor:
    """Captures noisy pose measurements of the nearest fully visible image."""

    def __init__(self, config: CameraConfig, field: Field, n_trials: int,
                 rng: np.random.Generator) -> None:
        self.config = config
        self.field = field
        self.n = n_trials
        self._rng = rng
        self._mount = np.array(config.mount_pose, dtype=float)
        self._noise = np.array([[n.distance_variance_coeff, n.variance_floor]  # eq. 32 per x, y, θ
                                for n in (config.position_noise, config.position_noise, config.yaw_noise)])
        self._outlier_std = np.array([config.outlier_position_std, config.outlier_position_std,
                                      config.outlier_yaw_std])

    def capture(self, t_ns: int, robot_pose: np.ndarray) -> CameraReading:
        cfg = self.config
        N = self.n
        # Fixed number of draws per capture: the random stream does not depend on visibility.
        z = self._rng.standard_normal((N, 3))
        u = self._rng.random(N)
        z_out = self._rng.standard_normal((N, 3))
        centres, normals, ends = self.field.image_arrays()
        visible = np.zeros(N, dtype=np.bool_)
        index = np.zeros(N, dtype=np.int64)
        d = np.zeros(N)
        pose = np.zeros((N, 3))
        cov = np.zeros((N, 3, 3))
        outlier = np.zeros(N, dtype=np.bool_)
        _capture(np.ascontiguousarray(robot_pose, dtype=float), self._mount, centres, normals, ends,
                 0.5 * cfg.field_of_view, float(cfg.max_range), self._noise, float(cfg.outlier_probability),
                 self._outlier_std, z, u, z_out, visible, index, d, pose, cov, outlier)
        return CameraReading(t_ns, t_ns + cfg.latency_ns, visible, pose, cov, index, d, outlier)
