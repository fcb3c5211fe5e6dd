"""Three dead-wheel (odometry pod) encoders E_L, E_R, E_a (seed 000, eq. 29-32).

The encoders report linear surface speeds (length unit/s). The true speeds follow
eq. 30 from the robot's true body twist, ``[E_L E_R E_a] = [vx − W·wz, vx + W·wz,
vy − D·wz]`` (``DeadWheelGeometry``: W half spacing of the parallel wheels, D the
lateral wheel's distance *behind* the centre), or with ``pods`` the true pods' own rows
(``PodGeometry``: each pod's offset, angle and scale; the twist and pose below still use
the nominal ``geometry``, so the robot's odometry is off as a miscalibrated robot's is). Each
speed gets independent Gaussian noise of variance ``speed_variance_coeff·E² + variance_floor``
(eq. 32) evaluated at the true speed; the reading reports the variance evaluated at the
*measured* speed (what a driver on the robot can compute).

``sampling``:
* ``"instantaneous"`` (seed 000, eq. 31): the speeds at the sample time, h(s) + r;
* ``"interval_average"``: the mean speed over the last period (encoder position
  differences / period, like a real encoder read out at that rate).

The body twist and its covariance come from eq. 29 (exact linear propagation, as
``models.sensors.dead_wheels.encoders_to_twist`` computes it). With ``integrate_pose`` the
sensor also integrates the measured twist with the pose exponential
(``sim_robot.world.pose_exponential``), starting from the pose given to ``reset``, with a
growing covariance (starting at zero).

``distances`` are the encoders' accumulated distances along the surface (what a real
encoder counts; sim_node publishes them as joint positions): at every sample the true
distance travelled over the period plus the noise of eq. 32 times the period, i.e. the
interval-average speed plus the same standard-normal draw as the reported speed. Position
differences over a period therefore give the interval-average speed with eq. 32's noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ekf_localization.core.units import METRES_PER_INCH, ns_to_seconds
from ekf_localization.models.sensors import dead_wheels
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry, EncoderNoise, PodGeometry
from sim_robot.world import pose_exponential

SAMPLING_MODES = ("instantaneous", "interval_average")


@dataclass(frozen=True)
class DeadWheelConfig:
    """Dead-wheel geometry, noise (eq. 32), sample period (ns) and options; SI defaults."""

    geometry: DeadWheelGeometry = field(default_factory=lambda: DeadWheelGeometry(0.17, 0.1))
    noise: EncoderNoise = field(
        default_factory=lambda: EncoderNoise(0.002, 0.001 * METRES_PER_INCH**2))
    period_ns: int = 10_000_000
    sampling: str = "instantaneous"
    integrate_pose: bool = True
    enabled: bool = True
    wheel_radius: float = 0.024  # length unit: distance along the surface per radian
    pods: PodGeometry | None = None  # the pods' true geometry when it differs from ``geometry``'s

    def __post_init__(self) -> None:
        if self.sampling not in SAMPLING_MODES:
            raise ValueError(f"dead-wheel sampling must be one of {SAMPLING_MODES}, got {self.sampling!r}")
        if not (isinstance(self.period_ns, int) and self.period_ns > 0):
            raise ValueError(f"dead-wheel period_ns must be a positive int, got {self.period_ns!r}")
        if not (np.isfinite(self.wheel_radius) and self.wheel_radius > 0.0):
            raise ValueError(f"dead-wheel wheel_radius must be > 0, got {self.wheel_radius!r}")


@dataclass(frozen=True)
class DeadWheelReading:
    """One encoder sample for N trials. ``pose``/``pose_cov`` are None without integration."""

    stamp_ns: int
    encoders: np.ndarray  # (N, 3) [E_L E_R E_a], length unit/s
    encoder_variances: np.ndarray  # (N, 3)
    twist: np.ndarray  # (N, 3) body [vx vy wz] from eq. 29
    twist_cov: np.ndarray  # (N, 3, 3)
    pose: np.ndarray | None  # (N, 3) integrated [x y θ] (frame of the reset pose)
    pose_cov: np.ndarray | None  # (N, 3, 3)
    distances: np.ndarray | None = None  # (N, 3) accumulated encoder distances, length unit


class DeadWheelSensor:
    """Samples the encoders from the world's truth; keeps the integrated pose per trial."""

    def __init__(self, config: DeadWheelConfig, n_trials: int, rng: np.random.Generator) -> None:
        self.config = config
        self.n = n_trials
        self._rng = rng
        # eq. 30, or the true pods' rows (docs/models.md, dead-wheel pods); the odometry's twist
        # below converts with the nominal geometry, as the robot's driver does
        self._E_from_twist = (config.pods or config.geometry).encoders_from_twist
        self.reset(np.zeros((n_trials, 3)), np.zeros((n_trials, 3)), 0)

    def reset(self, pose: np.ndarray, body_displacement: np.ndarray, t_ns: int) -> None:
        self._pose = np.array(pose, dtype=float)
        self._pose_cov = np.zeros((self.n, 3, 3))
        self._last_disp = np.array(body_displacement, dtype=float)
        self._last_ns = t_ns
        self._distances = np.zeros((self.n, 3))

    def sample(self, t_ns: int, body_velocity: np.ndarray,
               body_displacement: np.ndarray) -> DeadWheelReading:
        """Reading at ``t_ns`` from the true body velocity and accumulated body displacement."""
        cfg, noise = self.config, self.config.noise
        dt_s = ns_to_seconds(t_ns - self._last_ns)
        z = self._rng.standard_normal((self.n, 3))
        disp = np.array(body_displacement, dtype=float)
        average = (disp - self._last_disp) / dt_s  # the mean body twist over the period
        true = average if cfg.sampling == "interval_average" else np.asarray(body_velocity, dtype=float)
        E_true = true @ self._E_from_twist.T  # eq. 30
        E = E_true + np.sqrt(noise.variances(E_true)) * z  # eq. 32 at the true speed
        E_average = average @ self._E_from_twist.T  # the distance over the period, the same draw
        self._distances += (E_average + np.sqrt(noise.variances(E_average)) * z) * dt_s
        var = noise.variances(E)  # eq. 32 at the measured speed
        twist, twist_cov = dead_wheels.encoders_to_twist(cfg.geometry, E, noise.covariance(E))  # eq. 29
        pose = pose_cov = None
        if cfg.integrate_pose:
            self._pose, self._pose_cov = pose_exponential.integrate_with_covariance(
                self._pose, self._pose_cov, twist, twist_cov, dt_s)
            pose, pose_cov = self._pose.copy(), self._pose_cov.copy()
        self._last_disp = disp
        self._last_ns = t_ns
        return DeadWheelReading(t_ns, E, var, twist, twist_cov, pose, pose_cov, self._distances.copy())
