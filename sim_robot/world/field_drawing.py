"""The field as plain drawing data (JSON-able, no ROS): what field_view and its HTML export draw.

Lengths in the field's unit (m with the SI presets), angles in rad, REP-103 axes: x right on
the page, y up. The FTC field is tiled in 24 in (0.6096 m) foam tiles, drawn as a grid.
"""

from __future__ import annotations

from typing import Any

from ekf_localization.core.units import METRES_PER_INCH
from sim_robot.world.field import Field
from sim_robot.world.ramp import Ramp

TILE_IN = 24.0


def field_drawing(field: Field, ramp: Ramp | None = None,
                  length_per_inch: float = METRES_PER_INCH) -> dict[str, Any]:
    """{"size", "tile", "images": [{"name", "x", "y", "facing_yaw", "ends"}], "ramp"} of ``field``."""
    _, _, ends = field.image_arrays()
    images = [{"name": im.name, "x": float(im.x), "y": float(im.y), "facing_yaw": float(im.facing_yaw),
               "width": float(im.width), "ends": [[float(a), float(b)] for a, b in ends[i]]}
              for i, im in enumerate(field.images)]
    out: dict[str, Any] = {"size": float(field.size), "tile": TILE_IN * float(length_per_inch),
                           "images": images, "ramp": None}
    if ramp is not None and ramp.enabled:
        out["ramp"] = {"x_min": ramp.x_min, "x_max": ramp.x_max, "y_min": ramp.y_min, "y_max": ramp.y_max,
                       "flat_top_length": ramp.flat_top_length}
    return out
