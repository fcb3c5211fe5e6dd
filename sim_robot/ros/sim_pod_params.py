"""sim_node's dead-wheel geometry parameters (no ROS): the nominal W and D, and the pods' true
geometry when it differs from them (a robot whose ekf_node YAML is off, for ``ekf_calibrate``).

The encoders read with the true pods (``dead_wheels.pod_*``, docs/models.md "Dead-wheel
pods"); the robot's own odometry (odometry/dead_wheels) converts them with the nominal W and D,
as a driver configured with the measured-by-ruler numbers does.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from ekf_localization.models.sensors.dead_wheels import DeadWheelGeometry, PodGeometry
from ekf_localization.ros.parameters import Check, Entry, finite, positive
from sim_robot.world.dead_wheel_sensor import DeadWheelConfig

_dw = DeadWheelConfig()
POD_NAMES = ("dead_wheels.pod_offsets", "dead_wheels.pod_angles", "dead_wheels.pod_scales")


def _pods(form: str, positive_values: bool = False) -> Check:
    return Check(lambda v: not v or (len(v) == 3 and all(math.isfinite(x) and (x > 0.0 or not positive_values)
                                                          for x in v)), "[] or 3 " + form)


DEAD_WHEEL_GEOMETRY = (
    Entry("dead_wheels.half_spacing", "float", _dw.geometry.half_track, "m", "W (eq. 29)", positive()),
    Entry("dead_wheels.lateral_offset", "float", _dw.geometry.lateral_offset, "m",
          "D, > 0 = lateral wheel behind the centre (eq. 30)", finite()),
    Entry(POD_NAMES[0], "float_list", [], "m", "the true pods [left, right, lateral]: each rolling line's "
          "offset to the left of its rolling direction; [] = [W, -W, D]",
          _pods("finite offsets [left, right, lateral]")),
    Entry(POD_NAMES[1], "float_list", [], "rad",
          "the true pods' rolling directions from x; [] = [0, 0, pi/2]",
          _pods("finite angles [left, right, lateral]")),
    Entry(POD_NAMES[2], "float_list", [], "", "the true pods' scales (reading per metre rolled); [] = all 1",
          _pods("scales > 0 [left, right, lateral]", positive_values=True)),
)


def dead_wheel_geometry(v: Mapping[str, Any]) -> dict[str, Any]:
    """``geometry`` (nominal) and ``pods`` (true; None when no pod_* is set) for DeadWheelConfig,
    from values the entries above have checked."""
    nominal = DeadWheelGeometry(v["dead_wheels.half_spacing"], v["dead_wheels.lateral_offset"])
    if not any(v[n] for n in POD_NAMES):
        return {"geometry": nominal, "pods": None}
    base = PodGeometry.symmetric(nominal.half_track, nominal.lateral_offset)
    pods = PodGeometry(*(tuple(v[n]) or getattr(base, n.split(".pod_")[1]) for n in POD_NAMES))
    return {"geometry": nominal, "pods": pods}
