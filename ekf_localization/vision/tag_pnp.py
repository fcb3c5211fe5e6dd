"""Multi-tag PnP: the robot's pose in the map from tag corner pixels, with an honest covariance.

The unknown is the robot pose p = (x, y, z, roll, pitch, yaw) of ``base_link`` in ``map``
(REP-103, R = Rz(yaw)·Ry(pitch)·Rx(roll), the order of PoseWithCovarianceStamped's
covariance). A layout corner X (map) is seen by the camera, mounted at ``base_link <- camera``
(optical frame, T_bc = [R_bc, t_bc]), at

    X_c = R_bc^T (R_wb(p)^T (X - t_b(p)) - t_bc),      (u, v) = project(X_c)

(the pinhole of vision/camera_geometry.py), so the residuals r(p) = project(X_c) - uv and
their Jacobian J = dr/dp include the mount: the covariance from J at the optimum
(vision/corner_noise.py: the sandwich of the corner noise, sigma_px^2 (J^T J)^-1 for
independent corners) is already that of the robot pose.

The start comes from OpenCV: SQPnP over all corners of all layout tags seen, or for a single
tag IPPE_SQUARE's two solutions, whose reprojection errors give the ambiguity ratio
best / second (PhotonVision's ``ambiguity``: near 1 the tag's tilt is undecidable). The
start is refined by Levenberg-Marquardt on r(p). With the filter's heading (yaw ψ̂, variance
σ², vision/heading_prior.py) a single tag takes the IPPE solution whose yaw is nearest ψ̂, or
holds the yaw at ψ̂ and solves the other five unknowns p5; their error then also carries the
heading's, through s = d p5 / d yaw = -(J5ᵀJ5)⁻¹ J5ᵀ j_yaw:

    Σ = [[Σ5 + σ² s sᵀ, σ² s], [σ² sᵀ, σ²]]      (Σ5 the sandwich of the five)

Distorted pixels are first undistorted
(``PinholeCamera.undistort``: OpenCV, same K), so the model above is the distortion-free pinhole.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.angles import matrix_to_rpy, rpy_to_matrix, wrap_angles
from ekf_localization.core.units import ns_to_seconds
from ekf_localization.vision import camera_geometry, corner_noise
from ekf_localization.vision.corner_noise import CornerNoise
from ekf_localization.vision.detection import TagDetection
from ekf_localization.vision.heading_prior import AMBIGUITY, FIXED_HEADING, HEADING, Heading, nearest_yaw
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import TagLayout

# The tag's plane frame for IPPE_SQUARE: corners (-h, h, 0), (h, h, 0), (h, -h, 0),
# (-h, -h, 0) in the detector order bl, br, tr, tl. Its axes in the tag frame: a = +y,
# b = -z, c = a x b = -x.
_TAG_FROM_PLANE = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

MOTION_MAX_GAP_NS = 250_000_000   # a fix older than this gives no motion for the blur
ALL_DOF = (0, 1, 2, 3, 4, 5)
YAW = 5
UNINFORMATIVE_YAW_VARIANCE = math.pi**2 / 3.0   # rad²: a yaw uniform on the circle
HEADING_SIGMAS = 3.0   # heading: the two solutions' yaws must differ by more than this many heading stds

# Generators of the rotations about x, y, z: d/dθ R_axis(θ) = R_axis(θ) K_axis.
_K = (np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
      np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]),
      np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]))


@dataclass(frozen=True)
class PnPProblem:
    """The corners to fit: (N, 3) layout points in the map, (N, 2) ideal (undistorted) pixels."""

    object_points: np.ndarray
    image_points: np.ndarray
    camera: PinholeCamera
    base_to_camera: np.ndarray          # 4x4 base_link <- camera optical frame
    tag_ids: tuple[int, ...]


@dataclass(frozen=True)
class TagFix:
    """A solved robot pose: p (6,), its 6x6 covariance, and the fit's quality."""

    pose: np.ndarray                    # x, y, z, roll, pitch, yaw of base_link in map
    covariance: np.ndarray              # (6, 6), REP-103 order as in PoseWithCovariance
    tag_ids: tuple[int, ...]
    reprojection_rms: float             # px, after refinement
    ambiguity: float                    # best / second reprojection error (single tag), else 0
    iterations: int
    method: str = AMBIGUITY             # how a single tag's solution was chosen (vision/heading_prior.py)
    heading_fallback: bool = False      # a heading method fell back: the heading was missing or stale


