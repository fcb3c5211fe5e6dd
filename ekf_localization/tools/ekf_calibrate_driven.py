"""``ekf_calibrate``'s driven-wheel part: fit a mecanum or differential jointN input's wheel radius,
turning lever (mecanum's L + l, a differential's half track) and mecanum's strafe scale from the
camera's pose fixes, print them and put them in the parameters (docs/ekf_calibrate.md).

The bags are read as for the dead-wheel pods (:func:`ekf_calibrate_pods.read_bag`: each wheel's
distance at the file's radius), and fitted by :mod:`ekf_localization.tools.pod_calibration` with
the wheels' geometry (:class:`~ekf_localization.tools.driven_calibration.DrivenGeometry`).
"""

from __future__ import annotations

import argparse

import numpy as np

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.joint_states import EncoderInputConfig
from ekf_localization.tools import ekf_calibrate_mount, ekf_calibrate_pods, pod_calibration
from ekf_localization.tools.driven_calibration import DRIVEN, DrivenGeometry, lever_of, lever_parameters
from ekf_localization.tools.ekf_calibrate_pods import WALK, UnavailableError
from ekf_localization.tools.replay import abs_topic

BOUNDS = (0.5, 2.0)  # a fitted value outside this times the file's is refused (wrong joints or fixes)


def driven_input(config: EkfConfig, name: str | None):
    """The jointN input with a mecanum or differential geometry to calibrate (``name``, or the
    only one); None when there is none (or ``name`` is another input). Raises ValueError when the
    choice is ambiguous."""
    joints = [i for i in config.inputs if isinstance(i.settings, EncoderInputConfig)
              and i.settings.geometry in DRIVEN and (name is None or i.name == name)]
    if len(joints) > 1:
        raise ValueError(f"the parameters have {len(joints)} driven-wheel jointN inputs; name one with "
                         "--joint")
    return joints[0] if joints else None


def names_of(inp_name: str, geometry: str) -> list[str]:
    """The printed names of [r, k] (mecanum [r, k, σ]): mecanum's k is the sum of two parameters."""
    if geometry != "mecanum":
        return [f"{inp_name}_wheel_radius", f"{inp_name}_half_track"]
    return [f"{inp_name}_wheel_radius", f"{inp_name}_half_wheelbase+{inp_name}_half_track",
            f"{inp_name}_strafe_scale"]


# what a held parameter needs the drive to do while the camera sees
NEEDS = ("driving straight", "turning", "pushing sideways")


def calibrate(args: argparse.Namespace, config: EkfConfig, values: dict, inp,
              fix_topics: list[str]) -> list[str]:
    """Fit ``inp``'s wheel radius, lever and (mecanum) strafe scale; print them, set the fitted
    parameters in ``values`` and return their names. Raises UnavailableError (nothing fitted) or
    ValueError (a fit out of bounds: nothing may be written)."""
    try:
        return _calibrate(args, config, values, inp, fix_topics)
    except np.linalg.LinAlgError:
        raise ValueError(f"{inp.name}: the wheels' fit ran to a geometry that does not determine the body "
                         "twist: the wrong joints or directions, or fixes not of this robot; nothing "
                         "written") from None


def _calibrate(args: argparse.Namespace, config: EkfConfig, values: dict, inp,
               fix_topics: list[str]) -> list[str]:
    cfg: EncoderInputConfig = inp.settings
    start = DrivenGeometry(cfg.geometry, cfg.wheel_radius, cfg.wheel_radius,
                           lever_of(cfg.geometry, cfg.half_wheelbase, cfg.half_track), cfg.strafe_scale)
    cam = getattr(args, "camera_mount", None)
    pairs = [ekf_calibrate_pods.read_bag(bag, abs_topic(inp.topic), cfg, fix_topics, cam)
             for bag in args.bags]
    walk = tuple(float(config.process_noise_covariance[i, i]) for i in WALK)
    problem = pod_calibration.build_problem(pairs, walk, (cfg.speed_variance_coeff, cfg.speed_variance_floor))
    names = names_of(inp.name, cfg.geometry)
    lim = start.limits()
    cam = None if getattr(args, "mount_fitted", True) else cam
    geom, free, formal, _, cands = ekf_calibrate_mount.judge(problem, start, None, lim, cam, False)
    if cam is not None:
        ekf_calibrate_mount.not_observable(cam, free[-3:], cands[-3:], formal[-3:])
    for i, name in enumerate(names):
        if not free[i]:
            print(f"{name}: not observable from these drives (its std {formal[i]:.2g} > {lim[i]:.2g}: "
                  f"too little {NEEDS[i]} while the camera sees, or too few camera fixes); left unchanged")
    if not free.any():
        raise UnavailableError("the drives determine none of the wheel radius, the turning lever "
                               "and the strafe scale" if len(names) == 3 else
                               "the drives determine neither the wheel radius nor the turning lever")
    before = pod_calibration.fit(problem, geom, np.zeros_like(free))
    try:
        best = pod_calibration.fit(problem, geom, free)
    except ValueError:  # DrivenGeometry refuses a radius, lever or strafe scale <= 0
        raise ValueError(f"{inp.name}: the wheels' fit ran to a radius, lever or strafe scale <= 0: the "
                         "wrong joints or "
                         "directions, or fixes not of this robot; nothing written") from None
    v, was = best.pods.vector, start.vector
    lo, hi = BOUNDS
    for i, name in enumerate(names):
        if free[i] and not lo * was[i] <= v[i] <= hi * was[i]:
            raise ValueError(f"{name}: the fit gives {v[i]:g}, outside [{lo:g}, {hi:g}] × {was[i]:g}: the "
                             "wrong joints or directions, a broken encoder or fixes not of this robot; "
                             "nothing written")
    std = pod_calibration.bootstrap_std(problem, best, free, args.bootstrap, args.seed, args.block)
    ekf_calibrate_pods.print_fitted(names, v, std, was, free)
    fitted = []
    if cam is not None and free[-3:].any():
        fitted += ekf_calibrate_mount.report(cam, v[-3:], std[-3:], free[-3:], values)
        args.mount_fitted = True
    print(f"{inp.name} residual (RMS, normalised): before {before.rms:.4g}, after {best.rms:.4g} "
          f"({problem.n} camera fixes, {int(problem.link.sum())} wheel links, {len(args.bags)} bag(s))")
    if free[0]:
        values[f"{inp.name}_wheel_radius"] = float(v[0])
        fitted.append(f"{inp.name}_wheel_radius")
    if len(names) > 2 and free[2]:
        values[f"{inp.name}_strafe_scale"] = float(v[2])
        fitted.append(f"{inp.name}_strafe_scale")
    if free[1]:
        lever = lever_parameters(inp.name, cfg.geometry, cfg.half_wheelbase, cfg.half_track, float(v[1]))
        values.update(lever)
        fitted += list(lever)
        if cfg.geometry == "mecanum":
            print(f"{inp.name}: only L + l is observable from the wheels; L and l keep their ratio: "
                  + ", ".join(f"{k} {x:.6g}" for k, x in lever.items()))
    return fitted
