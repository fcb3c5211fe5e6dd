"""The field a sim_node parameter file describes, as field_view's drawing data: JSON on stdout.

    python -m sim_robot.ros.field_json SIM_PARAMS.yaml

``field_view`` and ``bag_replay --html`` (ekf_localization, which never imports sim_robot) run
this command to learn the field to draw: its size, tiles, wall images and ramp
(:func:`sim_robot.world.field_drawing.field_drawing`). Exit status 0 with one JSON object on
stdout; 2 with one line on stderr when the file does not load.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from ekf_localization.ros.parameters import ParameterError, parameters_from_yaml
from sim_robot.ros.sim_params import parse_parameters
from sim_robot.world.field_drawing import field_drawing

PROG = "field_json"


def field_of(sim_params_file: Path | str) -> dict[str, Any]:
    """The drawing data of the field (and ramp) sim_node builds from ``sim_params_file``."""
    world, _ = parse_parameters(parameters_from_yaml(sim_params_file, "sim_node"))
    return field_drawing(world.field, world.ramp)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print(f"usage: python -m sim_robot.ros.{PROG} SIM_PARAMS.yaml", file=sys.stderr)
        return 2
    try:
        field = field_of(args[0])
    except (ParameterError, OSError, ValueError) as exc:
        print(f"{args[0]}: {exc}".replace("\n", " "), file=sys.stderr)
        return 2
    print(json.dumps(field))
    return 0


if __name__ == "__main__":
    sys.exit(main())
