"""PID (seed 000 eq. 34-37 with real Δt, windup limit, derivative on measurement)."""

from __future__ import annotations

import math

import pytest

from ekf_localization.control.pid import PID, PIDGains

MS = 1_000_000  # ns


def test_proportional_and_output_limit():
    pid = PID(PIDGains(kp=2.0, output_limit=1.5))
    assert pid.update(0.5, 0.0, 0) == pytest.approx(1.0)
    assert pid.update(5.0, 0.0, 10 * MS) == 1.5
    assert pid.update(-5.0, 0.0, 20 * MS) == -1.5


def test_integral_uses_real_dt():
    pid = PID(PIDGains(kp=0.0, ki=1.0))
    pid.update(1.0, 0.0, 0)  # first call: no Δt yet
    assert pid.integral == 0.0
    pid.update(1.0, 0.0, 10 * MS)
    pid.update(1.0, 0.0, 40 * MS)  # uneven steps: 10 ms then 30 ms
    assert pid.integral == pytest.approx(0.040)
    assert pid.update(1.0, 0.0, 40 * MS) == pytest.approx(0.040)  # same stamp: no new I


def test_integral_windup_limit_and_recovery():
    """5 s of saturated error, then the error reverses: with the limit the output changes sign
    at once; without it the wound-up integral holds the output positive for seconds."""

    def steps_to_reverse(gains: PIDGains) -> tuple[int, PID]:
        pid = PID(gains)
        t = 0
        for _ in range(500):  # 5 s at 100 Hz, error +1
            pid.update(1.0, 0.0, t)
            t += 10 * MS
        for k in range(1, 2000):
            if pid.update(-1.0, 0.0, t) < 0.0:
                return k, pid
            t += 10 * MS
        return 2000, pid

    limited, pid = steps_to_reverse(PIDGains(kp=1.0, ki=10.0, integral_limit=0.05))
    unlimited, free = steps_to_reverse(PIDGains(kp=1.0, ki=10.0))
    assert limited == 1  # u = -1 + 10 * (0.05 - 0.01) = -0.6 on the first reversed step
    assert pid.integral == pytest.approx(0.04)
    # unclamped: ∫e dt reached 4.99 and must fall below 0.1 at 1/s: ~4.9 s of the wrong sign
    assert unlimited > 450
    assert free.integral == pytest.approx(0.1, abs=0.011)


def test_derivative_on_measurement_no_setpoint_kick():
    pid = PID(PIDGains(kp=1.0, kd=0.5))
    pid.update(0.0, 0.0, 0)
    u = pid.update(10.0, 0.0, 10 * MS)  # setpoint step, measurement still
    assert u == pytest.approx(10.0)  # P only: no derivative kick
    # measurement moves 0.02 in 20 ms -> rate 1.0: D = -0.5
    u = pid.update(10.0, 0.02, 30 * MS)
    assert u == pytest.approx(1.0 * 9.98 - 0.5 * 1.0)


def test_angular_wraps_error_and_measurement_difference():
    pid = PID(PIDGains(kp=1.0, kd=0.1), angular=True)
    u = pid.update(math.pi - 0.1, -math.pi + 0.1, 0)
    assert u == pytest.approx(-0.2)  # short way round across ±π
    # measurement crosses the seam: -π+0.1 -> π-0.1 is a change of -0.2 rad in 10 ms
    u = pid.update(math.pi - 0.1, math.pi - 0.1, 10 * MS)
    assert u == pytest.approx(0.0 - 0.1 * (-0.2 / 0.01))


def test_reset_forgets_history():
    pid = PID(PIDGains(kp=1.0, ki=1.0, kd=1.0))
    pid.update(1.0, 0.0, 0)
    pid.update(1.0, 0.5, 100 * MS)
    pid.reset()
    assert pid.integral == 0.0
    assert pid.update(1.0, 0.0, 200 * MS) == pytest.approx(1.0)  # no D from the old measurement


def test_pi_removes_steady_state_error_on_a_plant_with_disturbance():
    """First-order plant ẋ = u − 0.3 (constant drag): P alone leaves an offset, PI does not."""

    def run(gains: PIDGains) -> float:
        pid, x, t = PID(gains), 0.0, 0
        for _ in range(3000):  # 30 s at 100 Hz
            u = pid.update(1.0, x, t)
            x += (u - 0.3) * 0.01
            t += 10 * MS
        return x

    assert run(PIDGains(kp=2.0)) == pytest.approx(1.0 - 0.3 / 2.0, abs=1e-6)
    assert run(PIDGains(kp=2.0, ki=1.0, integral_limit=1.0)) == pytest.approx(1.0, abs=1e-4)


@pytest.mark.parametrize("kwargs, name", [
    ({"kp": -1.0}, "kp"), ({"kp": math.nan}, "kp"), ({"kp": 1.0, "ki": math.inf}, "ki"),
    ({"kp": 1.0, "kd": -0.1}, "kd"), ({"kp": 1.0, "integral_limit": 0.0}, "integral_limit"),
    ({"kp": 1.0, "output_limit": math.nan}, "output_limit"),
])
def test_bad_gains_name_the_field(kwargs, name):
    with pytest.raises(ValueError, match=name):
        PIDGains(**kwargs)
