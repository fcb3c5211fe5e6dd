"""Seed 000's Monte-Carlo loop: N trials of the 1 kHz world, one pure-pursuit follower per
trial, and every compared estimator stepped on the same readings (paired comparison).

Units are the paper's (in, in/s, rad, rad/s; ``WorldConfig.seed000_inches()``, its exact
Q and R constants). The paths and the follower are SI (metres): the follower gets the pose
in metres (× 0.0254 exactly) and its twist command is converted back to in/s, then to the
four wheel speeds (rad/s, unit-free) with the robot's inverse kinematics.

Timing per trial: the truth runs at 1 ms; every EKF period Δt the world delivers one
dead-wheel sample and one camera capture (both sampled at the end of the interval) and
every estimator takes one step; every control period (a whole number of EKF periods) the
follower computes the next wheel command from the *driver* pose — the truth, or one
estimator's estimate — so all estimators of a trial see the same commands and readings.

A trial is active until its follower reports the path done; the RMSE uses the steps while
it is active (seed 000 sec. VI A: "for all time steps").
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ekf_localization.control.field_path import FieldPath
from ekf_localization.control.pure_pursuit import FollowerConfig, PurePursuitFollower
from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.units import METRES_PER_INCH
from seed_experiments.batched.pure_pursuit import BatchedPurePursuit
from seed_experiments.experiments.progress import Progress
from seed_experiments.experiments.seed000_estimators import EstimatorSpec, build_estimator
from sim_robot.world.camera_sensor import CameraReading
from sim_robot.world.dead_wheel_sensor import DeadWheelReading
from sim_robot.world.field import Field
from sim_robot.world.world import World, WorldConfig

EKF_PERIOD_NS = 10_000_000  # seed 000 sec. IV A: the EKF's Δt
CONTROL_PERIOD_NS = 20_000_000  # follower at 50 Hz (pure_pursuit_node's default rate)
# The paper gives no speed: eq. 32 and its odo ẋ RMSE imply an RMS encoder speed of about
# 14.5 in/s (docs/results.md), hence a top speed of 0.37 m/s = 14.6 in/s. Lookahead 0.15 m (6 in):
# the test path's legs are 20-40 in long, and a 12 in circle cuts its corners by several inches.
FOLLOWER = FollowerConfig(max_linear_velocity=0.37, lookahead_distance=0.15)
MAX_DURATION_NS = 120_000_000_000
_NO_TRUTH_READINGS_NS = 3_600_000_000_000  # the loop reads world.truth directly
STAT_COLUMNS = ("x", "y", "xy", "theta", "vx", "vy", "vtheta")


def seed000_world_config(ekf_period_ns: int = EKF_PERIOD_NS, field_preset: str = "seed000",
                         camera: bool = True) -> WorldConfig:
    """The paper's inch model; dead wheels and camera sample once per EKF period, no IMU."""
    base = WorldConfig.seed000_inches()
    return dataclasses.replace(
        base, field=Field.preset(field_preset, 1.0), truth_period_ns=_NO_TRUTH_READINGS_NS,
        dead_wheels=dataclasses.replace(base.dead_wheels, period_ns=ekf_period_ns, integrate_pose=False),
        camera=dataclasses.replace(base.camera, period_ns=ekf_period_ns, enabled=camera),
        imu=dataclasses.replace(base.imu, enabled=False))


@dataclass
class History:
    """Per-step records (T steps, N trials) kept when a run is asked to record."""

    t_ns: np.ndarray  # (T,)
    truth: np.ndarray  # (T, N, 6)
    estimates: dict[str, np.ndarray]  # name -> (T, N, 6)
    pose_cov: dict[str, np.ndarray]  # name -> (T, N, 3, 3) (filters only)
    active: np.ndarray  # (T, N)
    path_progress_m: np.ndarray  # (T, N) follower progress along the path
    camera_visible: np.ndarray  # (T, N)


