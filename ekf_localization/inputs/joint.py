"""``jointN``: sensor_msgs/JointState of wheel encoders (ros2_control's joint_state_broadcaster),
fused as the wheels' surface speeds.

``jointN_geometry`` says which wheels: ``dead_wheels`` (unpowered odometry pods, seed 000
eq. 29-33: the model's ``dead_wheel_rows``), ``mecanum`` (the drive's four wheels, eq. 23-24)
or ``differential`` (its two wheels): the model's ``driven_wheel_rows``, its inverse kinematics
on the state's body twist, times the wheel radius; or ``swerve`` (steered modules, each a drive
and a steer joint): each module's velocity vector on the body twist (inputs/swerve.py). Driven wheels may be
checked for slip and collisions (``slip_detection``, inputs/slip.py).

core.joint_states turns successive messages into speeds E (m/s) stamped at each interval's
middle; :class:`JointHandler` fuses them as z = E = H x with
R = diag(a·Ê² + b + (r·q)²/(6·Δt²)), Ê = H x̂⁻ the speeds the filter predicts at the sample's
stamp (docs/models.md, driven wheels). With ``tilt_compensation`` on a ramp, H = M·P⁻¹ (the
wheels measure the velocity along the surface, the state is horizontal) and R gets the tilt's
uncertainty through J = ∂h/∂(roll, pitch) (core.tilt). Its :class:`UnitsGuard` sets the
input's ``SourceStats.fault`` (an ERROR on /diagnostics) while most messages are refused.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from ekf_localization.core.config import InputConfig
from ekf_localization.core.fusion_context import Fused, FusionContext
from ekf_localization.core.joint_states import (
    GEOMETRIES,
    WHEEL_ORDER,
    EncoderInputConfig,
    EncoderSample,
    EncoderSpeeds,
    UnitsGuard,
    validate_encoder_config,
)
from ekf_localization.core.linalg import symmetrise
from ekf_localization.core.linear import LinearMeasurement
from ekf_localization.core.measurements import JointStateMeasurement
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.core.part_plans import PartPlan
from ekf_localization.core.tilt import TiltSample, horizontal_projection, projection_tilt_jacobian
from ekf_localization.core.tilt_input import TWIST_FIELDS
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.inputs.joint_sampling import JointSampling
from ekf_localization.inputs.kind import InputKind, ParameterSpec, Report
from ekf_localization.inputs.slip import SLIP_PARAMETERS, SlipSettings, monitor
from ekf_localization.inputs.swerve import SwerveHandler
from ekf_localization.models.sensors.dead_wheels import PodGeometry
from ekf_localization.models.swerve import layout_problem

ENCODER_PART = "encoders"
POD_LISTS = ("pod_offsets", "pod_angles", "pod_scales")


def read(msg) -> JointStateMeasurement:
    """Positions rad, velocities rad/s; empty arrays when absent (copies: a bag's are read-only views)."""
    return JointStateMeasurement(
        stamp_ns=stamp_to_ns(msg.header.stamp), names=tuple(str(n) for n in msg.name),
        positions=np.array(msg.position, dtype=float), velocities=np.array(msg.velocity, dtype=float),
        efforts=np.array(msg.effort, dtype=float))


_E = EncoderInputConfig(names=("left", "right", "lateral"))
ENCODER_PARAMETERS = (
    ParameterSpec("names", "str_list", None, "",
                  "joint names in the geometry's wheel order: dead_wheels [left, right, lateral] (the "
                  "differential and tank models: [left, right], a third is ignored with a warning); "
                  "mecanum [rear_left, rear_right, front_left, front_right] (eq. 24's m1..m4); "
                  "differential [left, right]; swerve: each module's drive joint. Other joints in a "
                  "message are ignored", required=True),
    ParameterSpec("geometry", "str", _E.geometry, "",
                  "which wheels the joints are: dead_wheels (unpowered odometry pods), mecanum (the "
                  "drive's four wheels, eq. 23-24), differential (the drive's two wheels), swerve "
                  "(steered modules: steer_names, module_positions)",
                  lambda v: v in GEOMETRIES, "one of " + ", ".join(GEOMETRIES)),
    ParameterSpec("wheel_radius", "float", _E.wheel_radius, "m",
                  "wheel radius: joint position rad -> distance along the surface"),
    ParameterSpec("half_spacing", "float", _E.half_spacing, "m",
                  "W: the parallel wheels sit at ±W from the centre line (seed 000 eq. 29-30)"),
    ParameterSpec("lateral_offset", "float", _E.lateral_offset, "m",
                  "D: the lateral wheel sits this far behind the centre (negative: in front), "
                  "E_a = vy - D·vyaw (eq. 30)"),
    ParameterSpec("pod_offsets", "float_list", [], "m",
                  "dead_wheels, one per name: each pod's rolling line's offset from the centre, to the "
                  "left of its rolling direction (docs/models.md, dead-wheel pods); [] (default): "
                  "[W, -W, D] of half_spacing and lateral_offset"),
    ParameterSpec("pod_angles", "float_list", [], "rad",
                  "dead_wheels, one per name: each pod's rolling direction from base_link's x; [] "
                  "(default): [0, 0, pi/2]"),
    ParameterSpec("pod_scales", "float_list", [], "",
                  "dead_wheels, one per name: each pod's reading per metre it rolls (a wheel radius "
                  "off by 1 % is a scale of 1.01); [] (default): all 1"),
    ParameterSpec("speed_variance_coeff", "float", _E.speed_variance_coeff, "",
                  "a of the per-wheel speed variance a·E² + b (eq. 32)"),
    ParameterSpec("speed_variance_floor", "float", _E.speed_variance_floor, "(m/s)²", "b of a·E² + b"),
    ParameterSpec("use_velocities", "bool", _E.use_velocities, "",
                  "use the message's velocity array (rad/s) when it has one; false: speeds from position "
                  "differences (a message with velocities and no positions: its velocities)"),
    ParameterSpec("max_speed", "float", _E.max_speed, "m/s",
                  "a position step implying a faster wheel is an encoder reset or wrap: rejected "
                  "(encoder_jump)"),
    ParameterSpec("tilt_compensation", "bool", _E.tilt_compensation, "",
                  "fuse the speeds against the horizontal velocity with the IMU's roll and pitch"),
    ParameterSpec("half_wheelbase", "float", _E.half_wheelbase, "m",
                  "L (geometry mecanum): the wheels sit at ±L along x from the centre (eq. 23)"),
    ParameterSpec("half_track", "float", _E.half_track, "m",
                  "l (geometries mecanum, differential): the wheels sit at ±l from the centre line"),
    ParameterSpec("strafe_scale", "float", _E.strafe_scale, "",
                  "geometry mecanum: the robot's lateral velocity per the one eq. 23 gives from the wheels "
                  "(rollers slip sideways: below 1); the wheels' rows on ẏ are divided by it "
                  "(docs/models.md, driven wheels); 1: eq. 23"),
    ParameterSpec("directions", "float_list", [], "",
                  "+1 or -1 per name: -1 for a wheel whose joint turns backwards when the robot drives "
                  "forward (a mirrored motor); empty: all +1"),
    ParameterSpec("position_resolution", "float", _E.position_resolution, "rad",
                  "one encoder count in rad of the wheel (2π / counts per wheel turn): the speeds from "
                  "positions get the variance (wheel_radius·q)²/(6·Δt²) of two quantised readings; "
                  "0: not quantised"),
    ParameterSpec("speed_variance_at", "str", _E.speed_variance_at, "",
                  "where the speed term a·E² is evaluated: predicted (the filter's predicted wheel speed "
                  "at the sample's stamp; a quantised slow reading does not look certain) or measured "
                  "(seed 000 eq. 32 as written, as a driver computing its own covariance does)",
                  lambda v: v in ("predicted", "measured"), "predicted or measured"),
    ParameterSpec("steer_names", "str_list", [], "",
                  "swerve: the modules' steer joints (position: the wheel's direction, rad, 0 along x), "
                  "in the order of names"),
    ParameterSpec("module_positions", "float_list", [], "m",
                  "swerve: [x0, y0, x1, y1, ...] of each module's contact point in base_link, in the "
                  "order of names; two or more modules, not all at one point"),
    ParameterSpec("drive_gear_ratio", "float", _E.drive_gear_ratio, "",
                  "swerve: drive joint rad per wheel rad (1: the joint reports the wheel)"),
    ParameterSpec("coupling_ratio", "float", _E.coupling_ratio, "",
                  "swerve: drive joint rad per steer rad with the wheel held (coaxial modules such as "
                  "the MK4i); the wheel turns (drive - coupling_ratio*steer)/drive_gear_ratio"),
    ParameterSpec("steer_angle_variance", "float", _E.steer_angle_variance, "rad²",
                  "swerve: variance of a steer angle reading; across the wheel a module's velocity "
                  "has the variance speed²·this + speed_variance_floor"),
)
PARAMETERS = ENCODER_PARAMETERS + SLIP_PARAMETERS  # slip_*: driven geometries (inputs/slip.py)


def configure(values: Mapping[str, Any], name: str, spec: MotionModelSpec,
              report: Report) -> EncoderInputConfig | None:
    """A jointN input's encoder settings from its parsed ``values``."""
    if values["geometry"] != "dead_wheels":
        return _configure_driven(values, name, spec, report)
    if values["slip_detection"]:
        report.problem(name + "_slip_detection", "false with geometry dead_wheels (unpowered pods roll with "
                       "the floor: they measure a push, they do not slip)", True)
        return None
    key = name + "_names"
    want = spec.dead_wheel_count
    if want == 0:
        report.problem(name, f"no jointN input: model '{spec.name}' has no dead-wheel encoder measurement",
                       values["topic"])
        return None
    what = (f"a list of {want} joint names [left, right{', lateral' if want == 3 else ''}]"
            + (" (a lateral third name is ignored)" if want == 2 else ""))
    names = values["names"]
    if names is None:
        report.problem(key, what + " (required)")
        return None
    if len(names) not in (want, 3) or not all(names):
        report.problem(key, what, names)
        return None
    if len(names) > want:
        report.warn(f"{key}: model '{spec.name}' has no lateral velocity; '{names[2]}' is not used")
        names = names[:want]
        values = {**values, **{k: values[k][:want] for k in ("directions", *POD_LISTS) if values[k]}}
    return _checked(values, names, name, report)


def _checked(values: Mapping[str, Any], names, name: str, report: Report) -> EncoderInputConfig | None:
    cfg = EncoderInputConfig(names=tuple(names), **{p.name: values[p.name] for p in ENCODER_PARAMETERS[1:]})
    cfg = replace(cfg, directions=tuple(float(d) for d in cfg.directions),
                  **{k: tuple(float(v) for v in getattr(cfg, k)) for k in POD_LISTS},
                  steer_names=tuple(cfg.steer_names),
                  module_positions=tuple(float(v) for v in cfg.module_positions))
    problem = validate_encoder_config(cfg)
    if problem is not None:
        field_name, form = problem.split(": ", 1)
        report.problem(f"{name}_{field_name}", form, values.get(field_name, getattr(cfg, field_name)))
        return None
    return cfg


def _configure_driven(values: Mapping[str, Any], name: str, spec: MotionModelSpec,
                      report: Report) -> EncoderInputConfig | None:
    """A driven-wheel geometry: the names its wheel order needs, and rows the model can give."""
    geometry = values["geometry"]
    if values["names"] is None:
        report.problem(name + "_names", f"a list of joint names {WHEEL_ORDER[geometry]} (required)")
        return None
    cfg = _checked(values, values["names"], name, report)
    if cfg is None:
        return None
    if geometry == "swerve":
        return _configure_swerve(cfg, values, name, spec, report)
    if spec.driven_wheel_rows is None:
        report.problem(name + "_geometry", f"a geometry model '{spec.name}' can fuse (it has no driven-wheel "
                                           "rows)", geometry)
        return None
    try:
        spec.driven_wheel_rows(geometry, cfg.wheel_radius, cfg.half_wheelbase, cfg.half_track)
    except ValueError as exc:
        report.problem(name + "_geometry", f"a geometry model '{spec.name}' can fuse ({exc})", geometry)
        return None
    return replace(cfg, slip=SlipSettings.from_values(values))


def _configure_swerve(cfg: EncoderInputConfig, values: Mapping[str, Any], name: str, spec: MotionModelSpec,
                      report: Report) -> EncoderInputConfig | None:
    """A swerve layout the body twist can be fitted from, on a state with vx, vy and vyaw."""
    problem = layout_problem(np.reshape(cfg.module_positions, (-1, 2)))
    if problem is not None:
        report.problem(name + "_module_positions", problem, values["module_positions"])
        return None
    if not all(f in spec.state_fields for f in TWIST_FIELDS):
        report.problem(name + "_geometry", f"a geometry model '{spec.name}' can fuse (swerve modules need "
                                           "a state with vx, vy and vyaw)", "swerve")
        return None
    if cfg.tilt_compensation:
        report.problem(name + "_tilt_compensation", "false with geometry swerve (not supported)", True)
        return None
    return replace(cfg, slip=SlipSettings.from_values(values))


def pod_geometry(cfg: EncoderInputConfig) -> PodGeometry | None:
    """The dead-wheel pods' geometry when any pod_* list is set (the others: eq. 30's values);
    None: eq. 30's rows as they are."""
    if cfg.geometry != "dead_wheels" or not any(getattr(cfg, k) for k in POD_LISTS):
        return None
    base = PodGeometry.symmetric(cfg.half_spacing, cfg.lateral_offset, len(cfg.names))
    return PodGeometry(*(getattr(cfg, k) or getattr(base, k[4:]) for k in POD_LISTS))


def driven_rows(spec: MotionModelSpec, cfg: EncoderInputConfig) -> np.ndarray:
    """(wheels, state) the driven wheels' surface speeds (m/s) on the state: the wheel radius times
    the model's inverse kinematics, with mecanum's ẏ column divided by ``strafe_scale`` σ (the robot
    strafes σ times what eq. 23 gives from its wheels; docs/models.md, driven wheels)."""
    H = cfg.wheel_radius * spec.driven_wheel_rows(cfg.geometry, cfg.wheel_radius, cfg.half_wheelbase,
                                                  cfg.half_track)
    if cfg.strafe_scale != 1.0 and TWIST_FIELDS[1] in spec.state_fields:
        H[:, spec.state_fields.index(TWIST_FIELDS[1])] /= cfg.strafe_scale
    return H


def joint_handler(inp: InputConfig, ctx: FusionContext):
    """The handler of a jointN input: the swerve modules' or the wheel encoders'."""
    if inp.settings.geometry == "swerve":
        return SwerveHandler(inp, ctx, ENCODER_PART)
    return JointHandler(inp, ctx)


class JointHandler(JointSampling):
    """A jointN input: its speed tracker, its units guard and the model's encoder rows H (the
    geometry's: ``spec.dead_wheel_rows`` or ``spec.driven_wheel_rows`` times the wheel radius)."""

    def __init__(self, inp: InputConfig, ctx: FusionContext) -> None:
        cfg: EncoderInputConfig = inp.settings
        spec = ctx.spec
        self.config = cfg
        self.part = ENCODER_PART
        self.speeds = EncoderSpeeds(cfg)
        self.guard = UnitsGuard(cfg, inp.name)
        self._stats = ctx.stats[inp.name]
        self._estimate_at = ctx.estimate_at
        rows = spec.dead_wheel_rows if cfg.geometry == "dead_wheels" else spec.driven_wheel_rows
        if rows is None:
            raise ValueError(f"model '{spec.name}' has no {cfg.geometry} encoder measurement ({inp.name})")
        # the body-twist components [vx vy vyaw] the state has, as (index in the twist, state column)
        present = [j for j, f in enumerate(TWIST_FIELDS) if f in ctx.field_to_state]
        self.twist_idx = np.array(present, dtype=np.intp)
        self.cols = np.array([ctx.field_to_state[TWIST_FIELDS[j]] for j in present], dtype=np.intp)
        pods = pod_geometry(cfg)
        if pods is not None:  # each pod's row on the body twist (docs/models.md, dead-wheel pods)
            H = np.zeros((pods.count, len(spec.state_fields)))
            H[:, self.cols] = pods.encoders_from_twist[:, self.twist_idx]
        elif cfg.geometry == "dead_wheels":
            H = rows(cfg.half_spacing, cfg.lateral_offset)  # eq. 33
        else:  # wheel rad/s -> surface m/s
            H = driven_rows(spec, cfg)
        self.H = H
        self.M = H[:, self.cols]  # encoders <- body twist (mecanum's 4x3: the 4th row is redundant)
        self.M_inv = np.linalg.pinv(self.M)  # the body twist the speeds imply (least squares)
        m = H.shape[0]
        self.plan = PartPlan(ENCODER_PART, np.arange(m, dtype=np.intp), np.ix_(np.arange(m), np.arange(m)),
                             LinearMeasurement(H), inp.threshold(ENCODER_PART), "",
                             nis_key=f"{inp.name}/{ENCODER_PART}")
        self.plans = (self.plan,)
        self._joints = frozenset(cfg.names)
        self._tilt = ctx.tilt if cfg.tilt_compensation else None
        if cfg.slip is not None:  # the check across inputs (inputs/slip.py) refuses slipping wheels
            monitor(ctx).watch(inp.name, cfg.slip)

    def fuse(self, js: JointStateMeasurement, stamp: int) -> Fused:
        """The speeds since the previous message, stamped at the interval's middle (the message
        checks of inputs/joint_sampling.py first; one with some of the input's joints but not all
        is rejected as joint_missing)."""
        sample, early = self.sample(js, stamp)
        if early is not None:
            return early
        tilt = None if self._tilt is None else self._tilt.at(sample.stamp_ns)
        return Fused(sample.stamp_ns, (self.update(sample, tilt, self.predicted_state(sample.stamp_ns)),))

    def update(self, sample: EncoderSample, tilt: TiltSample | None,
               state: np.ndarray | None = None) -> tuple[PartPlan, np.ndarray, np.ndarray]:
        """(plan, z = E, R): R's speed term at the speeds H·``state`` predicts (the measured E
        without a state), its quantisation term over the sample's interval (docs/models.md, driven
        wheels); with a tilt, H = M·P⁻¹ and R gets the tilt term."""
        E = np.asarray(sample.speeds, dtype=float)
        plan, H = self.plan, self.H
        if tilt is not None:
            idx = self.twist_idx
            P_inv = np.linalg.inv(horizontal_projection(tilt.roll, tilt.pitch)[np.ix_(idx, idx)])
            H = self.H.copy()
            H[:, self.cols] = self.M @ P_inv  # E = M·v_body, v_body = P⁻¹·v_horizontal
            plan = replace(self.plan, model=LinearMeasurement(H))
        predicted = E if state is None else H @ state
        if not np.all(np.isfinite(predicted)):  # no usable estimate: the measured speed
            predicted = E
        R = np.diag(self.config.variances(predicted, sample.interval_ns))
        if tilt is None:
            return plan, E, R
        v = np.zeros(3)
        v[idx] = self.M_inv @ E  # body twist implied by the measured speeds
        J = -self.M @ P_inv @ projection_tilt_jacobian(v, tilt.roll, tilt.pitch)[idx]  # ∂h/∂(roll, pitch)
        return plan, E, symmetrise(R + J @ tilt.covariance @ J.T)


KIND = InputKind("joint", "sensor_msgs/msg/JointState", read, configure, joint_handler,
                 thresholds={"_rejection_threshold": ENCODER_PART}, parameters=PARAMETERS)
