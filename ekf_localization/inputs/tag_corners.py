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
undistorted pixels), with R = ``pixel_variance`` I. The Jacobian (checked against central
differences in test/test_tag_corners_input.py), with d_k = X_k - t and c, s = cos θ, sin θ:

    ∂(Rz^T d)/∂x = (-c, s, 0),  ∂/∂y = (-s, -c, 0),  ∂/∂θ = (-s d_x + c d_y, -c d_x - s d_y, 0)
    ∂X_c/∂· = R_bc^T ∂(Rz^T d)/∂·,   ∂u/∂X_c = (fx/z, 0, -fx x/z²),  ∂v/∂X_c = (0, fy/z, -fy y/z²)

One input per tag (the model is fixed per input, as a landmark's position is).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ekf_localization.core.measurements import REJECT_FRAME, REJECT_IMPLAUSIBLE, REJECT_NONFINITE
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.inputs.kind import ParameterSpec, fusion_kind
from ekf_localization.inputs.parts import VARIANCE_SCALE
from ekf_localization.vision import camera_geometry
from ekf_localization.vision.camera_geometry import mount_rotation_translation as camera_rotation_translation

_X, _Y, _YAW = 0, 1, 5  # RL fields the measurement needs in the state
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


@dataclass(frozen=True)
class TagCorners:
    """The fusion of one tag_cornersN input (its parameters' values)."""

    corners: tuple[float, ...]
    camera: tuple[float, float, float, float]
    camera_mount: tuple[float, ...]
    pixel_variance: float
    camera_frame: str = ""
    part: str = "tag_corners"

    def measurement_model(self, field_to_state: Mapping[int, int],
                          n: int) -> tuple[TagCornerMeasurement, tuple[int, ...]]:
        missing = [f for f in (_X, _Y, _YAW) if f not in field_to_state]
        if missing:
            raise ValueError("a tag's corner pixels need x, y and yaw in the state")
        cols = (field_to_state[_X], field_to_state[_Y], field_to_state[_YAW])
        R_bc, t_bc = camera_rotation_translation(self.camera_mount)
        return TagCornerMeasurement(np.array(self.corners), self.camera, R_bc, t_bc, cols, n), ()

    def fuse(self, record: TagCornerObservation, base_frame: str) -> tuple[np.ndarray, np.ndarray] | str:
        p = np.asarray(record.corners, dtype=float)
        if p.shape != (4, 2):
            return REJECT_IMPLAUSIBLE
        if not np.isfinite(p).all():
            return REJECT_NONFINITE
        if self.camera_frame and record.frame_id.strip().lstrip("/") != self.camera_frame:
            return REJECT_FRAME
        return p.reshape(8), self.pixel_variance * np.eye(8)


def fusion(values: Mapping[str, Any]) -> TagCorners:
    return TagCorners(tuple(values["corners"]), tuple(values["camera"]), tuple(values["camera_mount"]),
                      values["pixel_variance"], values["camera_frame"].strip("/ "))


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
        ParameterSpec("pixel_variance", "float", 1.0, "px²", "variance of a corner coordinate",
                      lambda v: math.isfinite(v) and v > 0.0, "a variance > 0"),
        ParameterSpec("camera_frame", "str", "", "", "the corners' frame_id (empty: any)"),
    ))
