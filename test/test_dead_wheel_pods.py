"""Dead-wheel pods with their own offsets, angles and scales (docs/models.md, "Dead-wheel pods"):
the rows, their Jacobian, the jointN parameters and the simulator's true pods."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_joint_states import R_WHEEL, D, W, _localizer, joint_params, js

from ekf_localization.inputs.joint import JointHandler, pod_geometry
from ekf_localization.models.registry import MODELS
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry, PodGeometry
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import ParameterError
from sim_robot.ros.sim_params import parse_parameters
from sim_robot.world.dead_wheel_sensor import DeadWheelConfig, DeadWheelSensor

MS = 1_000_000
PODS = PodGeometry((0.19, -0.15, 0.12), (0.02, -0.03, 1.55), (1.03, 0.97, 1.02))


def test_the_symmetric_pods_are_eq_30() -> None:
    np.testing.assert_allclose(PodGeometry.symmetric(W, D).encoders_from_twist,
                               DeadWheelGeometry(W, D).encoders_from_twist, atol=1e-15)
    assert PodGeometry.symmetric(W, D, 2).count == 2


def test_a_pod_reads_its_contact_point_velocity_along_its_direction() -> None:
    """A pod at (px, py) rolling along (cos α, sin α) reads k·u·(v + ω × p); its offset to the
    left of the rolling line is o = −px·sin α + py·cos α, and px·cos α + py·sin α does not enter."""
    v, w = np.array([0.3, -0.2]), 0.7
    for along in (0.0, 0.25, -1.0):
        for o, a, k in zip(*(PODS.offsets, PODS.angles, PODS.scales), strict=True):
            u, n = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
            p = o * n + along * u
            E = k * u @ (v + w * np.array([-p[1], p[0]]))
            row = PodGeometry((o,), (a,), (k,)).encoders_from_twist[0]
            assert row @ np.r_[v, w] == pytest.approx(E, abs=1e-12)


def test_the_rows_jacobian_is_the_finite_difference() -> None:
    J = PODS.rows_jacobian()
    p, h = PODS.vector, 1e-6
    for j in range(len(p)):
        step = np.zeros_like(p)
        step[j] = h
        fd = (PodGeometry.from_vector(p + step).encoders_from_twist
              - PodGeometry.from_vector(p - step).encoders_from_twist) / (2 * h)
        np.testing.assert_allclose(J[:, :, j], fd, atol=1e-8)


def test_bad_pod_geometry_is_refused() -> None:
    for args in (((0.1,), (0.0, 0.0), (1.0,)), ((0.1,), (0.0,), (0.0,)), ((math.nan,), (0.0,), (1.0,))):
        with pytest.raises(ValueError):
            PodGeometry(*args)


# --- the jointN parameters -------------------------------------------------------------------------

def _settings(**extra):
    (inp,) = parse_ekf_config(joint_params(**extra), MODELS).inputs
    return inp.settings


def test_without_pod_lists_the_rows_are_eq_33_as_before() -> None:
    cfg = _settings()
    assert cfg.pod_offsets == () and pod_geometry(cfg) is None


def test_pod_lists_parse_and_missing_ones_take_the_symmetric_values() -> None:
    cfg = _settings(joint0_pod_scales=[1.01, 0.99, 1.0])
    pods = pod_geometry(cfg)
    assert pods == PodGeometry((W, -W, D), (0.0, 0.0, 0.5 * math.pi), (1.01, 0.99, 1.0))


@pytest.mark.parametrize("name, value", [
    ("joint0_pod_offsets", [0.1, 0.2]), ("joint0_pod_angles", [0.0, math.inf, 1.5]),
    ("joint0_pod_scales", [1.0, 0.0, 1.0]), ("joint0_pod_scales", [1.0, -1.0, 1.0]),
])
def test_bad_pod_lists_name_the_parameter(name, value) -> None:
    with pytest.raises(ParameterError) as err:
        parse_ekf_config(joint_params(**{name: value}), MODELS)
    assert err.value.name == name


def test_two_pods_on_the_tank_state_take_the_first_two_of_each_list() -> None:
    (inp,) = parse_ekf_config(joint_params(model="differential", joint0_pod_offsets=[0.2, -0.16, 0.1]),
                              MODELS).inputs
    assert inp.settings.pod_offsets == (0.2, -0.16)


def test_the_handler_fuses_the_pods_rows() -> None:
    """A filter given the true pods tracks the twist from their readings; eq. 33's rows do not."""
    extra = {f"joint0_pod_{f}": list(getattr(PODS, f)) for f in ("offsets", "angles", "scales")}
    twist = np.array([0.4, -0.2, 0.5])
    E = PODS.encoders_from_twist @ twist
    results = []
    for params in (joint_params(**extra), joint_params()):
        loc = _localizer(params)
        for k in range(60):
            loc.add_measurement("joint0", js(k * 10 * MS, E * k * 0.01 / R_WHEEL))
        results.append(loc.committed().state[3:6])
    np.testing.assert_allclose(results[0], twist, atol=1e-3)
    assert np.max(np.abs(results[1] - twist)) > 0.01


