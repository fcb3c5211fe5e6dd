"""vision/camera_geometry.py: the projection and each CameraInfo distortion model against
OpenCV's own, undistortion as their inverse, the Jacobian, the frames, and that it is the only
module of ekf_localization and sim_robot that projects."""

from __future__ import annotations

import ast
import math
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from helpers.ros_helpers import REPO

from ekf_localization.core.angles import rpy_to_matrix
from ekf_localization.ros.image_io import BadImageError, camera_info_to_pinhole
from ekf_localization.vision import camera_geometry as cg
from ekf_localization.vision.pinhole import PinholeCamera

WIDTH, HEIGHT = 640, 480
INTRINSICS = (610.0, 590.0, 322.3, 236.8)
K = np.array([[610.0, 0.0, 322.3], [0.0, 590.0, 236.8], [0.0, 0.0, 1.0]])
# realistic calibrations: a wide-angle lens (plumb_bob), the same with the rational terms, a fisheye
MODELS = {
    "plumb_bob": (-0.29, 0.085, 0.0012, -0.0009, -0.011),
    "rational_polynomial": (0.35, -0.06, 0.0012, -0.0009, 0.004, 0.66, -0.02, 0.012),
    "equidistant": (0.021, -0.013, 0.004, -0.0011),
}
TOL_PX = 1e-6