@dataclass
class RunResult:
    """Per-trial squared-error sums of every estimator over the active steps."""

    names: tuple[str, ...]
    sq_err: dict[str, np.ndarray]  # name -> (N, 6) sums of squared errors of [x y θ ẋ ẏ θ̇]
    steps: np.ndarray  # (N,) active steps per trial
    camera_steps: np.ndarray  # (N,) active steps with an image fully in view
    done_ns: np.ndarray  # (N,) time the follower finished (-1: not within max_duration)
    sim_duration_ns: int
    wall_time_s: float
    history: History | None

    def per_trial_rmse(self, name: str) -> dict[str, np.ndarray]:
        """(N,) RMSE per trial for each column; (x, y) RMSE = sqrt(mean(ex² + ey²))."""
        s = self.sq_err[name] / np.maximum(self.steps, 1)[:, None]
        cols = np.column_stack([s[:, 0], s[:, 1], s[:, 0] + s[:, 1], s[:, 2], s[:, 3], s[:, 4], s[:, 5]])
        return {c: np.sqrt(cols[:, i]) for i, c in enumerate(STAT_COLUMNS)}

    def mean_rmse(self, name: str) -> dict[str, float]:
        """Mean over trials of the per-trial RMSE (the paper averages its trials)."""
        return {c: float(v.mean()) for c, v in self.per_trial_rmse(name).items()}

    def sem_rmse(self, name: str) -> dict[str, float]:
        """Standard error of that mean."""
        n = len(self.steps)
        return {c: float(v.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")
                for c, v in self.per_trial_rmse(name).items()}


def _readings(readings: list) -> tuple[DeadWheelReading, CameraReading | None]:
    odo = cam = None
    for r in readings:
        if isinstance(r, DeadWheelReading):
            odo = r
        elif isinstance(r, CameraReading):
            cam = r
    if odo is None:
        raise RuntimeError("the world delivered no dead-wheel reading in an EKF period")
    return odo, cam


class PerTrialFollowers:
    """N :class:`PurePursuitFollower` objects behind :class:`BatchedPurePursuit`'s interface.

    The reference the batched follower is tested against, and the peer of
    ``benchmarks/bench_seed_tables.py``; a trial that is done is not called again.
    """

    def __init__(self, path: FieldPath, config: FollowerConfig, n: int) -> None:
        self._followers = [PurePursuitFollower(path, config) for _ in range(n)]
        self.done = np.zeros(n, dtype=bool)
        self.progress = np.zeros(n)

    def update(self, x: np.ndarray, y: np.ndarray, theta: np.ndarray, t_ns: int) -> np.ndarray:
        out = np.zeros((len(self._followers), 3))
        xs, ys, ths = x.tolist(), y.tolist(), theta.tolist()
        for i in np.flatnonzero(~self.done).tolist():
            f = self._followers[i]
            out[i] = f.update(xs[i], ys[i], ths[i], t_ns)
            self.done[i] = f.done
            self.progress[i] = f.progress
        return out


def _add_squared_errors(sq: np.ndarray, E: np.ndarray, truth: np.ndarray, active: np.ndarray,
                        steps: np.ndarray) -> None:
    """sq[i] += (E[i] - truth)² with θ's difference wrapped, on the active trials; steps += active.
    sq (estimators, N, 6), E (estimators, N, 6), truth (N, 6), active (N,) bool."""
    err = E - truth
    err[..., 2] = wrap_angles(err[..., 2])
    sq += np.where(active[:, None], err * err, 0.0)
    steps += active


FOLLOWER_KINDS = ("batched", "per_trial")


def simulate(path: FieldPath, specs: Sequence[EstimatorSpec], n_trials: int, seed: int, *,
             ekf_period_ns: int = EKF_PERIOD_NS, control_period_ns: int = CONTROL_PERIOD_NS,
             driver: str = "truth", follower: FollowerConfig = FOLLOWER,
             world_config: WorldConfig | None = None, max_duration_ns: int = MAX_DURATION_NS,
             record_trials: int = 0, progress: Progress | None = None,
             follower_kind: str = "batched") -> RunResult:
    """Run ``n_trials`` along ``path`` (metres) and score every estimator against the truth.

    ``driver``: "truth" or the name of one of ``specs`` whose estimate the follower uses.
    ``record_trials``: keep the per-step history of the first that many trials (plots).
    ``follower_kind``: "batched" (:class:`BatchedPurePursuit`) or "per_trial" (one
    :class:`PurePursuitFollower` per trial, the reference); the results agree to rounding.
    """
    if follower_kind not in FOLLOWER_KINDS:
        raise ValueError(f"follower_kind must be one of {FOLLOWER_KINDS}, got {follower_kind!r}")
    if control_period_ns % ekf_period_ns:
        raise ValueError("control_period_ns must be a whole number of EKF periods")
    names = tuple(s.name for s in specs)
    if len(set(names)) != len(names):
        raise ValueError(f"estimator names must be unique, got {names}")
    if driver != "truth" and driver not in names:
        raise ValueError(f"driver must be 'truth' or one of {names}, got {driver!r}")
    cfg = world_config or seed000_world_config(ekf_period_ns)
    if cfg.dead_wheels.period_ns != ekf_period_ns or (cfg.camera.enabled
                                                       and cfg.camera.period_ns != ekf_period_ns):
        raise ValueError("the world's dead-wheel and camera periods must equal the EKF period")
    t_start = time.perf_counter()
    N = n_trials
    world = World(cfg, N, seed)
    start = np.array(path.start, dtype=float)
    start[:2] /= METRES_PER_INCH
    world.reset(start)
    X0 = np.tile(np.concatenate([start, np.zeros(3)]), (N, 1))
    estimators = {s.name: build_estimator(s, X0, cfg) for s in specs}
    followers = (BatchedPurePursuit(path, follower, N) if follower_kind == "batched"
                 else PerTrialFollowers(path, follower, N))
    inverse = cfg.mecanum.inverse_matrix  # body twist (in/s, rad/s) -> wheel speeds (rad/s)
    sq = np.zeros((len(names), N, 6))  # per estimator, sums of squared errors of [x y θ ẋ ẏ θ̇]
    steps = np.zeros(N, dtype=np.int64)
    camera_steps = np.zeros(N, dtype=np.int64)
    done_ns = np.full(N, -1, dtype=np.int64)
    active = np.ones(N, dtype=bool)
    wheels = np.zeros((N, 4))
    twist = np.zeros((N, 3))
    steps_per_control = control_period_ns // ekf_period_ns
    rec: dict[str, list] = {"t": [], "truth": [], "active": [], "progress": [], "visible": []}
    rec_est: dict[str, list] = {n: [] for n in names}
    rec_cov: dict[str, list] = {n: [] for n in names}
    rec_n = min(max(int(record_trials), 0), N)
    record = rec_n > 0
    k = 0
    while True:
        t = world.t_ns
        if k % steps_per_control == 0:
            pose = world.truth[:, :3] if driver == "truth" else estimators[driver].states[:, :3]
            was_active = active.copy()
            cmd = followers.update(pose[:, 0] * METRES_PER_INCH, pose[:, 1] * METRES_PER_INCH,
                                   pose[:, 2], t)
            twist[:, 0] = cmd[:, 0] / METRES_PER_INCH
            twist[:, 1] = cmd[:, 1] / METRES_PER_INCH
            twist[:, 2] = cmd[:, 2]
            finished = was_active & followers.done
            active &= ~followers.done
            done_ns[finished] = t
            twist[~active] = 0.0
            np.matmul(twist, inverse.T, out=wheels)
            world.set_wheel_command(wheels)  # held until the next control step
            if progress is not None:
                frac = np.where(followers.done, 1.0, followers.progress / path.length).mean()
                progress.update(int(frac * progress.total) - progress.count)
        if not active.any() or t >= max_duration_ns:
            break
        odo, cam = _readings(world.advance(ekf_period_ns))
        truth = world.truth
        for name, est in estimators.items():
            est.step(ekf_period_ns, wheels, odo, cam)
            if record:
                rec_est[name].append(est.states[:rec_n].copy())
                cov = est.pose_covariances()
                if cov is not None:
                    rec_cov[name].append(cov[:rec_n].copy())
        _add_squared_errors(sq, np.stack([est.states for est in estimators.values()]), truth, active, steps)
        if cam is not None:
            camera_steps += active & cam.visible
        if record:
            rec["t"].append(world.t_ns)
            rec["truth"].append(truth[:rec_n])
            rec["active"].append(active[:rec_n].copy())
            rec["progress"].append(followers.progress[:rec_n].copy())
            rec["visible"].append(cam.visible[:rec_n].copy() if cam is not None
                                  else np.zeros(rec_n, dtype=bool))
        k += 1
    history = None
    if record:
        history = History(np.array(rec["t"], dtype=np.int64), np.array(rec["truth"]),
                          {n: np.array(v) for n, v in rec_est.items()},
                          {n: np.array(v) for n, v in rec_cov.items() if v},
                          np.array(rec["active"]), np.array(rec["progress"]), np.array(rec["visible"]))
    sq_err = {n: sq[i] for i, n in enumerate(names)}
    return RunResult(names, sq_err, steps, camera_steps, done_ns, world.t_ns, time.perf_counter() - t_start,
                     history)