def test_the_handler_h_is_the_pods_rows_on_the_state_columns() -> None:
    extra = {f"joint0_pod_{f}": list(getattr(PODS, f)) for f in ("offsets", "angles", "scales")}
    handler = _localizer(joint_params(**extra))._handlers["joint0"]
    assert isinstance(handler, JointHandler)
    np.testing.assert_array_equal(handler.H[:, 3:6], PODS.encoders_from_twist)
    np.testing.assert_array_equal(handler.H[:, :3], 0.0)
    plain = _localizer(joint_params())._handlers["joint0"]
    np.testing.assert_array_equal(plain.H, MODELS["mecanum"].dead_wheel_rows(W, D))  # eq. 33 as before


# --- the simulator's true pods ---------------------------------------------------------------------

def test_the_simulator_reads_with_the_true_pods_and_converts_with_the_nominal_geometry() -> None:
    nominal = DeadWheelGeometry(W, D)
    sensor = DeadWheelSensor(DeadWheelConfig(geometry=nominal, pods=PODS, integrate_pose=False), 1,
                             np.random.default_rng(0))
    plain = DeadWheelSensor(DeadWheelConfig(geometry=nominal, integrate_pose=False), 1,
                            np.random.default_rng(0))
    v = np.array([[0.5, 0.1, 0.8]])
    a, b = sensor.sample(10 * MS, v, v * 0.01), plain.sample(10 * MS, v, v * 0.01)
    noise = plain.config.noise
    E_nominal, E_true = v @ nominal.encoders_from_twist.T, v @ PODS.encoders_from_twist.T
    z = (b.encoders - E_nominal) / np.sqrt(noise.variances(E_nominal))  # the same draw in both
    np.testing.assert_allclose(a.encoders, E_true + z * np.sqrt(noise.variances(E_true)), atol=1e-12)
    np.testing.assert_allclose(a.twist, a.encoders @ nominal.twist_from_encoders.T, atol=1e-15)


def test_sim_params_take_the_true_pods_and_default_to_none() -> None:
    world, _ = parse_parameters({})
    assert world.dead_wheels.pods is None
    world, _ = parse_parameters({"dead_wheels.pod_scales": [1.03, 0.97, 1.0]})
    assert world.dead_wheels.pods == PodGeometry((0.17, -0.17, 0.1), (0.0, 0.0, 0.5 * math.pi),
                                                 (1.03, 0.97, 1.0))
    with pytest.raises(ParameterError) as err:
        parse_parameters({"dead_wheels.pod_scales": [1.0, 0.0, 1.0]})
    assert "dead_wheels.pod_scales" in str(err.value)
