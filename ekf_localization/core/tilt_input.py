"""An IMU's roll and pitch as the tilt of a ramp: kept by stamp, applied to surface velocities,
and the height it integrates (core.tilt has the maths; no ROS imports)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ekf_localization.core.measurements import REJECT_TILT_RANGE, MeasurementPart, check_part
from ekf_localization.core.tilt import MAX_TILT_RAD, HeightIntegrator, TiltHistory, TiltSample, project_twist

_ROLL_PITCH = np.array([0, 1], dtype=np.intp)
TWIST_FIELDS = (6, 7, 11)  # vx vy vyaw: the planar body twist


def horizontal_velocity(est, field_to_state: dict[int, int]) -> tuple[float, float, np.ndarray] | None:
    """(ẋ_h, ẏ_h, their 2x2 covariance) of an Estimate (ẏ_h = 0 for a model without vy)."""
    if est is None:
        return None
    f = field_to_state
    cols = [f[c] for c in (6, 7) if c in f]
    C = np.zeros((2, 2))
    C[np.ix_(range(len(cols)), range(len(cols)))] = est.covariance[np.ix_(cols, cols)]
    return float(est.state[f[6]]), float(est.state[f[7]]) if 7 in f else 0.0, C


class TiltInput:
    """The tilt samples of the IMUs that give it (``imuN`` with roll and pitch fused)."""

    def __init__(self, keep_ns: int, base_frame: str) -> None:
        self._history = TiltHistory(keep_ns)
        self._height = HeightIntegrator()
        self._base_frame = base_frame

    def clear(self) -> None:
        self._history.clear()
        self._height.reset()

    def at(self, stamp_ns: int) -> TiltSample | None:
        """The roll/pitch in effect at ``stamp_ns`` (None before any sample)."""
        return self._history.at(stamp_ns)

    def add(self, part: MeasurementPart, stamp: int,
            velocity_at: Callable[[int], tuple[float, float, np.ndarray] | None]) -> str | None:
        """Roll and pitch of an IMU orientation part (REP-145: covariance[0] = -1 means none);
        z climbs at the tilt's stamp with ``velocity_at(stamp)``, the estimated (ẋ_h, ẏ_h, cov)."""
        reason = check_part(part, _ROLL_PITCH, self._base_frame)
        if reason is not None:
            return reason
        roll, pitch = float(part.values[0]), float(part.values[1])
        if max(abs(roll), abs(pitch)) > MAX_TILT_RAD:
            return REJECT_TILT_RANGE
        cov = np.asarray(part.covariance, dtype=float)[:2, :2].copy()
        self._history.add(TiltSample(stamp, roll, pitch, cov))
        velocity = velocity_at(stamp)
        if velocity is not None:
            self._height.update(stamp, *velocity, roll, pitch)
        return None

    def project_twist(self, local: np.ndarray, z: np.ndarray, R: np.ndarray,
                      stamp: int) -> tuple[np.ndarray, np.ndarray]:
        """A body twist (its fields ``6 + local``) measured along the surface -> the horizontal velocity."""
        tilt = self._history.at(stamp)
        if tilt is None:
            return z, R
        rows = np.array([TWIST_FIELDS.index(6 + int(j)) for j in local], dtype=np.intp)
        return project_twist(z, R, rows, tilt.roll, tilt.pitch, tilt.covariance)

    def attitude(self, stamp_ns: int) -> tuple[tuple[int, float, float], ...]:
        """(RL field, value, variance) of z (dead-reckoned, as of the newest sample: never
        extrapolated with a tilt that may be stale), roll and pitch; () before any sample."""
        tilt = self._history.at(stamp_ns)
        if tilt is None:
            return ()
        z, z_var = self._height.current()
        return ((2, z, z_var), (3, tilt.roll, float(tilt.covariance[0, 0])),
                (4, tilt.pitch, float(tilt.covariance[1, 1])))
