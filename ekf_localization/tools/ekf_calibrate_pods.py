"""``ekf_calibrate``'s dead-wheel part: read the pods and the camera's pose fixes from the bags, fit
the jointN input's pod offsets, angles and scales (tools/pod_calibration.py), print them and put
them in the parameters (docs/ekf_calibrate.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.joint_states import EncoderInputConfig
from ekf_localization.core.units import NS_PER_S, stamp_to_ns
from ekf_localization.inputs.joint import POD_LISTS, pod_geometry
from ekf_localization.models.sensors.dead_wheels import POD_FIELDS, PodGeometry
from ekf_localization.tools import bag_io, ekf_calibrate_mount, pod_calibration
from ekf_localization.tools.ekf_calibrate_mount import CameraMount
from ekf_localization.tools.pod_calibration import PodData, PoseFixes
from ekf_localization.tools.replay import abs_topic

WALK = (0, 1, 5)  # x, y, yaw in the 15 fields
SCALE_BOUNDS = (0.5, 2.0)  # a fitted scale outside is refused (wrong joints or a broken encoder)
MAX_OFFSET = 2.0  # m: a pod further from the centre than this is not on the robot


class UnavailableError(Exception):
    """A group of parameters (the IMU's, the pods', the driven wheels') cannot be fitted from these
    bags: named and left unchanged; the other groups may still be fitted."""


def dead_wheel_input(config: EkfConfig, name: str | None):
    """The jointN dead-wheel input to calibrate (``name``, or the only one); None when there is
    none and none was asked for. Raises ValueError when the choice is ambiguous or missing."""
    joints = [i for i in config.inputs if isinstance(i.settings, EncoderInputConfig)
              and pod_geometry_or_default(i.settings) is not None]
    if name is not None:
        joints = [i for i in joints if i.name == name]
        if len(joints) != 1:
            raise ValueError(f"the parameters have no dead-wheel jointN input named {name}")
    if not joints:
        return None
    if len(joints) > 1:
        raise ValueError(f"the parameters have {len(joints)} dead-wheel jointN inputs; name one with --joint")
    return joints[0]


def pod_geometry_or_default(cfg: EncoderInputConfig) -> PodGeometry | None:
    """The pods the filter uses now (their pod_* lists, else eq. 30's); None: not dead wheels."""
    if cfg.geometry != "dead_wheels":
        return None
    return pod_geometry(cfg) or PodGeometry.symmetric(cfg.half_spacing, cfg.lateral_offset, len(cfg.names))


def read_bag(bag: Path, joint_topic: str, cfg: EncoderInputConfig, fix_topics: list[str],
             mount: CameraMount | None = None) -> tuple[PoseFixes, PodData]:
    """The bag's pose fixes and pod distances (m: position · wheel radius · direction), stamps in s
    from the bag's first joint message; the fixes on ``mount``'s topic turned into base_link's
    through it, as ekf_node does."""
    ft, fpose, fvar, jt, jd = [], [], [], [], []
    signs = cfg.signs * cfg.wheel_radius
    for m in bag_io.iter_messages(bag, [joint_topic, *fix_topics]):
        if m.topic == joint_topic:
            index = {str(n): i for i, n in enumerate(m.msg.name)}
            pos = np.asarray(m.msg.position, dtype=float)
            if all(n in index and index[n] < len(pos) for n in cfg.names):
                d = pos[[index[n] for n in cfg.names]] * signs
                if np.all(np.isfinite(d)):
                    jt.append(stamp_to_ns(m.msg.header.stamp))
                    jd.append(d)
        else:
            t, state, cov = bag_io.pose_stamped_state(m.msg)
            var = np.diag(cov)
            if mount is not None and m.topic == mount.topic:
                base, grown = ekf_calibrate_mount.to_base(state[None, :], var[None, :], mount.planar)
                state, var = base[0], grown[0]
            if np.all(np.isfinite(state)) and np.all(np.isfinite(var)) and np.all(var > 0.0):
                ft.append(t)
                fpose.append(state)
                fvar.append(var)
    if not ft:
        raise UnavailableError(f"{bag}: no camera pose fixes with variances on {', '.join(fix_topics)}")
    if len(jt) < 2:
        raise UnavailableError(f"{bag}: no joint positions of {', '.join(cfg.names)} on {joint_topic}")
    t0 = min(jt)

    def sec(v: list[int]) -> np.ndarray:
        return (np.asarray(v, dtype=np.int64) - t0) / NS_PER_S

    return (PoseFixes(sec(ft), np.reshape(fpose, (-1, 3)), np.reshape(fvar, (-1, 3))),
            PodData(sec(jt), np.asarray(jd)))


def names_of(inp_name: str, count: int) -> list[str]:
    """``joint0_pod_offsets[1]`` for each parameter of ``PodGeometry.vector``."""
    return [f"{inp_name}_pod_{field}[{i}]" for field in POD_FIELDS for i in range(count)]


def print_fitted(names: list[str] | tuple[str, ...], fitted, std, was, free) -> None:
    """One line per fitted parameter: ``<name> <fitted> ± <std> (was <file value>)``."""
    for i, name in enumerate(names):
        if free[i]:
            print(f"{name} {fitted[i]:.6g} ± {std[i]:.2g} (was {was[i]:g})")


def calibrate(args: argparse.Namespace, config: EkfConfig, values: dict, inp,
              fix_topics: list[str]) -> list[str]:
    """Fit the pods of ``inp``; print the results, set the fitted lists in ``values`` and return
    the names of the fitted lists. Raises UnavailableError (nothing fitted) or ValueError (a fit
    out of bounds: nothing may be written)."""
    cfg: EncoderInputConfig = inp.settings
    start = pod_geometry_or_default(cfg)
    cols = pod_calibration.twist_columns(start.count)
    M = start.encoders_from_twist[:, cols]
    if np.linalg.matrix_rank(M) < len(cols):
        raise ValueError(f"{inp.name}: the pods as the params file gives them (pod_offsets, pod_angles) do "
                         "not determine the body twist (parallel pods at one offset?); nothing written")
    try:
        return _calibrate(args, config, values, inp, fix_topics, start)
    except np.linalg.LinAlgError:
        raise ValueError(f"{inp.name}: the pods' fit ran to a geometry that does not determine the body "
                         "twist: the wrong joints or directions, or fixes not of this robot; nothing "
                         "written") from None


def _calibrate(args: argparse.Namespace, config: EkfConfig, values: dict, inp, fix_topics: list[str],
               start: PodGeometry) -> list[str]:
    cfg: EncoderInputConfig = inp.settings
    cam = getattr(args, "camera_mount", None)
    pairs = [read_bag(bag, abs_topic(inp.topic), cfg, fix_topics, cam) for bag in args.bags]
    walk = tuple(float(config.process_noise_covariance[i, i]) for i in WALK)
    problem = pod_calibration.build_problem(pairs, walk, (cfg.speed_variance_coeff, cfg.speed_variance_floor))
    names = names_of(inp.name, start.count)
    candidates = np.ones(3 * start.count, bool)
    if start.count < 3:  # no ẏ on the state: a pod's angle only scales its reading
        candidates[start.count:2 * start.count] = False
    limits = pod_calibration.limits(start.count)
    cam = None if getattr(args, "mount_fitted", True) else cam
    geom, free, formal, shown, cands = ekf_calibrate_mount.judge(problem, start, candidates, limits, cam,
                                                                 pods=True)
    if cam is not None:
        ekf_calibrate_mount.not_observable(cam, free[-3:], cands[-3:], formal[-3:])
    for i, name in enumerate(names):
        if not shown[i]:
            why = ("no lateral velocity on this model" if not candidates[i] else f"its std {formal[i]:.2g} > "
                   f"{limits[i]:g}: too little turning or pushing, or too few camera fixes")
            print(f"{name}: not observable from these drives ({why}); left unchanged")
    if not free.any():
        raise UnavailableError("the drives determine none of the dead-wheel pods' parameters")
    before = pod_calibration.fit(problem, geom, np.zeros_like(free))
    best = pod_calibration.fit(problem, geom, free)
    v = best.pods.vector
    n = start.count
    lo, hi = SCALE_BOUNDS
    bad = [i for i in range(3 * n)
           if shown[i] and ((i >= 2 * n and not lo <= v[i] <= hi) or (i < n and abs(v[i]) > MAX_OFFSET))]
    if bad:
        raise ValueError(f"{names[bad[0]]}: the fit gives {v[bad[0]]:g}, out of bounds: the wrong joints, "
                         "a broken encoder or fixes not of this robot; nothing written")
    std = pod_calibration.bootstrap_std(problem, best, free, args.bootstrap, args.seed, args.block, shown)
    was = start.vector
    print_fitted(names, v, std, was, shown)
    fitted = []
    if cam is not None and free[-3:].any():
        fitted += ekf_calibrate_mount.report(cam, v[-3:], std[-3:], free[-3:], values)
        args.mount_fitted = True
    print(f"pods residual (RMS, normalised): before {before.rms:.4g}, after {best.rms:.4g} "
          f"({problem.n} camera fixes, {int(problem.link.sum())} pod links, {len(args.bags)} bag(s))")
    for k, key in enumerate(POD_LISTS):
        if free[k * n:(k + 1) * n].any():
            values[f"{inp.name}_{key}"] = [float(x) for x in v[k * n:(k + 1) * n]]
            fitted.append(f"{inp.name}_{key}")
    return fitted