@dataclass(frozen=True)
class TagRejection:
    """Why no fix came out: a reason (a counter's name on /diagnostics) and details."""

    reason: str
    detail: str = ""
    tag_ids: tuple[int, ...] = ()


# The rejection reasons (their counters on /diagnostics).
NO_LAYOUT_TAGS = "no_layout_tags"
AMBIGUOUS = "ambiguous"
OFF_FIELD = "off_field"
PNP_FAILED = "pnp_failed"
REJECTION_REASONS = (NO_LAYOUT_TAGS, AMBIGUOUS, OFF_FIELD, PNP_FAILED)


def pose_matrix(pose: Sequence[float]) -> np.ndarray:
    """4x4 transform of (x, y, z, roll, pitch, yaw)."""
    T = np.eye(4)
    T[:3, :3] = rpy_to_matrix(pose[3], pose[4], pose[5])
    T[:3, 3] = pose[:3]
    return T


def _rotations(roll: float, pitch: float, yaw: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """R_wb = Rz Ry Rx and its derivatives with respect to roll, pitch, yaw."""
    rx = rpy_to_matrix(roll, 0.0, 0.0)
    ry = rpy_to_matrix(0.0, pitch, 0.0)
    rz = rpy_to_matrix(0.0, 0.0, yaw)
    R = rz @ ry @ rx
    return R, [rz @ ry @ rx @ _K[0], rz @ ry @ _K[1] @ rx, rz @ _K[2] @ ry @ rx]


def camera_points(problem: PnPProblem, pose: np.ndarray) -> np.ndarray:
    """(N, 3) layout corners in the camera's optical frame for robot pose ``pose``."""
    R_wb, _ = _rotations(pose[3], pose[4], pose[5])
    R_bc, t_bc = problem.base_to_camera[:3, :3], problem.base_to_camera[:3, 3]
    in_base = (problem.object_points - pose[:3]) @ R_wb
    return (in_base - t_bc) @ R_bc


def residuals_and_jacobian(problem: PnPProblem, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """r(p) (2N,) = projected minus measured pixels (u0, v0, u1, ...) and J = dr/dp (2N, 6)."""
    cam = problem.camera
    R_wb, dR = _rotations(pose[3], pose[4], pose[5])
    R_bc, t_bc = problem.base_to_camera[:3, :3], problem.base_to_camera[:3, 3]
    d = problem.object_points - pose[:3]                      # X - t_b, (N, 3)
    Xc = (d @ R_wb - t_bc) @ R_bc                             # (N, 3)
    r = (camera_geometry.project(Xc, cam.intrinsics) - problem.image_points).reshape(-1)
    # d X_c / d p: translation -R_bc^T R_wb^T, angle k: R_bc^T dR_k^T (X - t_b)
    dXc = np.empty((len(Xc), 3, 6))
    dXc[:, :, :3] = -(R_bc.T @ R_wb.T)
    for k in range(3):
        dXc[:, :, 3 + k] = (d @ dR[k]) @ R_bc
    duv = camera_geometry.projection_jacobian(Xc, cam.intrinsics)   # d uv / d X_c of the pinhole
    return r, np.einsum("nij,njk->nik", duv, dXc).reshape(-1, 6)


def refine(problem: PnPProblem, pose: np.ndarray, iterations: int = 20,
           tolerance: float = 1e-10, free: Sequence[int] = ALL_DOF) -> tuple[np.ndarray, int]:
    """Levenberg-Marquardt on the reprojection error from ``pose`` over the unknowns ``free``
    (indices into p; the others held); (pose, iterations used)."""
    free = list(free)
    p = np.asarray(pose, dtype=float).copy()
    r, J = residuals_and_jacobian(problem, p)
    J = J[:, free]
    cost, lam = float(r @ r), 1e-3
    for it in range(1, iterations + 1):
        A, g = J.T @ J, J.T @ r
        step = np.zeros(6)
        step[free] = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), -g)
        trial = p + step
        r_t, J_t = residuals_and_jacobian(problem, trial)
        J_t = J_t[:, free]
        cost_t = float(r_t @ r_t)
        if np.isfinite(cost_t) and cost_t <= cost:
            converged = cost - cost_t <= tolerance * max(cost, 1e-12) or np.max(np.abs(step)) < 1e-12
            p, r, J, cost, lam = trial, r_t, J_t, cost_t, max(lam * 0.1, 1e-9)
            if converged:
                return p, it
        else:
            lam *= 10.0
            if lam > 1e8:
                return p, it
    return p, iterations


