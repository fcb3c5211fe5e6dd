"""ekf_demo's drives: the simulated robot and the filter's configuration each ``--drive`` runs,
and the swerve's own dead reckoning for the report.

``--drive mecanum`` (the default) is seed 000's robot (config/sim.yaml, config/ekf.yaml);
``--drive tank`` the tank (config/sim_tank.yaml, config/ekf_tank.yaml, pure pursuit in
differential mode); ``--drive swerve`` the swerve (config/sim_swerve.yaml,
config/ekf_swerve.yaml: its module states on joint_states). ``--sim-params FILE`` replaces the
drive's sim YAML: the simulated robot (geometry, grip, sensor errors) apart from the filter's.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ekf_localization.tools.evaluation import Trajectory

TOPIC_JOINTS = "/joint_states"
MODULE_DEAD_RECKONING_ROW = "dead reckoning (swerve modules)"


@dataclass(frozen=True)
class Drive:
    """One ``--drive``: its sim and EKF YAMLs (in config/), the pure pursuit mode, and whether the
    EKF reads joint_states (then the recorder alone subscribes the dead-wheel odometry)."""

    sim_yaml: str
    ekf_yaml: str
    pursuit_mode: str = "holonomic"
    joint_states: bool = False


DRIVES = {"mecanum": Drive("sim.yaml", "ekf.yaml"),
          "tank": Drive("sim_tank.yaml", "ekf_tank.yaml", "differential"),
          "swerve": Drive("sim_swerve.yaml", "ekf_swerve.yaml", joint_states=True)}


def module_dead_reckoning(bag: Path, ekf_params: Path) -> Trajectory | None:
    """The pose integrated from the recorded module states alone (the unweighted least-squares twist
    of the modules, models.swerve; the pose exponential over each interval) from the EKF's initial
    state: what the modules' odometry says without the IMU, the camera or cmd_vel. None when
    ``ekf_params`` has no swerve input or the bag no joint_states."""
    from ekf_localization.core.angles import wrap_angle
    from ekf_localization.core.units import ns_to_seconds
    from ekf_localization.inputs import joint
    from ekf_localization.models.drive_response import pose_step
    from ekf_localization.models.swerve import SwerveKinematics, module_vectors
    from ekf_localization.ros.parameters import parameters_from_yaml
    from ekf_localization.tools import bag_io

    p = parameters_from_yaml(ekf_params, "ekf_node")
    if p.get("joint0_geometry") != "swerve":
        return None
    from ekf_localization.core.joint_states import EncoderInputConfig
    from ekf_localization.core.swerve_states import SwerveSpeeds

    known = {f.name for f in dataclasses.fields(EncoderInputConfig)}  # not slip_*: the check's
    fields = {s.name: p[f"joint0_{s.name}"] for s in joint.PARAMETERS[1:]
              if f"joint0_{s.name}" in p and s.name in known}
    cfg = EncoderInputConfig(names=tuple(p["joint0_names"]), **{
        **fields, "steer_names": tuple(fields.get("steer_names", ())),
        "module_positions": tuple(fields.get("module_positions", ())),
        "directions": tuple(fields.get("directions", ()))})
    speeds = SwerveSpeeds(cfg)
    fit = np.linalg.pinv(SwerveKinematics(cfg.module_positions).module_rows)
    x0 = p.get("initial_state", [0.0] * 15)
    pose = [float(x0[0]), float(x0[1]), float(x0[5])]
    ts, states, last = [], [], None
    G = [[0.0] * 4, [0.0] * 4]
    for m in bag_io.iter_messages(bag, [TOPIC_JOINTS]):
        sample, reason = speeds.update(joint.read(m.msg))
        if sample is None or reason is not None:
            continue
        v = fit @ module_vectors(sample.speeds, sample.angles)
        if last is not None:
            dt = ns_to_seconds(sample.stamp_ns - last)
            dx, dy = pose_step(pose[2], v[0] * dt, v[1] * dt, v[2] * dt, G)
            pose = [pose[0] + dx, pose[1] + dy, wrap_angle(pose[2] + v[2] * dt)]
        last = sample.stamp_ns
        ts.append(sample.stamp_ns)
        states.append([*pose, *v])
    if not ts:
        return None
    return Trajectory(np.array(ts, dtype=np.int64), np.array(states))
