"""The parameter schema (no ROS): types, checks, collected errors, renames; docs in sync."""

from __future__ import annotations

import subprocess
import sys

import pytest

from ekf_localization.ros.parameters import (
    REQUIRED,
    Entry,
    ParameterError,
    Schema,
    choice,
    floats,
    positive,
)
from ekf_localization.tools import parameter_docs
from sim_robot.ros import parameter_docs as sim_parameter_docs

SCHEMA = Schema("demo_node", "docs/demo.md", (
    Entry("rate", "float", 10.0, "Hz", "loop rate", positive()),
    Entry("mode", "str", "a", "", "mode", choice(("a", "b"))),
    Entry("pose", "float_list", [0.0, 0.0, 0.0], "m, m, rad", "start", floats(3, "3 finite floats")),
    Entry("topic", "str", REQUIRED, "", "input topic"),
    Entry("verbose", "bool", False, "", "more logs"),
), renamed={"old_rate": "rate"})


def _error(values: dict) -> ParameterError:
    parsed = SCHEMA.parse(values)
    problems = parsed.problems + SCHEMA.unknown_problems(parsed.others)
    return ParameterError(problems)


def test_good_values_are_typed_and_missing_ones_take_defaults() -> None:
    parsed = SCHEMA.parse({"rate": 20.0, "pose": (1.0, 2.0, 3.0), "use_sim_time": True})
    assert parsed.problems == [] and parsed.warnings == []
    assert parsed.values == {"rate": 20.0, "mode": "a", "pose": [1.0, 2.0, 3.0], "topic": REQUIRED,
                             "verbose": False}
    assert parsed.given == {"rate", "pose"}
    assert SCHEMA.unknown_problems(parsed.others) == []  # use_sim_time is ROS's own


def test_two_bad_parameters_give_one_error_naming_both() -> None:
    err = _error({"rate": 5, "mode": "c"})
    assert err.names == ("rate", "mode")
    assert str(err) == ("2 bad parameters:\n"
                        "  parameter 'rate': expected a float > 0 (Hz), written with a decimal point "
                        "(e.g. 5.0), got 5\n"
                        "  parameter 'mode': expected one of 'a', 'b', got 'c'")


def test_each_kind_of_problem_names_the_parameter_and_the_expected_form() -> None:
    cases = {
        "rate": (float("nan"), "expected a float > 0 (Hz), got nan"),
        "pose": ([1.0, 2.0], "expected 3 finite floats (m, m, rad), got [1.0, 2.0]"),
        "verbose": ("yes", "expected true or false, got 'yes'"),
        "topic": (3, "expected a string, got 3"),
    }
    for name, (value, text) in cases.items():
        err = _error({name: value})
        assert str(err) == f"parameter '{name}': {text}", name
    err = _error({"rat": 1.0})
    assert str(err) == ("1 bad parameter (unknown parameter(s) 'rat'):\n  parameter 'rat': expected a "
                        "known demo_node parameter (see docs/demo.md), got 1.0")


def test_integers_for_floats_only_where_the_schema_allows() -> None:
    lenient = Schema("n", "d", SCHEMA.entries, ints_as_floats=True)
    assert lenient.parse({"rate": 5}).values["rate"] == 5.0
    assert SCHEMA.parse({"rate": 5}).problems


def test_a_renamed_parameter_keeps_working_with_a_warning() -> None:
    parsed = SCHEMA.parse({"old_rate": 7.0})
    assert parsed.values["rate"] == 7.0 and parsed.problems == []
    assert parsed.warnings == ["parameter 'old_rate' is deprecated: use 'rate' (same meaning; see "
                               "docs/demo.md)"]
    assert SCHEMA.parse({"old_rate": 7.0, "rate": 7.0}).problems == []
    assert SCHEMA.parse({"old_rate": 7.0, "rate": 8.0}).problems[0].name == "old_rate"


def test_an_error_needs_a_problem() -> None:
    with pytest.raises(ValueError):
        ParameterError([])


def test_the_docs_tables_are_the_schemas() -> None:
    assert parameter_docs.stale() == [], ("regenerate: python -m ekf_localization.tools.parameter_docs "
                                          "--write")
    assert sim_parameter_docs.stale() == [], "regenerate: python -m sim_robot.ros.parameter_docs --write"
    for key, (doc, parts) in (parameter_docs.TABLES | sim_parameter_docs.TABLES).items():
        text = (parameter_docs.DOCS / doc).read_text()
        assert parameter_docs.render_table(parts) in text, key
        for _, schema in parts:
            for name in schema:
                assert f"_{name}` |" in text or f"`{name}` |" in text, name


def test_a_stale_table_is_detected(tmp_path, monkeypatch) -> None:
    for doc in {d for d, _ in (parameter_docs.TABLES | sim_parameter_docs.TABLES).values()}:
        (tmp_path / doc).write_text((parameter_docs.DOCS / doc).read_text())
    monkeypatch.setattr(parameter_docs, "DOCS", tmp_path)
    text = (tmp_path / "simulator.md").read_text()
    (tmp_path / "simulator.md").write_text(text.replace("| `seed` | int | 0 |", "| `seed` | int | 1 |"))
    assert parameter_docs.stale() == []  # not one of its tables
    assert sim_parameter_docs.stale() == ["simulator.md"]
    assert sim_parameter_docs.stale(write=True) == ["simulator.md"]
    assert sim_parameter_docs.stale() == []
    text = (tmp_path / "ekf_node.md").read_text()
    assert "| `frequency` |" in text
    (tmp_path / "ekf_node.md").write_text(text.replace("| `frequency` |", "| `frequency_hz` |", 1))
    assert parameter_docs.stale() == ["ekf_node.md"] and sim_parameter_docs.stale() == []


@pytest.mark.parametrize("module", ["ekf_localization.tools.parameter_docs", "sim_robot.ros.parameter_docs"])
def test_the_docs_check_command_passes(module: str) -> None:
    res = subprocess.run([sys.executable, "-m", module], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr


def test_the_same_concept_has_the_same_name_in_every_node() -> None:
    from ekf_localization.ros.ekf_parameters import EKF_PARAMETERS
    from ekf_localization.ros.pure_pursuit_parameters import PURE_PURSUIT_PARAMETERS, parse_settings
    from sim_robot.ros.sim_params import SIM_PARAMETERS

    for name in ("stamped_cmd_vel", "base_link_frame"):
        assert all(name in schema for schema in (EKF_PARAMETERS, PURE_PURSUIT_PARAMETERS, SIM_PARAMETERS))
    assert "stamped_control" not in EKF_PARAMETERS and EKF_PARAMETERS.renamed == {
        "stamped_control": "stamped_cmd_vel"}
    assert parse_settings({"base_link_frame": "/robot_base"}).base_link_frame == "robot_base"
    assert parse_settings({}).base_link_frame == "base_link"
