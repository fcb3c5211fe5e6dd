"""The core's config holds only what the Localizer uses; ekf_node's own settings are the node's."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
import re

import ekf_localization
from ekf_localization.core.config import EkfConfig
from ekf_localization.models.registry import MODELS
from ekf_localization.ros.ekf_node_settings import NODE_SETTINGS, EkfNodeSettings
from ekf_localization.ros.ekf_parameters import EKF_PARAMETERS, parse_ekf_config, parse_ekf_settings

CORE_PACKAGES = ("core", "models", "inputs", "control", "vision")  # no ROS (the project's guide)
# Names of settings a ROS node has and a filter does not: outputs, rates, topics, scheduling.
NODE_LIKE = re.compile(r"^(publish_|print_|marker_)|(^|_)topic$|^queue_size$|^thread_priority$|"
                       r"^(publish_)?frequency$|^stamped_cmd_vel$|^warnings$|^(map|odom)_frame$")
# Per-input subscription settings the core's input list still carries: (class, field).
SUBSCRIPTION_FIELDS = {("InputConfig", "topic"), ("InputConfig", "queue_size")}


def _field_names(cls: type) -> tuple[str, ...]:
    if dataclasses.is_dataclass(cls):
        return tuple(f.name for f in dataclasses.fields(cls))
    return tuple(getattr(cls, "_fields", ()))  # a NamedTuple


def _core_classes() -> list[type]:
    out = []
    for package in CORE_PACKAGES:
        pkg = importlib.import_module(f"{ekf_localization.__name__}.{package}")
        for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
            module = importlib.import_module(info.name)
            out += [c for _, c in inspect.getmembers(module, inspect.isclass)
                    if c.__module__ == module.__name__]
    return out


def test_the_core_config_has_none_of_the_node_settings() -> None:
    core = set(_field_names(EkfConfig))
    assert core.isdisjoint(NODE_SETTINGS) and "warnings" not in core, core & set(NODE_SETTINGS)
    assert not [n for n in core if NODE_LIKE.search(n)]
    # every ekf_node parameter is exactly one of the two
    for name in EKF_PARAMETERS:
        assert (name in core) != (name in NODE_SETTINGS), name
    assert set(NODE_SETTINGS) <= set(EKF_PARAMETERS)


def test_no_class_of_the_core_has_a_field_named_like_a_node_setting() -> None:
    classes = _core_classes()
    assert EkfConfig in classes and len(classes) > 20
    found = [(c.__name__, n) for c in classes for n in _field_names(c)
             if (n in NODE_SETTINGS or NODE_LIKE.search(n)) and (c.__name__, n) not in SUBSCRIPTION_FIELDS]
    assert found == []


def test_the_pattern_recognises_every_node_setting() -> None:
    """The name check above can fail: it matches each of the node's settings."""
    assert all(NODE_LIKE.search(n) for n in (*NODE_SETTINGS, "warnings")), \
        [n for n in NODE_SETTINGS if not NODE_LIKE.search(n)]


def test_the_settings_hold_the_config_the_core_parser_gives() -> None:
    values = {"frequency": 50.0, "publish_markers": True, "thread_priority": 7, "world_frame": "field",
              "map_frame": "field", "odom0": "odom", "odom0_config": [False] * 6 + [True] * 2 + [False] * 7}
    settings = parse_ekf_settings(values, MODELS)
    assert (settings.frequency, settings.publish_markers, settings.thread_priority) == (50.0, True, 7)
    assert settings.publish_period_ns == 20_000_000 and settings.map_frame == "field"
    config = parse_ekf_config(values, MODELS)
    assert config.world_frame == settings.config.world_frame == "field"
    assert config.inputs == settings.config.inputs
    default = EkfNodeSettings().frequency
    assert parse_ekf_settings({}, MODELS).frequency == default == EKF_PARAMETERS["frequency"].default
