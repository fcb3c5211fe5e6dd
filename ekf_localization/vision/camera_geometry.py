"""Camera geometry: the optical frame, the pinhole projection, lens distortion (docs/models.md).

The one module that projects: tag PnP, the ``tag_corners`` input, the CameraInfo reader and
the simulator's renderer call these; no other module writes the optical rotation, a depth
division or a distortion formula (``test/test_camera_geometry.py``).

Frames (REP-103): a camera *body* frame has x forward, y left, z up; its *optical* frame
(``*_optical``) has z forward, x right, y down. Pixels are (u right, v down) with the pixel
centre at integer coordinates. ``intrinsics`` are (fx, fy, cx, cy) of CameraInfo's K.

Equations (docs/models.md, "Camera geometry"), for a point X_c = (X, Y, Z) in the optical frame:

    x = X / Z,  y = Y / Z,                         u = fx x + cx,  v = fy y + cy    (pinhole)
    r² = x² + y²
    plumb_bob, rational_polynomial (k1 k2 p1 p2 k3 [k4 k5 k6], CameraInfo's D order):
        s = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)
        x' = x s + 2 p1 x y + p2 (r² + 2 x²),  y' = y s + p1 (r² + 2 y²) + 2 p2 x y
    equidistant (fisheye, k1 k2 k3 k4):
        θ = atan(r),  θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸),  (x', y') = (θ_d / r) (x, y)

and the distorted pixel is u' = fx x' + cx, v' = fy y' + cy. These are OpenCV's
``projectPoints`` and ``fisheye.projectPoints`` (checked against them in the test);
undistortion is OpenCV's iterative inverse (``undistortPointsIter`` in OpenCV 4, ``undistortPoints``
with its criteria in 5, ``fisheye.undistortPoints``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ekf_localization.core.angles import rpy_to_matrix

# The optical frame's axes in the camera body frame (R body <- optical): z_opt = x_body,
# x_opt = -y_body, y_opt = -z_body.
OPTICAL_IN_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
OPTICAL_IN_BODY.setflags(write=False)

# CameraInfo's distortion models (sensor_msgs/distortion_models.hpp) and the names of their
# coefficients, in D's order ("" is a camera without distortion: D empty).
PLUMB_BOB, RATIONAL_POLYNOMIAL, EQUIDISTANT = "plumb_bob", "rational_polynomial", "equidistant"
DISTORTION_COEFFICIENTS: dict[str, tuple[str, ...]] = {
    "": (),
    PLUMB_BOB: ("k1", "k2", "p1", "p2", "k3"),
    RATIONAL_POLYNOMIAL: ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    EQUIDISTANT: ("k1", "k2", "k3", "k4"),
}
DISTORTION_MODELS = tuple(DISTORTION_COEFFICIENTS)

# Undistortion iterates to convergence (OpenCV's default for undistortPoints is 5 fixed
# iterations, which leaves visible errors towards the corners of a strongly distorted image).
_UNDISTORT_ITERATIONS = 100
_UNDISTORT_EPS = 1e-12


def mount_rotation_translation(mount: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """R_bc, t_bc of the optical frame in base_link from the body mount [x, y, z, roll, pitch, yaw]."""
    return rpy_to_matrix(*mount[3:6]) @ OPTICAL_IN_BODY, np.array(mount[:3], dtype=float)


def optical_pose(body_pose: np.ndarray) -> np.ndarray:
    """parent <- optical (4x4) of a camera whose body frame (x forward, z up) is ``body_pose``."""
    T = np.array(body_pose, dtype=float)
    T[:3, :3] = T[:3, :3] @ OPTICAL_IN_BODY
    return T


def distortion_coefficients(model: str, coefficients: Sequence[float]) -> tuple[float, ...]:
    """``coefficients`` (CameraInfo's D) of ``model`` as a full tuple (missing ones 0.0), or a
    ValueError naming what is wrong: an unknown model, non-finite or surplus non-zero
    coefficients, D given without a model, or an equidistant D that is not 4 numbers."""
    if model not in DISTORTION_COEFFICIENTS:
        raise ValueError(f"distortion model {model!r} is not supported "
                         f"({' or '.join(m for m in DISTORTION_MODELS if m)})")
    d = tuple(float(v) for v in coefficients)
    if not all(np.isfinite(d)):
        raise ValueError(f"distortion coefficients must be finite, got {d}")
    names = DISTORTION_COEFFICIENTS[model]
    if model == "" and d:
        raise ValueError("distortion coefficients without a distortion model")
    if model == EQUIDISTANT and len(d) not in (0, 4):
        raise ValueError(f"equidistant distortion takes 4 coefficients (k1..k4), got {len(d)}")
    if any(d[len(names):]):
        raise ValueError(f"{model} takes {len(names)} coefficients ({' '.join(names)}); "
                         f"the others must be 0, got {d}")
    return (d + (0.0,) * len(names))[:len(names)]


def project(points: np.ndarray, intrinsics: Sequence[float], min_depth: float | None = None) -> np.ndarray:
    """(..., 2) ideal (undistorted) pixels of (..., 3) optical-frame points; a depth below
    ``min_depth`` (when given) is held at it."""
    fx, fy, cx, cy = intrinsics
    p = np.asarray(points, dtype=float)
    z = p[..., 2] if min_depth is None else np.maximum(p[..., 2], min_depth)
    return np.stack([fx * p[..., 0] / z + cx, fy * p[..., 1] / z + cy], axis=-1)


def projection_jacobian(points: np.ndarray, intrinsics: Sequence[float],
                        min_depth: float | None = None) -> np.ndarray:
    """(..., 2, 3) d(u, v)/d(X, Y, Z) of :func:`project` at (..., 3) optical-frame points:
    [[fx/Z, 0, -fx X/Z²], [0, fy/Z, -fy Y/Z²]] (Z held at ``min_depth`` as in project)."""
    fx, fy = intrinsics[0], intrinsics[1]
    p = np.asarray(points, dtype=float)
    z = p[..., 2] if min_depth is None else np.maximum(p[..., 2], min_depth)
    J = np.zeros(p.shape[:-1] + (2, 3))
    J[..., 0, 0] = fx / z
    J[..., 0, 2] = -fx * p[..., 0] / z**2
    J[..., 1, 1] = fy / z
    J[..., 1, 2] = -fy * p[..., 1] / z**2
    return J


def pixel_rays(pixels: np.ndarray, intrinsics: Sequence[float]) -> np.ndarray:
    """(..., 3) optical-frame rays (x, y, 1) through (..., 2) ideal pixels: project's inverse."""
    fx, fy, cx, cy = intrinsics
    px = np.asarray(pixels, dtype=float)
    x, y = (px[..., 0] - cx) / fx, (px[..., 1] - cy) / fy
    return np.stack([x, y, np.ones_like(x)], axis=-1)


def _distort_normalized(x: np.ndarray, y: np.ndarray, model: str,
                        d: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(x', y') of normalized ideal coordinates (x, y) under ``model`` (full coefficients ``d``)."""
    r2 = x * x + y * y
    if model == EQUIDISTANT:
        k1, k2, k3, k4 = d
        r = np.sqrt(r2)
        theta = np.arctan(r)
        t2 = theta * theta
        theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        scale = np.divide(theta_d, r, out=np.ones_like(r), where=r > 0.0)   # -> 1 on the axis
        return x * scale, y * scale
    k1, k2, p1, p2, k3, k4, k5, k6 = d + (0.0,) * (8 - len(d))
    radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


def project_distorted(points: np.ndarray, intrinsics: Sequence[float], model: str,
                      coefficients: Sequence[float]) -> np.ndarray:
    """(..., 2) pixels of (..., 3) optical-frame points (Z > 0) through the lens ``model``."""
    d = distortion_coefficients(model, coefficients)
    if not any(d):
        return project(points, intrinsics)
    fx, fy, cx, cy = intrinsics
    p = np.asarray(points, dtype=float)
    xd, yd = _distort_normalized(p[..., 0] / p[..., 2], p[..., 1] / p[..., 2], model, d)
    return np.stack([fx * xd + cx, fy * yd + cy], axis=-1)


def distort_pixels(pixels: np.ndarray, intrinsics: Sequence[float], model: str,
                   coefficients: Sequence[float]) -> np.ndarray:
    """(..., 2) pixels of the distorted camera of (..., 2) ideal pixels (the pinhole, same K)."""
    px = np.asarray(pixels, dtype=float)
    if not any(distortion_coefficients(model, coefficients)):
        return px.copy()
    return project_distorted(pixel_rays(px, intrinsics), intrinsics, model, coefficients)


def undistort_pixels(pixels: np.ndarray, intrinsics: Sequence[float], model: str,
                     coefficients: Sequence[float]) -> np.ndarray:
    """(..., 2) ideal pixels (the pinhole, same K) of (..., 2) pixels of the distorted camera:
    :func:`distort_pixels`' inverse, by OpenCV (iterated to convergence)."""
    px = np.asarray(pixels, dtype=float)
    d = distortion_coefficients(model, coefficients)
    if not any(d):
        return px.copy()
    import cv2

    fx, fy, cx, cy = intrinsics
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    src = px.reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, _UNDISTORT_ITERATIONS, _UNDISTORT_EPS)
    if model == EQUIDISTANT:
        out = cv2.fisheye.undistortPoints(src, K, np.array(d), R=np.eye(3), P=K, criteria=criteria)
    else:
        iterated = getattr(cv2, "undistortPointsIter", None)  # OpenCV 4 (criteria); 5: undistortPoints
        out = iterated(src, K, np.array(d), np.eye(3), K, criteria) if iterated is not None \
            else cv2.undistortPoints(src, K, np.array(d), R=np.eye(3), P=K, criteria=criteria)
    return out.reshape(px.shape)
