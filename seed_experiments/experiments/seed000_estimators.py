"""The estimators seed 000 compares, batched over N trials, in the paper's units.

State ``[x y θ ẋ ẏ θ̇]`` (eq. 19): pose in the field frame (in, rad), body velocity
(in/s, rad/s). Each estimator is stepped once per EKF period Δt with the wheel speeds
commanded during the interval that just ended (rad/s, eq. 20), the dead-wheel reading
and the camera reading taken at its end (``sim_robot`` readings, stamped in integer ns).

* ``model`` — prediction only (eq. 25): the velocity is what the wheel commands give
  (eq. 24), the pose integrates it (eq. 22). No measurement.
* ``odo`` — odometry only, no model: the velocity is the dead wheels' body twist (eq. 29),
  the pose integrates it with eq. 22 (the EKF's own discretisation, so the two differ only
  in where the velocity comes from). Direct integration rather than an EKF with a huge
  process noise: the same numbers without an ill-conditioned covariance.
* ``model + odo`` — the paper's EKF: predict with eq. 25-27 and Q of eq. 26, update with
  the encoders (eq. 31 rows 4-6, Jacobian eq. 33, R eq. 32 as the sensor reports it).
* ``+ camera`` — also the landmark pose update (eq. 28, R eq. 32) when an image is fully in
  view; skipped otherwise (equivalent to the paper's inflated variance).
* ``improved`` — the same model, Q constants, sensors and R, but the prediction runs in
  sub-steps of the truth's physics tick (1 ms): eq. 26's velocity variance is "per step",
  so it is only the truth's noise at the truth's Δt, and eq. 22 integrates the previous
  velocity for the whole step, while the simulated robot holds the sampled velocity for one
  tick and then moves at the new command. See docs/results.md for the effect.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.units import ns_to_seconds
from ekf_localization.models.mecanum import MecanumModel
from ekf_localization.models.sensors.camera import pose_measurement
from ekf_localization.models.sensors.dead_wheels import encoder_measurement
from seed_experiments.batched.ekf import BatchedEKF
from sim_robot.world.camera_sensor import CameraReading
from sim_robot.world.dead_wheel_sensor import DeadWheelReading
from sim_robot.world.world import WorldConfig

# Eq. 26 in the paper's units: position variance rate in²/s (θ: rad²/s), velocity variance
# per prediction step (in/s)² and (rad/s)².
PAPER_POSE_VARIANCE_RATE = 0.002
PAPER_VELOCITY_VARIANCE_PER_STEP = 0.45
# Initial covariance: the start pose is known (the robot is placed on it); a small positive
# variance keeps P0 positive definite.
INITIAL_POSE_VARIANCE = 1e-4  # in², rad²
INITIAL_VELOCITY_VARIANCE = 1e-4  # (in/s)², (rad/s)²
KINDS = ("model", "odometry", "ekf")


class Seed000Estimator(Protocol):
    """What the experiment loop needs from an estimator."""

    @property
    def states(self) -> np.ndarray: ...  # (N, 6), the estimator's own array

    def pose_covariances(self) -> np.ndarray | None: ...  # (N, 3, 3) or None

    def step(self, dt_ns: int, wheels: np.ndarray, odometry: DeadWheelReading,
             camera: CameraReading | None) -> None: ...


@dataclass(frozen=True)
class EstimatorSpec:
    """A named estimator configuration (see the module docstring)."""

    name: str
    kind: str  # "model", "odometry" or "ekf"
    encoders: bool = True  # ekf: fuse the dead wheels
    camera: bool = False  # ekf: fuse the camera pose
    predict_substep_ns: int | None = None  # ekf/model: predict in sub-steps of this length
    gate_sigmas: float = math.inf  # Mahalanobis gate on the camera update

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"estimator kind must be one of {KINDS}, got {self.kind!r}")
        if self.predict_substep_ns is not None and not (
                isinstance(self.predict_substep_ns, int) and self.predict_substep_ns > 0):
            raise ValueError(f"predict_substep_ns must be a positive int, got {self.predict_substep_ns!r}")


PHYSICS_TICK_NS = 1_000_000
_IDENTITY3 = np.eye(3)
MODEL = EstimatorSpec("model", "model")
ODO = EstimatorSpec("odo", "odometry")
MODEL_ODO = EstimatorSpec("model + odo", "ekf")
MODEL_ODO_CAMERA = EstimatorSpec("model + odo + camera", "ekf", camera=True)
IMPROVED = EstimatorSpec("improved: model + odo", "ekf", predict_substep_ns=PHYSICS_TICK_NS)
IMPROVED_CAMERA = EstimatorSpec("improved: model + odo + camera", "ekf", camera=True,
                                predict_substep_ns=PHYSICS_TICK_NS)


def paper_process_model(config: WorldConfig) -> MecanumModel:
    """Eq. 22-27 with wheel-speed control (eq. 20, 23) and the paper's Q (eq. 26), inches."""
    return MecanumModel(pose_variance_rate=np.full(3, PAPER_POSE_VARIANCE_RATE),
                        velocity_variance_per_step=np.full(3, PAPER_VELOCITY_VARIANCE_PER_STEP),
                        velocity_variance_rate=np.zeros(3), control="wheels", kinematics=config.mecanum)