def _points(n: int = 500, seed: int = 0) -> np.ndarray:
    """(n, 3) optical-frame points whose ideal pixels fill the image and a margin around it."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform([-40.0, -40.0], [WIDTH + 40.0, HEIGHT + 40.0], (n, 2))
    z = rng.uniform(0.3, 8.0, n)
    return cg.pixel_rays(uv, INTRINSICS) * z[:, None]


def _opencv(points: np.ndarray, model: str, d: tuple[float, ...]) -> np.ndarray:
    zero = np.zeros(3)
    if model == "equidistant":
        px, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), zero, zero, K, np.array(d))
    else:
        px, _ = cv2.projectPoints(points.reshape(-1, 1, 3), zero, zero, K, np.array(d))
    return px.reshape(-1, 2)


@pytest.mark.parametrize("model", list(MODELS))
def test_distortion_matches_opencv(model: str) -> None:
    X = _points()
    d = MODELS[model]
    ours = cg.distort_pixels(cg.project(X, INTRINSICS), INTRINSICS, model, d)
    assert np.max(np.abs(ours - _opencv(X, model, d))) < TOL_PX
    direct = cg.project_distorted(X, INTRINSICS, model, d)
    assert np.max(np.abs(direct - _opencv(X, model, d))) < TOL_PX
    camera = PinholeCamera(WIDTH, HEIGHT, *INTRINSICS, d, model)
    assert np.max(np.abs(camera.project(X) - direct)) < TOL_PX
    # the distortion is real: pixels move by more than a pixel near the edges
    assert np.max(np.abs(direct - cg.project(X, INTRINSICS))) > 5.0


@pytest.mark.parametrize("model", list(MODELS))
def test_undistortion_inverts_within_the_image(model: str) -> None:
    d = MODELS[model]
    X = _points(2000, seed=1)
    ideal = cg.project(X, INTRINSICS)
    seen = cg.distort_pixels(ideal, INTRINSICS, model, d)
    inside = np.all((seen >= -0.5) & (seen <= (WIDTH - 0.5, HEIGHT - 0.5)), axis=1)
    assert inside.sum() > 1000
    back = cg.undistort_pixels(seen[inside], INTRINSICS, model, d)
    assert np.max(np.abs(back - ideal[inside])) < TOL_PX
    # and the other way round, on a grid over the whole image (corners included)
    u, v = np.meshgrid(np.linspace(-0.5, WIDTH - 0.5, 17), np.linspace(-0.5, HEIGHT - 0.5, 13))
    grid = np.stack([u, v], axis=-1)                                     # (13, 17, 2): any shape
    again = cg.distort_pixels(cg.undistort_pixels(grid, INTRINSICS, model, d), INTRINSICS, model, d)
    assert again.shape == grid.shape and np.max(np.abs(again - grid)) < TOL_PX
    camera = PinholeCamera(WIDTH, HEIGHT, *INTRINSICS, d, model)
    assert np.max(np.abs(camera.undistort(seen[inside]) - ideal[inside])) < TOL_PX


def test_no_distortion_is_the_pinhole() -> None:
    X = _points()
    ideal = cg.project(X, INTRINSICS)
    assert np.max(np.abs(ideal - _opencv(X, "plumb_bob", (0.0,) * 5))) < TOL_PX
    for model in cg.DISTORTION_MODELS:
        n = len(cg.DISTORTION_COEFFICIENTS[model])
        assert np.array_equal(cg.project_distorted(X, INTRINSICS, model, (0.0,) * n), ideal)
        assert np.array_equal(cg.undistort_pixels(ideal, INTRINSICS, model, ()), ideal)


def test_projection_is_vectorised_and_its_jacobian_is_the_derivative() -> None:
    X = _points(24, seed=2).reshape(2, 3, 4, 3)
    uv = cg.project(X, INTRINSICS)
    assert uv.shape == (2, 3, 4, 2)
    assert np.array_equal(uv.reshape(-1, 2), cg.project(X.reshape(-1, 3), INTRINSICS))
    J = cg.projection_jacobian(X, INTRINSICS)
    assert J.shape == (2, 3, 4, 2, 3)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        numeric = (cg.project(X + e, INTRINSICS) - cg.project(X - e, INTRINSICS)) / (2 * h)
        assert np.allclose(J[..., k], numeric, rtol=1e-6, atol=1e-6)
    # back-projection: the ray through a pixel projects onto it
    assert np.allclose(cg.project(cg.pixel_rays(uv, INTRINSICS), INTRINSICS), uv, atol=1e-9)


def test_min_depth_holds_a_point_off_the_image_plane() -> None:
    X = np.array([[0.1, -0.2, 0.0], [0.1, -0.2, -1.0], [0.1, -0.2, 2.0]])
    uv = cg.project(X, INTRINSICS, min_depth=1e-3)
    J = cg.projection_jacobian(X, INTRINSICS, min_depth=1e-3)
    assert np.all(np.isfinite(uv)) and np.all(np.isfinite(J))
    assert np.array_equal(uv[0], uv[1])
    assert np.array_equal(uv[2], cg.project(X[2], INTRINSICS))


def test_the_optical_frame() -> None:
    R = cg.OPTICAL_IN_BODY
    assert np.allclose(R @ R.T, np.eye(3)) and math.isclose(np.linalg.det(R), 1.0)
    # optical z (forward) is body x, optical x (right) is body -y, optical y (down) is body -z
    assert np.array_equal(R @ [0, 0, 1], [1, 0, 0])
    assert np.array_equal(R @ [1, 0, 0], [0, -1, 0])
    assert np.array_equal(R @ [0, 1, 0], [0, 0, -1])
    mount = (0.1, 0.02, 0.25, 0.05, -0.1, 0.3)
    R_bc, t_bc = cg.mount_rotation_translation(mount)
    assert np.allclose(R_bc, rpy_to_matrix(*mount[3:]) @ R) and np.array_equal(t_bc, mount[:3])
    body = np.eye(4)
    body[:3, :3], body[:3, 3] = rpy_to_matrix(*mount[3:]), mount[:3]
    T = cg.optical_pose(body)
    assert np.allclose(T[:3, :3], R_bc) and np.array_equal(T[:3, 3], mount[:3])
    with pytest.raises(ValueError):
        R[0, 0] = 1.0                                                    # a constant


def test_bad_distortion_is_named() -> None:
    cases = {("fisheye", ()): "not supported", ("", (0.1,)): "without a distortion model",
             ("equidistant", (0.1, 0.0, 0.0, 0.0, 0.0)): "4 coefficients",
             ("plumb_bob", (0.1, 0, 0, 0, 0, 0.2)): "the others must be 0",
             ("rational_polynomial", (0.1, math.nan)): "finite"}
    for (model, d), message in cases.items():
        with pytest.raises(ValueError, match=message):
            cg.distortion_coefficients(model, d)
        with pytest.raises(ValueError, match=message):
            PinholeCamera(WIDTH, HEIGHT, *INTRINSICS, d, model)
    assert cg.distortion_coefficients("plumb_bob", (0.1,)) == (0.1, 0.0, 0.0, 0.0, 0.0)
    assert cg.distortion_coefficients("equidistant", ()) == (0.0,) * 4


def test_camera_info_takes_every_model() -> None:
    base = dict(k=[610.0, 0, 322.3, 0, 590.0, 236.8, 0, 0, 1], width=WIDTH, height=HEIGHT)
    for model, d in MODELS.items():
        cam = camera_info_to_pinhole(SimpleNamespace(**base, d=list(d), distortion_model=model))
        assert (cam.distortion_model, cam.distortion) == (model, d)
    for model, d in (("equidistant", [0.1, 0, 0]), ("rational_polynomial", [0.0] * 8 + [0.1])):
        with pytest.raises(BadImageError) as e:
            camera_info_to_pinhole(SimpleNamespace(**base, d=d, distortion_model=model))
        assert e.value.reason == "bad_camera_info"


# --- the projection is defined once -------------------------------------------------------

PACKAGES = ("ekf_localization", "sim_robot")
GEOMETRY_MODULE = "ekf_localization/vision/camera_geometry.py"
_COEFFICIENTS = {"k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2"}
_DEPTH_NAMES = {"z", "Z", "depth"}


def _number(node: ast.AST) -> float | None:
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        v = _number(node.operand)
        return None if v is None else -v
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        return float(node.value)
    return None


def _matrix(node: ast.AST) -> list[list[float | None]] | None:
    """A 3x3 literal of numbers (nested lists or tuples) as rows, else None."""
    if not (isinstance(node, ast.List | ast.Tuple) and len(node.elts) == 3):
        return None
    rows = [r.elts for r in node.elts if isinstance(r, ast.List | ast.Tuple) and len(r.elts) == 3]
    return [[_number(e) for e in r] for r in rows] if len(rows) == 3 else None


def _is_depth(node: ast.AST) -> bool:
    """``p[..., 2]``, ``p[:, 2]``, ``p[2]``, ``z``, ``p.z``, ``depth`` (or its square)."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow):
        return _is_depth(node.left)
    if isinstance(node, ast.Subscript):
        index = node.slice.elts[-1] if isinstance(node.slice, ast.Tuple) and node.slice.elts else node.slice
        if isinstance(index, ast.Slice):
            index = index.lower
        return index is not None and _number(index) == 2
    if isinstance(node, ast.Name):
        return node.id in _DEPTH_NAMES
    return isinstance(node, ast.Attribute) and node.attr in _DEPTH_NAMES