def image_blur(problem: PnPProblem, pose: np.ndarray, velocity: np.ndarray,
               exposure_time: float) -> np.ndarray:
    """(T, 2) mean pixel motion of each tag's corners over the exposure, the robot moving at
    ``velocity`` (d pose / dt, 6) about ``pose`` (the exposure's middle)."""
    half = 0.5 * exposure_time * np.asarray(velocity, dtype=float)
    r0, _ = residuals_and_jacobian(problem, np.asarray(pose) - half)
    r1, _ = residuals_and_jacobian(problem, np.asarray(pose) + half)
    return (r1 - r0).reshape(-1, 4, 2).mean(axis=1)


def pose_velocity(pose: np.ndarray, stamp_ns: int, previous: tuple[int, np.ndarray] | None,
                  max_gap_ns: int) -> np.ndarray | None:
    """d pose / dt from the previous fix (stamp, pose) when it is at most ``max_gap_ns`` older."""
    if previous is None or not 0 < stamp_ns - previous[0] <= max_gap_ns:
        return None
    d = np.asarray(pose, dtype=float) - previous[1]
    d[3:] = wrap_angles(d[3:])
    return d / ns_to_seconds(stamp_ns - previous[0])


def pose_covariance(problem: PnPProblem, pose: np.ndarray, noise: CornerNoise,
                    velocity: np.ndarray | None = None, heading_variance: float | None = None) -> np.ndarray:
    """The robot pose's 6x6 covariance under the corner noise ``noise`` (vision/corner_noise.py);
    the blur comes from ``velocity``, or is the model's unknown-motion blur. With
    ``heading_variance`` the yaw was held at a heading of that variance and the other five
    unknowns solved: their covariance is the sandwich plus the heading's error carried through
    them (module docstring). inf if singular."""
    r, J = residuals_and_jacobian(problem, pose)
    tags = len(problem.tag_ids)
    if noise.exposure_time <= 0.0:
        blurs = np.zeros((tags, 2))                      # no blur model
    elif velocity is None:
        blurs = noise.unknown_blurs(tags)
    else:
        blurs = image_blur(problem, pose, velocity, noise.exposure_time)
    corner_cov = noise.corner_covariance(blurs)
    if heading_variance is None:
        return corner_noise.pose_covariance(J, r, corner_cov)
    J5, j_yaw = J[:, :YAW], J[:, YAW]
    cov = np.full((6, 6), math.inf)
    cov5 = corner_noise.pose_covariance(J5, r, corner_cov)
    if not np.all(np.isfinite(cov5)):
        return cov
    s = -np.linalg.solve(J5.T @ J5, J5.T @ j_yaw)         # d p5 / d yaw at the held yaw
    cov[:YAW, :YAW] = cov5 + heading_variance * np.outer(s, s)
    cov[:YAW, YAW] = cov[YAW, :YAW] = heading_variance * s
    cov[YAW, YAW] = heading_variance
    return cov


def published_covariance(fix: TagFix) -> np.ndarray:
    """The covariance a fix is published with. A held heading's yaw is the filter's own: fused
    again it would count the filter's heading twice, and the filter cannot model its x, y's
    correlation with its own yaw error. So that fix says nothing of the yaw
    (UNINFORMATIVE_YAW_VARIANCE, uncorrelated) and keeps x, y's marginal covariance, which
    holds the heading's error; any other fix is published as solved."""
    if fix.method != FIXED_HEADING:
        return fix.covariance
    cov = fix.covariance.copy()
    cov[YAW, :] = cov[:, YAW] = 0.0
    cov[YAW, YAW] = UNINFORMATIVE_YAW_VARIANCE
    return cov


