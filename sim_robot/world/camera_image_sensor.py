"""Camera image sensor: what a camera on the robot sees of the field's AprilTags (mono8).

At each capture (every ``period_ns`` of sim time from ``phase_ns`` on, the stamp = the middle of
the exposure)
the camera pose comes from the robot's true pose and body velocity, extrapolated by half
the exposure either side (start and end of the exposure, for the motion blur), and the
:class:`~sim_robot.world.camera_render.CameraRenderer` draws the layout's tags. The image
is delivered ``latency_ns`` after its stamp (``arrival_ns``).

The camera is mounted at ``mount`` = [x, y, z, yaw, pitch] in ``base_link`` (m, rad; pitch
> 0 looks down); its REP-103 optical frame (z forward, x right, y down) is what
:meth:`CameraImageSensor.base_to_optical` returns, for the static TF base_link -> camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ekf_localization.vision.camera_geometry import optical_pose
from ekf_localization.vision.pinhole import PinholeCamera
from ekf_localization.vision.tag_layout import TagLayout
from sim_robot.world.camera_render import CameraRenderer, RenderSettings, planar_pose


@dataclass(frozen=True)
class CameraImageConfig:
    """Rate, phase and latency (ns), the pinhole camera, its mount in base_link, the render settings.
    Captures fall at ``phase_ns + k * period_ns``: a second, free-running camera is not in step
    with the first."""

    camera: PinholeCamera
    layout: TagLayout
    period_ns: int = 50_000_000
    latency_ns: int = 0
    mount: tuple[float, float, float, float, float] = (0.0, 0.0, 0.2, 0.0, 0.0)
    render: RenderSettings = field(default_factory=RenderSettings)
    phase_ns: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.period_ns, int) and self.period_ns > 0):
            raise ValueError(f"camera image period_ns must be a positive int, got {self.period_ns!r}")
        if not (isinstance(self.latency_ns, int) and self.latency_ns >= 0):
            raise ValueError(f"camera image latency_ns must be an int >= 0, got {self.latency_ns!r}")
        if not (isinstance(self.phase_ns, int) and 0 <= self.phase_ns < self.period_ns):
            raise ValueError(f"camera image phase_ns must be an int in [0, period_ns), got {self.phase_ns!r}")
        if len(self.mount) != 5 or not all(math.isfinite(v) for v in self.mount):
            raise ValueError(f"camera mount must be 5 finite numbers, got {self.mount!r}")


@dataclass(frozen=True)
class ImageReading:
    """One captured image: stamp (exposure middle) and arrival time (ns), mono8 pixels."""

    stamp_ns: int
    arrival_ns: int
    image: np.ndarray


class CameraImageSensor:
    """Renders the camera's view from the robot's true state (see the module docstring)."""

    def __init__(self, config: CameraImageConfig, seed: int | tuple[int, ...] = 0) -> None:
        """``seed``: the pixel noise's stream (numpy's seed: an int, or a tuple for another camera's)."""
        self.config = config
        self.renderer = CameraRenderer(config.camera, config.layout, config.render)
        self._rng = np.random.default_rng(seed)
        x, y, z, yaw, pitch = config.mount
        self._base_to_optical = optical_pose(planar_pose(x, y, z, yaw, pitch))

    def base_to_optical(self) -> np.ndarray:
        """base_link <- camera optical frame (4x4)."""
        return self._base_to_optical.copy()

    def due(self, stamp_ns: int) -> bool:
        """Whether a capture happens at ``stamp_ns`` (the phase plus a multiple of the period)."""
        return (stamp_ns - self.config.phase_ns) % self.config.period_ns == 0

    def next_capture_ns(self, after_ns: int) -> int:
        """The first capture time later than ``after_ns``."""
        period, phase = self.config.period_ns, self.config.phase_ns
        return phase + ((after_ns - phase) // period + 1) * period

    def camera_pose(self, state: np.ndarray, dt: float) -> np.ndarray:
        """map <- optical (4x4) at ``dt`` s from the state [x y yaw vx vy wz] (body velocity)."""
        x, y, yaw, vx, vy, wz = (float(v) for v in state[:6])
        c, s = math.cos(yaw), math.sin(yaw)
        base = planar_pose(x + (c * vx - s * vy) * dt, y + (s * vx + c * vy) * dt, 0.0,
                           yaw + wz * dt)
        return base @ self._base_to_optical

    def capture(self, stamp_ns: int, state: np.ndarray) -> ImageReading:
        """The image whose exposure is centred on ``stamp_ns``, the robot in ``state``."""
        half = 0.5 * self.config.render.exposure_time
        image = self.renderer.render(self.camera_pose(state, -half), self.camera_pose(state, half),
                                     self._rng)
        return ImageReading(stamp_ns, stamp_ns + self.config.latency_ns, image)