def _projection_code(tree: ast.Module) -> list[str]:
    """What only the geometry module may hold: the optical rotation (or its transpose) as a
    literal, a division by a point's depth, two or more distortion coefficients' names, a
    distortion model's name as a string."""
    optical = cg.OPTICAL_IN_BODY.tolist()
    found, names = [], set()
    for node in ast.walk(tree):
        m = _matrix(node)
        if m is not None and m in (optical, cg.OPTICAL_IN_BODY.T.tolist()):
            found.append(f"{node.lineno}: the optical rotation")
        elif isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div) and _is_depth(node.right):
            found.append(f"{node.lineno}: a division by the depth: {ast.unparse(node)}")
        elif isinstance(node, ast.Constant) and node.value in cg.DISTORTION_MODELS[1:]:
            found.append(f"{node.lineno}: the distortion model {node.value!r}")
        elif isinstance(node, ast.Name | ast.arg | ast.Attribute):
            names.add(node.id if isinstance(node, ast.Name) else node.arg if isinstance(node, ast.arg)
                      else node.attr)
    if len(names & _COEFFICIENTS) >= 2:
        found.append(f"the distortion coefficients {sorted(names & _COEFFICIENTS)}")
    return found


def test_the_checker_catches_a_projection() -> None:
    copies = [
        "R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])",
        "R_OPT = ((0, -1, 0), (0, 0, -1), (1, 0, 0))",
        "x, y = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]",
        "uv = np.stack([fx * Xc[..., 0] / z + cx, fy * Xc[..., 1] / z + cy], axis=-1)",
        "du = -fx * X / Z**2",
        "u = f * pt.x / pt.z",
        "k1, k2, p1, p2, k3 = camera.distortion",
        "info.distortion_model = 'plumb_bob'",
    ]
    for code in copies:
        assert _projection_code(ast.parse(code)), code
    for code in ["R = np.eye(3)", "a = b / c[1]", "k2 = k * k", "v = x / 2", "m = 'plumb'"]:
        assert not _projection_code(ast.parse(code)), code
    geometry = (REPO / GEOMETRY_MODULE).read_text()
    assert len(_projection_code(ast.parse(geometry))) >= 4, "the checker no longer sees the geometry"


def test_only_the_geometry_module_projects() -> None:
    problems = []
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            rel = path.relative_to(REPO).as_posix()
            if rel != GEOMETRY_MODULE:
                problems += [f"{rel}:{p}" for p in _projection_code(ast.parse(path.read_text(), rel))]
    assert not problems, "call ekf_localization.vision.camera_geometry:\n" + "\n".join(problems)
