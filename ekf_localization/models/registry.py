"""The motion models ekf_node can run, by the name its ``model`` parameter takes.

Adding a model is one module declaring a :class:`~ekf_localization.core.motion_model.MotionModelSpec`
named ``SPEC`` plus one entry in :data:`MODELS` (docs/models.md, "Writing a model").
"""

from __future__ import annotations

from collections.abc import Callable

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.localizer import Localizer
from ekf_localization.core.motion_model import MotionModelSpec
from ekf_localization.models import differential, mecanum

MODELS: dict[str, MotionModelSpec] = {spec.name: spec for spec in (
    mecanum.SPEC,
    differential.SPEC,
    differential.TANK_SPEC,
)}


def get(name: str) -> MotionModelSpec:
    """The spec registered as ``name``; ValueError naming the known models otherwise."""
    try:
        return MODELS[name]
    except KeyError:
        known = ", ".join(repr(n) for n in MODELS)
        raise ValueError(f"unknown motion model {name!r}: expected one of {known}") from None


def make_localizer(config: EkfConfig, warn: Callable[[str], None] | None = None) -> Localizer:
    """A :class:`Localizer` running the model ``config.model`` names."""
    return Localizer(config, get(config.model), warn=warn)