def initial_covariance() -> np.ndarray:
    return np.diag([INITIAL_POSE_VARIANCE] * 3 + [INITIAL_VELOCITY_VARIANCE] * 3)


def _substeps(dt_ns: int, substep_ns: int | None) -> tuple[int, int, int]:
    """dt split into whole sub-steps: (sub-step, how many, the remainder after them or 0)."""
    if substep_ns is None or dt_ns <= substep_ns:
        return dt_ns, 1, 0
    n, rest = divmod(dt_ns, substep_ns)
    return substep_ns, n, rest


class OdometryIntegrator:
    """``odo``: the dead wheels' body twist (eq. 29) integrated with eq. 22."""

    def __init__(self, X0: np.ndarray) -> None:
        self._X = np.array(X0, dtype=float)
        self._model = MecanumModel(control="twist")  # eq. 25 with the twist as the new velocity

    @property
    def states(self) -> np.ndarray:
        return self._X

    def pose_covariances(self) -> None:
        return None

    def step(self, dt_ns: int, wheels: np.ndarray, odometry: DeadWheelReading,
             camera: CameraReading | None) -> None:
        # the pose by eq. 22 with the previous velocity (the EKF's own f), then the velocity <-
        # the dead wheels' twist (eq. 29)
        self._X[:] = self._model.f(self._X, odometry.twist, ns_to_seconds(dt_ns))
        self._X[:, 2] = wrap_angles(self._X[:, 2])


class Seed000Filter:
    """``model`` (predict only) or the EKF with encoders and optionally the camera."""

    def __init__(self, spec: EstimatorSpec, X0: np.ndarray, config: WorldConfig) -> None:
        self.spec = spec
        self.ekf = BatchedEKF(paper_process_model(config), X0, initial_covariance())
        self._encoders = encoder_measurement(config.dead_wheels.geometry)
        self._camera = pose_measurement()
        N = self.ekf.N
        self._R_enc = np.zeros((N, 3, 3))
        self._R_enc_diagonal = self._R_enc.reshape(N, 9)[:, ::4]  # a view of the diagonals
        self._R_cam = np.zeros((N, 3, 3))
        self._Z_cam = np.zeros((N, 3))
        self._mask_cam = np.zeros((N, 3), dtype=bool)
        self.camera_updates = 0  # accepted camera updates (all trials)
        self.camera_rejections = 0

    @property
    def states(self) -> np.ndarray:
        return self.ekf.X

    def pose_covariances(self) -> np.ndarray:
        return self.ekf.P[:, :3, :3]

    def step(self, dt_ns: int, wheels: np.ndarray, odometry: DeadWheelReading,
             camera: CameraReading | None) -> None:
        spec = self.spec
        h, count, rest = _substeps(dt_ns, spec.predict_substep_ns)
        self.ekf.predict(h, wheels, count)  # eq. 25-27, Q eq. 26
        if rest:
            self.ekf.predict(rest, wheels)
        if spec.kind == "model":
            return
        if spec.encoders:
            self._R_enc_diagonal[:] = odometry.encoder_variances  # eq. 32
            self.ekf.update(self._encoders, odometry.encoders, self._R_enc)  # eq. 31 rows 4-6, eq. 33
        if spec.camera and camera is not None and camera.visible.any():
            vis = camera.visible
            self._Z_cam.fill(0.0)  # the pose where an image is in view, 0 and R = I elsewhere
            np.copyto(self._Z_cam, camera.pose, where=vis[:, None])
            self._R_cam[:] = _IDENTITY3
            np.copyto(self._R_cam, camera.cov, where=vis[:, None, None])  # eq. 32
            self._mask_cam[:] = vis[:, None]
            status, _ = self.ekf.update(self._camera, self._Z_cam, self._R_cam, mask=self._mask_cam,
                                        gate_sigmas=spec.gate_sigmas)  # eq. 28
            ok = status[vis] == 0
            self.camera_updates += int(ok.sum())
            self.camera_rejections += int((~ok).sum())


def build_estimator(spec: EstimatorSpec, X0: np.ndarray, config: WorldConfig) -> Seed000Estimator:
    """The estimator of ``spec`` for N trials starting at X0 (N, 6)."""
    if spec.kind == "odometry":
        return OdometryIntegrator(X0)
    return Seed000Filter(spec, X0, config)
