"""The same simulated run through the EKF twice: dead wheels as JointState vs as the odometry twist.

ROS-free: the simulator world drives a seeded path; one Localizer gets config/ekf.yaml's
odometry twist (eq. 29's twist with its propagated covariance), the other
config/ekf_joint_states.yaml's joint positions (speeds from position differences, R = a·E² + b
per wheel). Both also fuse the IMU; the camera is left out so that the dead wheels matter.
"""

from __future__ import annotations

import math

import numpy as np
from helpers.ros_helpers import REPO

from ekf_localization.core.measurements import ImuMeasurement, JointStateMeasurement, TwistMeasurement
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import parameters_from_yaml
from ekf_localization.tools.evaluation import Trajectory, rmse
from sim_robot.world.camera_sensor import CameraConfig
from sim_robot.world.dead_wheel_sensor import DeadWheelReading
from sim_robot.world.imu_sensor import ImuReading
from sim_robot.world.world import TruthReading, World, WorldConfig

NAMES = ("left_pod", "right_pod", "lateral_pod")
BIG = 1e6


def _config(name: str):
    values = {k: v for k, v in parameters_from_yaml(REPO / "config" / name, "ekf_node").items()
              if not k.startswith("pose0")}
    if "joint0" in values:  # a·E² at the measured speed, as the simulated twist's covariance is:
        values["joint0_speed_variance_at"] = "measured"  # the two routes share one noise model
    return parse_ekf_config(values, MODELS)


def _twist(r: DeadWheelReading) -> TwistMeasurement:
    C = np.eye(6) * BIG
    C[np.ix_([0, 1, 5], [0, 1, 5])] = r.twist_cov[0]
    tw = r.twist[0]
    return TwistMeasurement(r.stamp_ns, "base_link", np.array([tw[0], tw[1], 0, 0, 0, tw[2]]), C)


def _imu(r: ImuReading) -> ImuMeasurement:
    return ImuMeasurement(r.stamp_ns, "base_link", np.array([0.0, 0.0, r.yaw[0]]),
                          np.diag([BIG, BIG, r.yaw_variance]), np.array([0.0, 0.0, r.yaw_rate[0]]),
                          np.diag([BIG, BIG, r.yaw_rate_variance]), np.zeros(3), np.eye(3))


def run(seed: int) -> dict[str, tuple[dict, np.ndarray]]:
    world = World(WorldConfig(camera=CameraConfig(enabled=False)), seed=seed)
    world.reset(np.zeros(3))
    locs = {"joint": make_localizer(_config("ekf_joint_states.yaml")),
            "twist": make_localizer(_config("ekf.yaml"))}
    wr = world.config.dead_wheels.wheel_radius
    truth, est = [], {k: [] for k in locs}
    sig = {k: [] for k in locs}
    for step in range(600):  # 6 s: forward, strafing arcs, turning in place
        t = step * 0.01
        world.set_command((0.8 * math.cos(0.7 * t), 0.5 * math.sin(1.1 * t), 1.2 * math.sin(0.5 * t)))
        for r in world.advance(10_000_000):
            if isinstance(r, DeadWheelReading):
                locs["twist"].add_measurement("odom0", _odometry(r), r.stamp_ns)
                js = JointStateMeasurement(r.stamp_ns, NAMES, r.distances[0] / wr)
                assert not locs["joint"].add_measurement("joint0", js, r.stamp_ns).rejected
                if r.stamp_ns > 500_000_000:  # σ of the velocity at each dead-wheel update's stamp
                    half = world.config.dead_wheels.period_ns // 2  # joint speeds: interval midpoint
                    for k, t_upd in (("twist", r.stamp_ns), ("joint", r.stamp_ns - half)):
                        sig[k].append(np.sqrt(np.diag(locs[k].estimate_at(t_upd).covariance)[3:6]))
            elif isinstance(r, ImuReading):
                for loc in locs.values():
                    loc.add_measurement("imu0", _imu(r), r.stamp_ns)
            elif isinstance(r, TruthReading) and r.stamp_ns > 500_000_000:
                truth.append((r.stamp_ns, r.truth[0]))
                for k, loc in locs.items():
                    e = loc.estimate_at(r.stamp_ns)
                    est[k].append(e.state)
    t_ns = np.array([t for t, _ in truth])
    tr = Trajectory(t_ns, np.array([s for _, s in truth]))
    return {k: (rmse(Trajectory(t_ns, np.array(est[k])), tr), np.mean(sig[k], axis=0)) for k in locs}


def _odometry(r: DeadWheelReading):
    from ekf_localization.core.measurements import OdometryMeasurement

    tw = _twist(r)
    return OdometryMeasurement(r.stamp_ns, "odom", "base_link", np.zeros(6), np.eye(6) * BIG,
                               tw.twist, tw.covariance)


def test_joint_state_input_as_accurate_as_the_twist_input(record_property) -> None:
    """Equal (x, y) accuracy within the seed-to-seed spread, and the same velocity covariance.

    The velocity RMSE is not compared tightly: the simulated truth velocity has white noise at
    every 1 ms tick (seed 000 eq. 26), which an instantaneous twist sample sees and a position
    difference (the mean speed over 10 ms) averages out.
    """
    xy = {"joint": [], "twist": []}
    for seed in (1, 2, 3):
        res = run(seed)
        (rj, sj), (rt, st) = res["joint"], res["twist"]
        print(f"\nseed {seed}: (x,y) RMSE joint_states {rj['xy']:.4f} m, twist {rt['xy']:.4f} m; "
              f"vx RMSE {rj['vx']:.4f} / {rt['vx']:.4f} m/s; mean σ(vx, vy, vyaw) at each update: "
              f"joint {np.round(sj, 4)}, twist {np.round(st, 4)}")
        assert rj["xy"] < 0.1 and rt["xy"] < 0.1
        assert rj["vx"] < 2.0 * rt["vx"]
        # the joint input's covariance comes from eq. 32 at the encoder speeds, the twist's is eq. 29's
        # propagation of it: the same vx, vy σ at each update's stamp (vyaw: the gyro at the twist's
        # stamp, 5 ms after the joint update, dominates it)
        np.testing.assert_allclose(sj[:2], st[:2], rtol=0.1)
        xy["joint"].append(rj["xy"])
        xy["twist"].append(rt["xy"])
    mj, mt = np.mean(xy["joint"]), np.mean(xy["twist"])
    record_property("xy_rmse_joint_m", float(mj))
    record_property("xy_rmse_twist_m", float(mt))
    spread = np.std(np.array(xy["joint"]) - np.array(xy["twist"]))
    assert abs(mj - mt) < max(0.3 * mt, 2.0 * spread), (xy, spread)


def test_joint_states_config_is_ekf_yaml_but_for_the_dead_wheel_input() -> None:
    """config/ekf_joint_states.yaml must follow config/ekf.yaml, or the comparison compares more."""
    def rest(name: str) -> dict:
        values = parameters_from_yaml(REPO / "config" / name)
        return {k: v for k, v in values.items() if not k.startswith(("odom0", "joint0"))}

    assert rest("ekf_joint_states.yaml") == rest("ekf.yaml")
