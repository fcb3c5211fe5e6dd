"""``tag_cornersN``: the four corner pixels of one AprilTag, fused directly (no PnP pose).

The message is geometry_msgs/PolygonStamped: the tag's corners (u, v) in pixels (x = u right,
y = v down, z unused), in the detector's order bl, br, tr, tl (vision/tag_layout.py), its
``frame_id`` the camera's optical frame (``tag_cornersN_camera_frame``; empty: any). It is
fused as the nonlinear measurement

    z = [u_bl, v_bl, u_br, v_br, u_tr, v_tr, u_tl, v_tl]
    h(x) = project(X_c,k),   X_c,k = R_bc^T (Rz(θ)^T (X_k - t) - t_bc),   t = (x, y, 0)

of the layout's corners X_k (``tag_cornersN_corners``, map frame) from the predicted planar
pose (x, y, θ) through the camera mount (``tag_cornersN_camera_mount``: the camera body frame,
x forward, z up, in base_link; its optical frame z forward, x right, y down) and the pinhole
(vision/camera_geometry.py) of the intrinsics (``tag_cornersN_camera``: fx, fy, cx, cy;
undistorted pixels). R is the corner noise model's 8x8 covariance of the tag
(vision/corner_noise.py, the one tag_localizer's PnP covariance uses: own noise, a shift shared
by the four corners, both grown along the motion blur), its blur the corners' motion over
``exposure_time`` at the filter's estimate and velocity at the stamp (the model's unknown-motion
blur without them); with ``diagonal_covariance`` R = ``pixel_variance`` I. The residual
check (docs/models.md, "Tag corners and the residual check"): an innovation whose NIS at the
filter's prior exceeds the χ²(8) quantile at ``corner_noise.RESIDUAL_CHECK_MASS`` has R scaled
by NIS / 8, as PnP's fit scales its covariance (counted in the input's ``widened``).

The Jacobian (checked against central differences in test/test_tag_corners_input.py), with
d_k = X_k - t and c, s = cos θ, sin θ:

    ∂(Rz^T d)/∂x = (-c, s, 0),  ∂/∂y = (-s, -c, 0),  ∂/∂θ = (-s d_x + c d_y, -c d_x - s d_y, 0)
    ∂X_c/∂· = R_bc^T ∂(Rz^T d)/∂·,   ∂u/∂X_c = (fx/z, 0, -fx x/z²),  ∂v/∂X_c = (0, fy/z, -fy y/z²)

One input per tag (the model is fixed per input, as a landmark's position is).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ekf_localization.core.measurements import REJECT_FRAME, REJECT_IMPLAUSIBLE, REJECT_NONFINITE
from ekf_localization.core.outcomes import Estimate
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.inputs.kind import ParameterSpec, fusion_kind
from ekf_localization.inputs.parts import VARIANCE_SCALE
from ekf_localization.vision import camera_geometry
from ekf_localization.vision.camera_geometry import mount_rotation_translation as camera_rotation_translation
from ekf_localization.vision.corner_noise import CornerNoise, residual_bound

_X, _Y, _YAW = 0, 1, 5  # RL fields the measurement needs in the state
_VX, _VY, _VYAW = 6, 7, 11  # body velocities: the motion blur, when the state has them
_NOISE = CornerNoise()  # the model's defaults: the parameters' defaults
MIN_DEPTH = 1e-3  # m: a predicted corner closer to the image plane is held there (no division by 0)


@dataclass(frozen=True, eq=False)
class TagCornerObservation:
    """The four corner pixels (4, 2) of one tag in ``frame_id`` (the camera), at ``stamp_ns``."""

    stamp_ns: int
    frame_id: str
    corners: np.ndarray


def read(msg) -> TagCornerObservation:
    pts = msg.polygon.points
    return TagCornerObservation(stamp_to_ns(msg.header.stamp), str(msg.header.frame_id),
                                np.array([[float(p.x), float(p.y)] for p in pts], dtype=float).reshape(-1, 2))


class TagCornerMeasurement:
    """h(x) and its Jacobian on a planar state whose x, y, θ are the columns ``cols`` (module docstring)."""

    m = 8
    z_is_angle = np.zeros(8, dtype=bool)

    def __init__(self, corners: np.ndarray, camera: tuple[float, float, float, float],
                 R_bc: np.ndarray, t_bc: np.ndarray, cols: tuple[int, int, int], n: int) -> None:
        self.corners = np.asarray(corners, dtype=float).reshape(4, 3)
        self.camera = tuple(camera)   # fx, fy, cx, cy
        self.R_bc, self.t_bc = R_bc, t_bc
        self.cols, self.n = cols, n

    def _camera_points(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        ix, iy, ith = self.cols
        c, s = np.cos(X[:, ith])[:, None], np.sin(X[:, ith])[:, None]
        dx = self.corners[None, :, 0] - X[:, ix, None]                      # (N, 4)
        dy = self.corners[None, :, 1] - X[:, iy, None]
        dz = np.broadcast_to(self.corners[None, :, 2], dx.shape)
        body = np.stack([c * dx + s * dy, -s * dx + c * dy, dz], axis=-1)  # Rz^T d, (N, 4, 3)
        Xc = (body - self.t_bc) @ self.R_bc
        return Xc, c, s, np.stack([dx, dy], axis=-1)

    def h(self, X: np.ndarray) -> np.ndarray:
        Xc, _, _, _ = self._camera_points(X)
        return camera_geometry.project(Xc, self.camera, MIN_DEPTH).reshape(X.shape[0], 8)

    def jacobian(self, X: np.ndarray) -> np.ndarray:
        Xc, c, s, d = self._camera_points(X)
        N = X.shape[0]
        zeros = np.zeros_like(d[..., 0])
        # ∂(Rz^T d)/∂(x, y, θ): (N, 4, 3 components, 3 variables)
        dbody = np.stack([
            np.stack([-c + zeros, s + zeros, zeros], axis=-1),
            np.stack([-s + zeros, -c + zeros, zeros], axis=-1),
            np.stack([-s * d[..., 0] + c * d[..., 1], -c * d[..., 0] - s * d[..., 1], zeros], axis=-1),
        ], axis=-1)
        dXc = np.einsum("ji,nkjv->nkiv", self.R_bc, dbody)                 # R_bc^T ∂body
        duv = camera_geometry.projection_jacobian(Xc, self.camera, MIN_DEPTH) @ dXc   # (N, 4, 2, 3)
        H = np.zeros((N, 8, self.n))
        H[:, :, list(self.cols)] = duv.reshape(N, 8, 3)
        return H


def image_blur(model: TagCornerMeasurement, pose: np.ndarray, velocity: np.ndarray,
               exposure_time: float) -> np.ndarray:
    """(2,) mean pixel motion of the tag's corners over the exposure, the robot at planar ``pose``
    (x, y, θ; the exposure's middle) moving at ``velocity`` (d pose / dt, map frame); ``model``
    on a 3-state (x, y, θ)."""
    half = 0.5 * exposure_time * np.asarray(velocity, dtype=float)
    uv = model.h(np.stack([pose - half, pose + half]))
    return (uv[1] - uv[0]).reshape(4, 2).mean(axis=0)


def model_covariance(noise: CornerNoise, model: TagCornerMeasurement, pose: np.ndarray | None,
                     velocity: np.ndarray | None) -> np.ndarray:
    """The corner noise model's 8x8 R of the tag seen from planar ``pose`` moving at ``velocity``
    (map frame); no blur without an exposure, the model's unknown-motion blur without a motion."""
    if noise.exposure_time <= 0.0:
        blur = np.zeros(2)
    elif pose is None or velocity is None:
        blur = noise.unknown_blurs(1)[0]
    else:
        blur = image_blur(model, pose, velocity, noise.exposure_time)
    return noise.tag_covariance(blur)


def _pose_and_velocity(estimate: Estimate | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The estimate's planar pose and its map-frame velocity (None when it lacks them)."""
    if estimate is None or not estimate.is_finite():
        return None, None
    at = {f: i for i, f in enumerate(estimate.state_fields)}
    if any(f not in at for f in (_X, _Y, _YAW)):
        return None, None
    x = estimate.state
    pose = np.array([x[at[_X]], x[at[_Y]], x[at[_YAW]]])
    if any(f not in at for f in (_VX, _VY, _VYAW)):
        return pose, None
    c, s = math.cos(pose[2]), math.sin(pose[2])
    vx, vy = x[at[_VX]], x[at[_VY]]
    return pose, np.array([c * vx - s * vy, s * vx + c * vy, x[at[_VYAW]]])


@dataclass(frozen=True)
class TagCorners:
    """The fusion of one tag_cornersN input (its parameters' values)."""

    corners: tuple[float, ...]
    camera: tuple[float, float, float, float]
    camera_mount: tuple[float, ...]
    pixel_variance: float
    camera_frame: str = ""
    noise: CornerNoise = _NOISE
    diagonal_covariance: bool = False
    part: str = "tag_corners"
    uses_estimate = True  # FusionHandler passes the filter's estimate at the stamp to ``fuse``

    @property
    def widen_above(self) -> float:
        """The residual check's NIS bound: χ²(8)'s quantile at RESIDUAL_CHECK_MASS."""
        return residual_bound(TagCornerMeasurement.m)

    def _model(self, cols: tuple[int, ...], n: int) -> TagCornerMeasurement:
        R_bc, t_bc = camera_rotation_translation(self.camera_mount)
        return TagCornerMeasurement(np.array(self.corners), self.camera, R_bc, t_bc, cols, n)

    @functools.cached_property
    def _planar_model(self) -> TagCornerMeasurement:
        """The model on a 3-state (x, y, θ): the motion blur's corner motion."""
        return self._model((0, 1, 2), 3)

    def measurement_model(self, field_to_state: Mapping[int, int],
                          n: int) -> tuple[TagCornerMeasurement, tuple[int, ...]]:
        missing = [f for f in (_X, _Y, _YAW) if f not in field_to_state]
        if missing:
            raise ValueError("a tag's corner pixels need x, y and yaw in the state")
        return self._model((field_to_state[_X], field_to_state[_Y], field_to_state[_YAW]), n), ()

    def fuse(self, record: TagCornerObservation, base_frame: str,
             estimate: Estimate | None = None) -> tuple[np.ndarray, np.ndarray] | str:
        p = np.asarray(record.corners, dtype=float)
        if p.shape != (4, 2):
            return REJECT_IMPLAUSIBLE
        if not np.isfinite(p).all():
            return REJECT_NONFINITE
        if self.camera_frame and record.frame_id.strip().lstrip("/") != self.camera_frame:
            return REJECT_FRAME
        if self.diagonal_covariance:
            return p.reshape(8), self.pixel_variance * np.eye(8)
        R = model_covariance(self.noise, self._planar_model, *_pose_and_velocity(estimate))
        return p.reshape(8), R


def fusion(values: Mapping[str, Any]) -> TagCorners:
    noise = CornerNoise(values["pixel_std"], values["tag_shift_std"], values["blur_std_per_px"],
                        values["exposure_time"], values["unknown_motion_blur_px"])
    return TagCorners(tuple(values["corners"]), tuple(values["camera"]), tuple(values["camera_mount"]),
                      values["pixel_variance"], values["camera_frame"].strip("/ "), noise,
                      values["diagonal_covariance"])


def _non_negative(v: float) -> bool:
    return math.isfinite(v) and v >= 0.0


def _finite(v: list[float], n: int) -> bool:
    return len(v) == n and all(math.isfinite(x) for x in v)


KIND = fusion_kind(
    "tag_corners", "geometry_msgs/msg/PolygonStamped", read, "tag_corners", fusion, common=(VARIANCE_SCALE,),
    parameters=(
        ParameterSpec("corners", "float_list", None, "m",
                      "the tag's corners in the world frame, bl br tr tl: [x, y, z] x 4 "
                      "(vision/tag_layout.py Tag.corners_map)",
                      lambda v: _finite(v, 12), "a list of 12 finite floats", required=True),
        ParameterSpec("camera", "float_list", None, "px", "intrinsics [fx, fy, cx, cy] (undistorted pixels)",
                      lambda v: _finite(v, 4) and v[0] > 0 and v[1] > 0,
                      "a list of 4 finite floats, fx, fy > 0", required=True),
        ParameterSpec("camera_mount", "float_list", [0.0] * 6, "m, rad",
                      "the camera body frame (x forward, z up) in base_link: [x, y, z, roll, pitch, yaw]",
                      lambda v: _finite(v, 6), "a list of 6 finite floats"),
        ParameterSpec("diagonal_covariance", "bool", False, "",
                      "R = pixel_variance I (each coordinate independent) instead of the corner noise "
                      "model's 8x8 covariance (vision/corner_noise.py)"),
        ParameterSpec("pixel_variance", "float", 1.0, "px²",
                      "with diagonal_covariance: variance of a corner coordinate",
                      lambda v: math.isfinite(v) and v > 0.0, "a variance > 0"),
        ParameterSpec("pixel_std", "float", _NOISE.pixel_std, "px",
                      "corner noise model: std of a corner's own error (each axis), as tag_localizer's",
                      lambda v: math.isfinite(v) and v > 0.0, "a std > 0"),
        ParameterSpec("tag_shift_std", "float", _NOISE.tag_shift_std, "px",
                      "corner noise model: std of the error shared by the tag's four corners (each axis)",
                      _non_negative, "a std >= 0"),
        ParameterSpec("blur_std_per_px", "float", _NOISE.blur_std_per_px, "px/px",
                      "corner noise model: std added along the image motion per px of motion blur",
                      _non_negative, "a value >= 0"),
        ParameterSpec("exposure_time", "float", _NOISE.exposure_time, "s",
                      "corner noise model: the camera's exposure, over which the image moves (0: no blur)",
                      _non_negative, "a time >= 0"),
        ParameterSpec("unknown_motion_blur_px", "float", _NOISE.unknown_motion_blur_px, "px",
                      "corner noise model: blur along the image rows when the filter has no velocity",
                      _non_negative, "a value >= 0"),
        ParameterSpec("camera_frame", "str", "", "", "the corners' frame_id (empty: any)"),
    ))