def _pose_from_camera(R_cw: np.ndarray, t_cw: np.ndarray, base_to_camera: np.ndarray) -> np.ndarray:
    """Robot pose p from OpenCV's world -> camera (X_c = R X + t)."""
    T_wc = np.eye(4)
    T_wc[:3, :3], T_wc[:3, 3] = R_cw.T, -R_cw.T @ t_cw
    T_wb = T_wc @ np.linalg.inv(base_to_camera)
    return np.concatenate([T_wb[:3, 3], matrix_to_rpy(T_wb[:3, :3])])


def build_problem(detections: Sequence[TagDetection], layout: TagLayout, camera: PinholeCamera,
                  base_to_camera: np.ndarray) -> tuple[PnPProblem | None, tuple[int, ...]]:
    """The corners of the layout tags among ``detections``; also the ids not in the layout."""
    known = [d for d in detections if d.tag_id in layout.tags]
    unknown = tuple(d.tag_id for d in detections if d.tag_id not in layout.tags)
    if not known:
        return None, unknown
    obj = np.concatenate([layout.tags[d.tag_id].corners_map() for d in known])
    img = camera.undistort(np.concatenate([np.asarray(d.corners, dtype=float).reshape(4, 2)
                                           for d in known]))
    return PnPProblem(obj, img, camera, np.asarray(base_to_camera, dtype=float),
                      tuple(d.tag_id for d in known)), unknown


def _single_tag_starts(problem: PnPProblem, layout: TagLayout) -> tuple[list[np.ndarray], float]:
    """IPPE_SQUARE's solutions as robot poses, best first, and the ambiguity ratio."""
    import cv2

    tag = layout.tags[problem.tag_ids[0]]
    h = 0.5 * tag.size
    plane = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
    T_wp = tag.pose_in_map.copy()
    T_wp[:3, :3] = T_wp[:3, :3] @ _TAG_FROM_PLANE
    n, rvecs, tvecs, errors = cv2.solvePnPGeneric(
        plane, problem.image_points.reshape(-1, 1, 2), problem.camera.matrix, None,
        flags=cv2.SOLVEPNP_IPPE_SQUARE)
    starts = []
    for i in np.argsort(np.asarray(errors).reshape(-1))[:n]:
        R_cp, _ = cv2.Rodrigues(rvecs[i])
        R_cw = R_cp @ T_wp[:3, :3].T                       # camera <- plane <- world
        t_cw = tvecs[i].reshape(3) - R_cw @ T_wp[:3, 3]
        starts.append(_pose_from_camera(R_cw, t_cw, problem.base_to_camera))
    errs = np.sort(np.asarray(errors).reshape(-1))
    ambiguity = float(errs[0] / errs[1]) if n > 1 and errs[1] > 0.0 else 0.0
    return starts, ambiguity


