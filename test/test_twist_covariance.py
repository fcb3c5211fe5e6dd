"""``<input>_twist_covariance`` (odomN, twistN): checked at start, naming the parameter; it
replaces each message's twist covariance before the checks, and zero_variance_floor and
variance_scale apply after it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.fusion_scenario import fuse

from ekf_localization.core.measurements import OdometryMeasurement, TwistMeasurement
from ekf_localization.core.units import NS_PER_S as SEC
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config, parse_ekf_settings
from ekf_localization.ros.parameters import ParameterError

DIAG = [4e-4, 9e-4, 0.0, 0.0, 0.0, 1e-3]


def values(**overrides) -> dict:
    v = {"odom0": "diff_drive_controller/odom", "odom0_config": fuse(6, 7, 11), "frequency": 50.0}
    v.update(overrides)
    return v


def _matrix(diag) -> list[float]:
    return [float(c) for c in np.diag(diag).ravel()]


ASYMMETRIC = _matrix(DIAG)
ASYMMETRIC[1] = 1e-4
NOT_PSD = _matrix([1e-3, 1e-3, 0, 0, 0, 1e-3])
NOT_PSD[1] = NOT_PSD[6] = 2e-3  # |correlation| > 1
BAD = [
    ([1e-3] * 5, "6 finite variances"),
    ([1e-3] * 35, "36 values"),
    ([1e-3, math.nan, 0, 0, 0, 1e-3], "finite"),
    ([1e-3, math.inf, 0, 0, 0, 1e-3], "finite"),
    ([1e-3, -1e-4, 0, 0, 0, 1e-3], ">= 0"),
    (ASYMMETRIC, "symmetric"),
    (NOT_PSD, "positive semi-definite"),
    ("0.1", "list of floats"),
]


@pytest.mark.parametrize(("value", "form"), BAD, ids=[str(i) for i in range(len(BAD))])
@pytest.mark.parametrize("name", ["odom0", "twist0"])
def test_a_bad_twist_covariance_is_refused_naming_it(name: str, value, form: str) -> None:
    v = values(**{f"{name}_twist_covariance": value})
    if name == "twist0":
        v.update(twist0="base/twist", twist0_config=fuse(6, 7, 11))
    with pytest.raises(ParameterError, match=f"{name}_twist_covariance") as err:
        parse_ekf_settings(v, MODELS)
    assert form in str(err.value)


def test_a_matrix_singular_on_the_fused_fields_is_refused() -> None:
    C = _matrix([1e-3, 1e-3, 0, 0, 0, 1e-3])
    C[1] = C[6] = 1e-3  # vx and vy perfectly correlated: every message would be refused
    with pytest.raises(ParameterError, match="odom0_twist_covariance.*positive definite on the fused"):
        parse_ekf_settings(values(odom0_twist_covariance=C), MODELS)


def test_six_variances_are_the_diagonal_and_a_zero_fused_variance_is_noted() -> None:
    settings = parse_ekf_settings(values(odom0_twist_covariance=DIAG), MODELS)
    given = settings.config.inputs[0].settings.twist_covariance
    assert np.array_equal(np.reshape(given, (6, 6)), np.diag(DIAG))
    assert settings.warnings == ()
    noted = parse_ekf_settings(values(odom0_twist_covariance=[0.0, *DIAG[1:]]), MODELS)
    assert any("odom0_twist_covariance: zero variance on fused vx" in w for w in noted.warnings)
    assert parse_ekf_settings(values(), MODELS).config.inputs[0].settings.twist_covariance == ()


def _odometry(t: int, cov: np.ndarray) -> OdometryMeasurement:
    twist = np.array([0.4 + 0.1 * math.sin(t / SEC), 0.05, 0.0, 0.0, 0.0, 0.3])
    return OdometryMeasurement(t, "odom", "base_link", np.zeros(6), np.eye(6), twist, cov)


def _run(overrides: dict, cov: np.ndarray, kind: str = "odom") -> np.ndarray:
    """The covariance and state after 1 s of 50 Hz messages carrying ``cov``."""
    if kind == "twist":
        overrides = {"twist0": "base/twist", "twist0_config": fuse(6, 7, 11),
                     **{k.replace("odom0", "twist0"): v for k, v in overrides.items()}}
        v = {"frequency": 50.0, **overrides}
    else:
        v = values(**overrides)
    loc = make_localizer(parse_ekf_config(v, MODELS))
    t0 = 10 * SEC
    for k in range(50):
        t = t0 + k * SEC // 50
        m = _odometry(t, cov)
        if kind == "twist":
            m = TwistMeasurement(t, "base_link", m.twist, cov)
        res = loc.add_measurement(f"{kind}0", m, now_ns=t)
        assert res.applied == ("twist",), res
    est = loc.committed()
    return np.concatenate([est.state, est.covariance.ravel()])


@pytest.mark.parametrize("kind", ["odom", "twist"])
def test_the_parameter_replaces_the_message_covariance(kind: str) -> None:
    C = np.diag(DIAG)
    C[0, 1] = C[1, 0] = 2e-4  # a full matrix: correlations are kept
    placeholder = np.eye(6) * 0.1  # mecanum_drive_controller's fixed diagonal
    replaced = _run({"odom0_twist_covariance": [float(c) for c in C.ravel()]}, placeholder, kind)
    assert np.array_equal(replaced, _run({}, C, kind))
    assert not np.allclose(replaced, _run({}, placeholder, kind))
    # a driver that publishes no covariance (zeros, or NaN) is fused with the parameter's
    assert np.array_equal(_run({"odom0_twist_covariance": DIAG}, np.zeros((6, 6)), kind),
                          _run({}, np.diag(DIAG), kind))
    assert np.array_equal(_run({"odom0_twist_covariance": DIAG}, np.full((6, 6), math.nan), kind),
                          _run({}, np.diag(DIAG), kind))


def test_variance_scale_and_the_zero_variance_floor_apply_after_it() -> None:
    scaled = _run({"odom0_twist_covariance": DIAG, "odom0_variance_scale": 3.0}, np.eye(6) * 0.1)
    assert np.allclose(scaled, _run({}, np.diag(DIAG) * 3.0), rtol=1e-12, atol=0.0)
    zero_vx = [0.0, *DIAG[1:]]
    floored = _run({"odom0_twist_covariance": zero_vx, "zero_variance_floor": 2e-4}, np.eye(6) * 0.1)
    assert np.array_equal(floored, _run({}, np.diag([2e-4, *DIAG[1:]])))
