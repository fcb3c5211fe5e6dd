"""What the Localizer needs to know about a motion model: :class:`MotionModelSpec`.

The core defines the interface; each module in :mod:`ekf_localization.models` declares one
spec and :mod:`ekf_localization.models.registry` maps ``config.model`` names to them. The
Localizer receives the spec (it never imports a model), so adding a model touches no core file.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.ekf import ProcessModel
from ekf_localization.core.measurements import FIELD_NAMES, N_FIELDS


@dataclass(frozen=True)
class MotionModelSpec:
    """A motion model as ekf_node, its parameter checks and its diagnostics see it.

    * ``state_fields``: the robot_localization field (0-14, :data:`FIELD_NAMES`) of each
      state component, in state order; the model's ``n`` must equal its length.
    * ``build``: the process model, with its noise taken from the parameters.
    * ``control_from_twist``: a cmd_vel twist ``[vx vy vz wx wy wz]`` -> the model's control
      input, used with ``use_control``; None when the model takes no command.
    * ``input_fields``: fields an input message supplies as the process input instead of as
      a measurement (e.g. an IMU's ax), in the order of the control vector; all in one part
      of one message (orientation, angular_velocity, linear_acceleration, pose or twist).
    * ``process_input``: one line saying what the process input is (parameter errors quote it).
    * ``dead_wheel_rows``: (half spacing W, lateral offset D) in m -> H (k, n), the dead-wheel
      encoder speeds ``[E_L E_R]`` or ``[E_L E_R E_a]`` on the state (seed 000 eq. 30), for
      jointN inputs; None when the model has none (jointN inputs are then refused).
    * ``driven_wheel_rows``: (geometry "mecanum" | "differential", wheel radius r, half wheelbase
      L, half track l) in m -> H (k, n), the driven wheels' speeds (rad/s of each wheel) on the
      state: the model's inverse kinematics on its body twist (e.g. seed 000 eq. 23-24); raises
      ValueError for a geometry the state cannot hold; None when the model has none.
    * ``twist_from_wheels``: the config -> (wheel order, matrix (3, k)) that turns commanded
      wheel speeds, in that order, into the body twist ``[vx vy vyaw]`` (e.g. seed 000 eq. 23-24);
      None when the model takes no wheel-speed commands.
    * ``state_names``: short names for diagnostics (``std_<name>``); default: the field names.
    """

    name: str
    state_fields: tuple[int, ...]
    build: Callable[[EkfConfig], ProcessModel]
    process_input: str
    control_from_twist: Callable[[np.ndarray], np.ndarray] | None = None
    input_fields: tuple[int, ...] = ()
    dead_wheel_rows: Callable[[float, float], np.ndarray] | None = None
    driven_wheel_rows: Callable[[str, float, float, float], np.ndarray] | None = None
    twist_from_wheels: Callable[[EkfConfig], tuple[tuple[str, ...], np.ndarray]] | None = None
    state_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        fields = self.state_fields + self.input_fields
        if not self.state_fields or len(set(fields)) != len(fields) \
                or not all(0 <= f < N_FIELDS for f in fields):
            raise ValueError(f"model '{self.name}': state_fields and input_fields must be distinct "
                             f"fields 0-{N_FIELDS - 1}, got {self.state_fields} and {self.input_fields}")
        if self.control_from_twist is not None and self.input_fields:
            raise ValueError(f"model '{self.name}': the process input comes from cmd_vel or from "
                             "input_fields, not both")
        if not self.state_names:
            object.__setattr__(self, "state_names", tuple(FIELD_NAMES[f] for f in self.state_fields))
        if len(self.state_names) != len(self.state_fields):
            raise ValueError(f"model '{self.name}': one state name per state field")

    @property
    def takes_control(self) -> bool:
        """Whether ``use_control`` (cmd_vel as the process input) is possible."""
        return self.control_from_twist is not None

    @property
    def dead_wheel_count(self) -> int:
        """How many encoders a jointN input names for this model (0: none)."""
        return 0 if self.dead_wheel_rows is None else int(self.dead_wheel_rows(1.0, 1.0).shape[0])