def _multi_tag_start(problem: PnPProblem) -> list[np.ndarray]:
    import cv2

    ok, rvec, tvec = cv2.solvePnP(problem.object_points, problem.image_points.reshape(-1, 1, 2),
                                  problem.camera.matrix, None, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        return []
    R_cw, _ = cv2.Rodrigues(rvec)
    return [_pose_from_camera(R_cw, tvec.reshape(3), problem.base_to_camera)]


def solve(problem: PnPProblem, layout: TagLayout, noise: CornerNoise,
          max_ambiguity: float = 0.2, field_margin: float = 0.5,
          previous: tuple[int, np.ndarray] | None = None, stamp_ns: int = 0,
          single_tag: str = AMBIGUITY, heading: Heading | None = None) -> TagFix | TagRejection:
    """The robot pose of ``problem``'s corners, or why not (ambiguous, off the field, failed).
    ``previous`` (stamp, pose), the last fix, gives the motion behind the blur at ``stamp_ns``.
    A single tag is solved by ``single_tag`` (vision/heading_prior.py) with the filter's
    ``heading`` at the stamp; by ``ambiguity`` without it (missing or stale), and for ``heading``
    also when the two solutions' yaws differ by no more than HEADING_SIGMAS heading stds."""
    ids = problem.tag_ids
    ambiguity = 0.0
    try:
        if len(ids) == 1:
            starts, ambiguity = _single_tag_starts(problem, layout)
        else:
            starts = _multi_tag_start(problem)
    except Exception as e:  # noqa: BLE001 - OpenCV raises cv2.error on degenerate input
        return TagRejection(PNP_FAILED, f"OpenCV: {e}".splitlines()[0], ids)
    if not starts:
        return TagRejection(PNP_FAILED, "no PnP solution", ids)
    single = len(ids) == 1
    use_heading = single and single_tag != AMBIGUITY and heading is not None
    if use_heading and single_tag == HEADING and len(starts) > 1:   # can the heading tell them apart?
        gap = abs(wrap_angles(np.array([starts[0][YAW] - starts[1][YAW]]))[0])
        use_heading = gap > HEADING_SIGMAS * math.sqrt(heading.variance)
    method = single_tag if use_heading else AMBIGUITY
    fallback = single and single_tag != AMBIGUITY and not use_heading
    if single and method == AMBIGUITY and ambiguity > max_ambiguity:
        return TagRejection(AMBIGUOUS, f"ambiguity {ambiguity:.2f} > {max_ambiguity:.2f}", ids)
    free: Sequence[int] = ALL_DOF
    if method != AMBIGUITY:                  # the IPPE solution whose yaw is nearest the filter's
        starts = [starts[nearest_yaw([float(p[YAW]) for p in starts], heading.yaw)]]
        if method == FIXED_HEADING:
            starts[0][YAW] = heading.yaw
            free = ALL_DOF[:YAW]
    # refine every start (IPPE's two for one tag) and keep the lowest reprojection error
    best = None
    for start in starts:
        pose, iterations = refine(problem, start, free=free)
        r, _ = residuals_and_jacobian(problem, pose)
        cost = float(r @ r) if np.all(np.isfinite(r)) else math.inf
        if best is None or cost < best[0]:
            best = (cost, pose, iterations, r)
    _, pose, iterations, r = best
    if not (np.all(np.isfinite(pose)) and np.all(np.isfinite(r))):
        return TagRejection(PNP_FAILED, "refinement diverged", ids)
    if np.any(camera_points(problem, pose)[:, 2] <= 0.0):
        return TagRejection(PNP_FAILED, "a corner behind the camera", ids)
    if not layout.on_field(pose[0], pose[1], field_margin):
        return TagRejection(OFF_FIELD, f"pose ({pose[0]:.2f}, {pose[1]:.2f}) m is off the field", ids)
    velocity = pose_velocity(pose, stamp_ns, previous, MOTION_MAX_GAP_NS)
    cov = pose_covariance(problem, pose, noise, velocity,
                          heading.variance if method == FIXED_HEADING else None)
    if not np.all(np.isfinite(cov)):
        return TagRejection(PNP_FAILED, "singular Jacobian", ids)
    rms = float(np.sqrt(np.mean(r.reshape(-1, 2) ** 2 @ np.ones(2))))
    return TagFix(pose, cov, ids, rms, ambiguity, iterations, method, fallback)


def localize(detections: Sequence[TagDetection], layout: TagLayout, camera: PinholeCamera,
             base_to_camera: np.ndarray, noise: CornerNoise, max_ambiguity: float = 0.2,
             field_margin: float = 0.5, previous: tuple[int, np.ndarray] | None = None,
             stamp_ns: int = 0, single_tag: str = AMBIGUITY,
             heading: Heading | None = None) -> tuple[TagFix | TagRejection, tuple[int, ...]]:
    """Detections -> a fix or a rejection, plus the detected ids that are not in the layout.
    ``previous`` (stamp, pose), the last fix, sets the blur of the corner noise at ``stamp_ns``;
    ``single_tag`` and ``heading`` choose a single tag's solution (:func:`solve`)."""
    problem, unknown = build_problem(detections, layout, camera, base_to_camera)
    if problem is None:
        return TagRejection(NO_LAYOUT_TAGS, "no tag of the layout seen"), unknown
    return solve(problem, layout, noise, max_ambiguity, field_margin, previous, stamp_ns,
                 single_tag, heading), unknown
