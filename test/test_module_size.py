"""A module a reader can hold in mind: at most 500 lines under ekf_localization/ and sim_robot/,
and the Localizer, which only orchestrates, at most 300."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LIMIT = 500
LOCALIZER_LIMIT = 300


def test_no_module_is_over_500_lines() -> None:
    modules = [p for pkg in ("ekf_localization", "sim_robot") for p in (REPO / pkg).rglob("*.py")]
    assert len(modules) > 100
    long = {str(p.relative_to(REPO)): n for p in modules if (n := len(p.read_text().splitlines())) > LIMIT}
    assert long == {}


def test_the_localizer_is_at_most_300_lines() -> None:
    lines = len((REPO / "ekf_localization" / "core" / "localizer.py").read_text().splitlines())
    assert lines <= LOCALIZER_LIMIT
