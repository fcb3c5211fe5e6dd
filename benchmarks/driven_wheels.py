"""The drive's four mecanum wheel encoders, quantised and jittered: which route is most accurate?

    python benchmarks/driven_wheels.py [--seconds 60] [--seeds 1 2 ... 10] [--slip 1.0]

The simulator world drives a seeded path for each seed; its wheel encoders (sim_robot.world.
wheel_encoder_sensor) give positions quantised at 537.7 counts per turn, read out every
16-41 ms around 20 ms. The wheels' angles are exact; the body slips (the world's velocity noise).
Printed: the (x, y) RMSE against the truth of

* ``joint``: a jointN input, geometry mecanum, the speed term at the predicted speed and the
  quantisation term (docs/models.md, driven wheels);
* ``joint_eq32``: the same with eq. 32 at the measured speed and no quantisation term;
* ``dead3``: the wheels turned into three virtual dead wheels (eq. 30 of the wheels' twist), eq. 32;
* ``twist_fixed``: the wheels' twist (eq. 24 of the position differences) with one fixed
  covariance, the joint model's at rest and the mean interval;
* ``integration``: that twist integrated (no filter).

Each filter has only that input (no IMU, no camera), with config/ekf.yaml's other settings.
The world has config/sim.yaml's truth noise (``--slip`` scales it: at 1 the wheels barely slip
and quantisation dominates) and wheel limits; each route runs with the speed coefficient
a = 0.002 (the default) and a = 0 (the simulated wheels have no noise in proportion to their
speed).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

from ekf_localization.core.measurements import JointStateMeasurement, TwistMeasurement
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import parameters_from_yaml
from sim_robot.world.camera_sensor import CameraConfig
from sim_robot.world.dead_wheel_sensor import DeadWheelConfig
from sim_robot.world.drives import DriveLimits
from sim_robot.world.wheel_encoder_sensor import WheelEncoderConfig, WheelEncoderReading
from sim_robot.world.world import TruthReading, World, WorldConfig

REPO = Path(__file__).resolve().parents[1]
WHEELS = ("rear_left", "rear_right", "front_left", "front_right")
PODS = ("left", "right", "lateral")
B = 1e-6  # (m/s)², the wheel speed floor (the body's slip over an interval is ~2e-7)


def _base() -> dict:
    values = parameters_from_yaml(REPO / "config" / "ekf.yaml", "ekf_node")
    values = {k: v for k, v in values.items() if not k.startswith(("odom0", "pose0", "imu0"))}
    values.update(use_control=False, smooth_lagged_data=False, publish_tf=False)
    return values


def _localizers(world: World, q: float, a: float, b: float) -> dict:
    kin = world.config.mecanum
    r = kin.wheel_radius
    joint = {"joint0": "joint_states", "joint0_geometry": "mecanum", "joint0_names": list(WHEELS),
             "joint0_wheel_radius": r, "joint0_half_wheelbase": kin.half_length,
             "joint0_half_track": kin.half_width, "joint0_speed_variance_coeff": a,
             "joint0_speed_variance_floor": b, "joint0_position_resolution": q, "joint0_max_speed": 10.0}
    old = {**joint, "joint0_speed_variance_at": "measured", "joint0_position_resolution": 0.0}
    dead = {"joint0": "joint_states", "joint0_names": list(PODS), "joint0_wheel_radius": 1.0,
            "joint0_half_spacing": 0.17, "joint0_lateral_offset": 0.1, "joint0_speed_variance_coeff": a,
            "joint0_speed_variance_floor": b, "joint0_speed_variance_at": "measured",
            "joint0_max_speed": 10.0}
    twist = {"twist0": "wheel_odometry",
             "twist0_config": [False] * 6 + [True, True, False, False, False, True] + [False] * 3}
    return {name: make_localizer(parse_ekf_config({**_base(), **p}, MODELS))
            for name, p in (("joint", joint), ("joint_eq32", old), ("dead3", dead), ("twist_fixed", twist))}


def run(seed: int, seconds: float, slip: float, a: float) -> dict[str, float]:
    """``slip`` scales config/sim.yaml's truth noise (its process_noise); its wheel limits apply."""
    sim = parameters_from_yaml(REPO / "config" / "sim.yaml", "sim_node")
    cfg = dataclasses.replace(
        WorldConfig(), camera=CameraConfig(enabled=False), dead_wheels=DeadWheelConfig(enabled=False),
        wheel_encoders=WheelEncoderConfig(enabled=True),
        limits=DriveLimits(sim["limits.wheel_speed_limit"] or math.inf,
                           sim["limits.wheel_acceleration_limit"] or math.inf),
        velocity_variance_per_step=tuple(slip * v for v in sim["process_noise.velocity_variance_per_step"]),
        pose_variance_rate=tuple(slip * v for v in sim["process_noise.pose_variance_rate"]))
    world = World(cfg, seed=seed)
    world.reset(np.zeros(3))
    kin, q = cfg.mecanum, cfg.wheel_encoders.resolution
    r = kin.wheel_radius
    b = B
    locs = _localizers(world, q, a, b)
    F = kin.forward_matrix  # wheels rad/s -> [vx vy wz] (eq. 24)
    pods = DeadWheelGeometry(0.17, 0.1).encoders_from_twist @ F  # wheel angles -> pod distances (r = 1)
    dt_mean = ns_to_s(cfg.wheel_encoders.period_ns)
    C_E = np.eye(4) * (b + (r * q) ** 2 / (6 * dt_mean**2))
    C = np.eye(6) * 1e6
    C[np.ix_([0, 1, 5], [0, 1, 5])] = (F / r) @ C_E @ (F / r).T  # twist from surface speeds
    pose, prev = np.zeros(3), None
    err = {k: [] for k in (*locs, "integration")}
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * math.pi, 3)
    for step in range(int((seconds + 1.0) * 100)):
        t = step * 0.01 - 1.0  # at rest for the first second: every route starts before the motion
        world.set_command((0.9 * math.sin(0.35 * t + phase[0]), 0.6 * math.sin(0.23 * t + phase[1]),
                           1.5 * math.sin(0.3 * t + phase[2])) if t > 0.0 else (0.0, 0.0, 0.0))
        for rd in world.advance(10_000_000):
            if isinstance(rd, WheelEncoderReading):
                pos = rd.positions[0]
                locs["joint"].add_measurement("joint0", JointStateMeasurement(rd.stamp_ns, WHEELS, pos))
                locs["joint_eq32"].add_measurement("joint0", JointStateMeasurement(rd.stamp_ns, WHEELS, pos))
                locs["dead3"].add_measurement("joint0", JointStateMeasurement(rd.stamp_ns, PODS, pods @ pos))
                if prev is not None:
                    dt = ns_to_s(rd.stamp_ns - prev[0])
                    tw = F @ (pos - prev[1]) / dt
                    mid = prev[0] + (rd.stamp_ns - prev[0]) // 2
                    locs["twist_fixed"].add_measurement(
                        "twist0", TwistMeasurement(mid, "base_link", np.r_[tw[:2], 0, 0, 0, tw[2]], C))
                    pose = _integrate(pose, tw, dt)
                prev = (rd.stamp_ns, pos)
            elif isinstance(rd, TruthReading) and prev is not None and rd.stamp_ns > 1_000_000_000:
                xy = rd.truth[0, :2]
                for k, loc in locs.items():
                    est = loc.estimate_at(rd.stamp_ns)
                    err[k].append(est.state[:2] - xy)
                err["integration"].append(pose[:2] - xy)  # at the last read-out (<= 41 ms old)
    return {k: float(np.sqrt(np.mean(np.sum(np.square(e), axis=1)))) for k, e in err.items()}


