"""The demo run's parameter files and start: the known start pose and its placement error,
ekf_node's YAML written next to the bag (what the node ran with), and the simulator's YAML
for field_view."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

PLACEMENT_STREAM = 1  # the placement error's random stream, beside the simulator's seed

# How well a team knows where it put the robot: against the wall on a tile seam, to about half
# a centimetre per axis and half a degree (m, rad; one standard deviation).
KNOWN_START_STD = (0.005, math.radians(0.5))


def known_start(ekf_yaml: Path, x: float, y: float, yaw: float) -> dict[str, list[float]]:
    """ekf_node parameters for a known start pose (a team places the robot before a match):
    the EKF starts there with P0 = ``KNOWN_START_STD`` squared, instead of the YAML's
    "somewhere on the field"."""
    from ekf_localization.ros.parameters import parameters_from_yaml

    p0 = np.array(parameters_from_yaml(ekf_yaml, "ekf_node")["initial_estimate_covariance"], float)
    p0 = p0.reshape(15, 15)
    p0[0, 0] = p0[1, 1] = KNOWN_START_STD[0] ** 2
    p0[5, 5] = KNOWN_START_STD[1] ** 2
    return {"initial_state": [x, y, 0.0, 0.0, 0.0, yaw] + [0.0] * 9,
            "initial_estimate_covariance": [float(v) for v in p0.ravel()]}


def placed_start(x: float, y: float, yaw: float, seed: int) -> tuple[float, float, float]:
    """Where the robot really stands: the known start plus a placement error drawn (seeded)
    from ``KNOWN_START_STD``, so that the EKF's P0 describes a real error. A robot put exactly
    on the start while P0 says otherwise makes the published covariance look too wide for the
    whole run: only the camera pulls a position error in, over about 15 s."""
    std = np.array([KNOWN_START_STD[0], KNOWN_START_STD[0], KNOWN_START_STD[1]])
    dx, dy, dyaw = np.random.default_rng([seed, PLACEMENT_STREAM]).standard_normal(3) * std
    return x + float(dx), y + float(dy), yaw + float(dyaw)


def write_ekf_params(ekf_yaml: Path, dst: Path, overrides: dict) -> Path:
    """ekf_node's YAML with ``overrides``, written next to the bag: exactly what the node ran
    with, so ``bag_replay BAG --params <this file>`` reproduces the run."""
    import yaml

    from ekf_localization.ros.parameters import parameters_from_yaml

    values = parameters_from_yaml(ekf_yaml, "ekf_node")
    values.update(overrides)
    dst.write_text("# ekf_node parameters of this run: config/ekf.yaml + the known start pose\n"
                   + yaml.safe_dump({"ekf_node": {"ros__parameters": values}}, sort_keys=False))
    return dst


def write_view_sim_params(sim_yaml: Path, dst: Path, preset: str | None, ramp: bool) -> Path:
    """``sim_yaml`` with the field preset and ramp the run's sim_node gets, for field_view to draw."""
    import yaml

    from ekf_localization.ros.params_match import section_for

    doc = yaml.safe_load(sim_yaml.read_text())
    p = section_for(doc, "sim_node")
    if preset is not None:
        p["field"]["preset"] = preset
    if ramp:
        p["ramp"]["enabled"] = True
    dst.write_text(yaml.safe_dump(doc, sort_keys=False))
    return dst