def ns_to_s(ns: int) -> float:
    return ns * 1e-9


def _integrate(pose: np.ndarray, tw: np.ndarray, dt: float) -> np.ndarray:
    """The pose after driving body twist ``tw`` for ``dt`` (midpoint heading)."""
    th = pose[2] + 0.5 * tw[2] * dt
    c, s = math.cos(th), math.sin(th)
    return pose + dt * np.array([tw[0] * c - tw[1] * s, tw[0] * s + tw[1] * c, tw[2]])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    ap.add_argument("--slip", type=float, default=1.0, help="scale of config/sim.yaml's truth noise")
    args = ap.parse_args(argv)
    for a in (0.002, 0.0):
        rows = [run(seed, args.seconds, args.slip, a) for seed in args.seeds]
        print(f"\nslip x{args.slip:g}, a = {a:g}: (x, y) RMSE over {args.seconds:g} s, seeds {args.seeds}")
        print(f"{'route':<12}{'mean m':>9}{'route / integration, mean ± s.e.':>34}{'median':>8}")
        for n in rows[0]:
            r = np.array([row[n] / row["integration"] for row in rows])
            se = r.std(ddof=1) / math.sqrt(len(r)) if len(r) > 1 else 0.0
            print(f"{n:<12}{np.mean([row[n] for row in rows]):>9.4f}{r.mean():>26.3f} ± {se:.3f}"
                  f"{np.median(r):>8.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
