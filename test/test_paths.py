"""Paths: geometry, headings, stop points, YAML loading/validation and the presets."""

from __future__ import annotations

import math
import textwrap

import numpy as np
import pytest

from ekf_localization.control.field_path import (
    FieldPath,
    PathError,
    Waypoint,
    load_path,
    load_preset,
    path_from_dict,
    preset_file,
    resolve_config_file,
)
from ekf_localization.core.angles import wrap_angles
from ekf_localization.core.units import METRES_PER_INCH as INCH

HALF_FIELD = 72 * INCH  # 1.8288 m


def square(closed: bool = False, cycles: int = 1) -> FieldPath:
    wps = [Waypoint(0, 0), Waypoint(1, 0), Waypoint(1, 1), Waypoint(0, 1)]
    return FieldPath(wps, closed=closed, cycles=cycles)


def test_arc_length_point_and_segment():
    p = square()
    assert p.s == (0.0, 1.0, 2.0, 3.0)
    assert p.length == 3.0
    assert p.point_at(1.5) == pytest.approx((1.0, 0.5))
    assert p.point_at(-1.0) == (0.0, 0.0) and p.point_at(10.0) == (0.0, 1.0)
    assert p.segment_at(1.0) == 1  # at a vertex: the outgoing segment
    assert p.segment_at(3.0) == 2


def test_tangent_and_interpolated_headings():
    p = square()
    assert p.heading_at(0.5) == pytest.approx(0.0)
    assert p.heading_at(1.5) == pytest.approx(math.pi / 2)
    assert p.heading_at(2.5) == pytest.approx(math.pi)
    assert p.stop_heading(0) == pytest.approx(math.pi)  # end heading of the last segment
    # explicit headings interpolate linearly in arc length, the short way round (170° -> -170°)
    q = FieldPath([Waypoint(0, 0, math.radians(170)), Waypoint(2, 0, math.radians(-170))])
    assert math.degrees(q.heading_at(1.0)) == pytest.approx(180.0)
    assert math.degrees(q.heading_at(0.5)) == pytest.approx(175.0)
    # explicit at one end, tangent at the other
    r = FieldPath([Waypoint(0, 0, math.pi / 2), Waypoint(1, 0)])
    assert r.heading_at(0.0) == pytest.approx(math.pi / 2)
    assert r.heading_at(0.5) == pytest.approx(math.pi / 4)
    assert r.heading_at(1.0) == pytest.approx(0.0)


def test_nearest_respects_the_arc_length_window():
    # a hairpin: out along y=0, back along y=0.1
    p = FieldPath([Waypoint(0, 0), Waypoint(2, 0), Waypoint(2, 0.1), Waypoint(0, 0.1)])
    s, px, py, d = p.nearest(1.0, 0.09)  # unrestricted: the return leg is nearer
    assert py == pytest.approx(0.1) and s == pytest.approx(2.0 + 0.1 + 1.0)
    s, px, py, d = p.nearest(1.0, 0.09, 0.0, 1.5)  # windowed: stays on the outbound leg
    assert (px, py) == pytest.approx((1.0, 0.0)) and d == pytest.approx(0.09)
    s, px, py, d = p.nearest(1.0, 0.0, 1.2, 1.8)  # behind the window start: clamps to it
    assert s == pytest.approx(1.2) and px == pytest.approx(1.2)


def test_closed_loop_and_cycles_are_unrolled():
    p = square(closed=True, cycles=3)
    assert p.length == pytest.approx(12.0)
    assert len(p.xs) == 13 and (p.xs[-1], p.ys[-1]) == (0.0, 0.0)
    assert p.stop_s == (12.0,)  # no stop points: one leg, ends after the third cycle
    assert p.with_cycles(1).length == pytest.approx(4.0)
    with pytest.raises(PathError, match="cycles"):
        square(closed=False, cycles=2)


def test_stop_points_split_legs():
    wps = [Waypoint(0, 0, stop=True), Waypoint(1, 0), Waypoint(1, 1, stop=True), Waypoint(0, 1)]
    p = FieldPath(wps, closed=True, cycles=2)
    # the start (s = 0) is not a stop; its repeats in later cycles are
    assert p.stop_s == (2.0, 4.0, 6.0, 8.0)


def test_from_poses_merges_duplicates():
    p = FieldPath.from_poses([0, 0, 1, 1, 2], [0, 0, 0, 0, 0], [0.0, 0.1, 0.2, 0.3, 0.4], frame_id="odom")
    assert len(p.xs) == 3 and p.frame_id == "odom"
    assert [w.heading for w in p.waypoints] == [0.1, 0.3, 0.4]


def test_ellipse_arc_expansion():
    data = {"waypoints": [[1.0, 0.5],
                          {"ellipse_arc": {"center": [1.0, 0.0], "radii": [0.5, 0.5 * 0.6],
                                           "start_deg": 90, "end_deg": 0, "rotation_deg": 90,
                                           "points": 10}}]}
    p = path_from_dict(data)
    # rotated 90°: the long axis is along y, so the arc starts at (1 - 0.3·sin 90°·..., ...)
    pts = p.points()
    local = pts - [1.0, 0.0]
    rot = np.array([[0.0, 1.0], [-1.0, 0.0]])  # undo the 90° rotation
    u = local @ rot.T
    np.testing.assert_allclose((u[1:, 0] / 0.5) ** 2 + (u[1:, 1] / 0.3) ** 2, 1.0, atol=1e-12)
    assert len(pts) == 11  # first waypoint + 10 arc points (the arc start is not on it)


@pytest.mark.parametrize("doc, needle", [
    ("waypoints: [[0, 0]]", "need at least 2"),
    ("waypoints: [[0, 0], [0, 0]]", r"waypoints\[0\] and waypoints\[1\] coincide"),
    ("waypoints: [[0, 0], [1, .nan]]", r"waypoints\[1\]\[1\]: expected a finite number"),
    ("waypoints: [[0, 0], [1, 2, 3, 4]]", r"waypoints\[1\]: expected \[x, y\]"),
    ("waypoints: [[0, 0], {x: 1}]", r"waypoints\[1\]: expected a mapping with x and y"),
    ("waypoints: [[0, 0], {x: 1, y: 0, speed: 2}]", r"waypoints\[1\]: unknown keys \['speed'\]"),
    ("waypoints: [[0, 0], {x: 1, y: 0, stop: 1}]", r"waypoints\[1\].stop: expected true or false"),
    ("waypoints: [[0, 0], {x: 1, y: 0, heading: 1, heading_deg: 2}]", "not both"),
    ("waypoints: [[0, 0], {ellipse_arc: {center: [0, 0], radii: [0, 1], start_deg: 0, end_deg: 90}}]",
     r"ellipse_arc.radii: expected two positive numbers"),
    ("waypoints: [[0, 0], {ellipse_arc: {center: [0, 0], radii: [1, 1], start_deg: 0}}]",
     r"ellipse_arc.end_deg: missing"),
    ("closed: yes-please\nwaypoints: [[0, 0], [1, 0]]", "closed: expected true or false"),
    ("closed: true\ncycles: 0\nwaypoints: [[0, 0], [1, 0]]", "cycles: expected an integer >= 1"),
    ("closed: true\nwaypoints: [[0, 0], [1, 0], [0, 0]]", "drop the repeated waypoint"),
    ("frame_id: ''\nwaypoints: [[0, 0], [1, 0]]", "frame_id: expected a non-empty string"),
    ("waypoint: [[0, 0], [1, 0]]", r"unknown keys \['waypoint'\]"),
    ("- 1\n- 2", "expected a mapping with a waypoints list"),
    ("waypoints: [[0, 0], [1, 0]", "not valid YAML"),
])
def test_bad_yaml_names_the_entry(tmp_path, doc, needle):
    f = tmp_path / "bad.yaml"
    f.write_text(doc)
    with pytest.raises(PathError, match=needle) as info:
        load_path(f)
    assert str(f) in str(info.value)


def test_load_path_yaml_round_trip(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text(textwrap.dedent("""\
        frame_id: odom
        waypoints:
          - [0.0, 0.0]
          - [1.0, 0.0, 1.5707963267948966]
          - {x: 1.0, y: 1.0, heading_deg: 180, stop: true}
          - [0.0, 1.0]
        """))
    p = load_path(f)
    assert p.name == "p" and p.frame_id == "odom" and p.length == pytest.approx(3.0)
    assert p.waypoints[1].heading == pytest.approx(math.pi / 2)
    assert p.waypoints[2].heading == pytest.approx(math.pi) and p.waypoints[2].stop
    assert p.stop_s == (2.0, 3.0)


def test_resolve_config_file(tmp_path, monkeypatch):
    assert resolve_config_file("config/paths/ftc_cycle.yaml").is_file()  # source tree
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.yaml").write_text("waypoints: [[0, 0], [1, 0]]")
    assert resolve_config_file("mine.yaml") == tmp_path / "mine.yaml"  # cwd first
    assert preset_file("seed000_test_path").is_file()
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        resolve_config_file("nope.yaml")
    with pytest.raises(PathError, match="presets are"):
        preset_file("nope")


# -- presets ---------------------------------------------------------------------------------
def _image_fully_in_view(x: float, y: float, heading: float, ends: np.ndarray,
                         half_fov: float = math.radians(35.0)) -> np.ndarray:
    """(M,) True where both end points of an image lie inside the camera's horizontal FOV."""
    bearings = np.arctan2(ends[..., 1] - y, ends[..., 0] - x) - heading
    bearings = wrap_angles(bearings)
    return np.all(np.abs(bearings) < half_fov, axis=-1)


def _visible_fraction(path: FieldPath, field_preset: str) -> float:
    from sim_robot.world.field import Field

    _, _, ends = Field.preset(field_preset).image_arrays()
    s = np.linspace(0.0, path.length, 600)
    seen = [bool(np.any(_image_fully_in_view(*path.point_at(v), path.heading_at(v), ends))) for v in s]
    return float(np.mean(seen))


@pytest.mark.parametrize("name", ["seed000_test_path", "ftc_cycle"])
def test_presets_stay_inside_the_field_with_margin(name):
    p = load_preset(name)
    pts = p.points()
    margin = 12 * INCH  # robot half-size (9 in) plus 3 in
    assert np.all(np.abs(pts) <= HALF_FIELD - margin + 1e-12), pts[np.abs(pts).max(axis=1).argmax()]
    assert p.frame_id == "map"


def test_seed000_path_matches_the_paper_description():
    p = load_preset("seed000_test_path")
    # fig. 7: starts at (0, 0) in and ends at (75, 2) in -> the same displacement on the field
    assert ((p.xs[-1] - p.xs[0]) / INCH, (p.ys[-1] - p.ys[0]) / INCH) == pytest.approx((75.0, 2.0))
    # straight lines, left and right turns: signed heading changes at the corners
    turns = [math.degrees(math.remainder(p.seg_heading_start[i + 1] - p.seg_heading_end[i], 2 * math.pi))
             for i in range(p.segment_count - 1)]
    big = [round(t) for t in turns if abs(t) > 45]
    assert big.count(90) >= 3 and big.count(-90) >= 1  # left (CCW) and right (CW) turns
    # an elliptical curve: many small clockwise turns in a row summing to -180°
    small = [t for t in turns if 0 < abs(t) < 45]
    assert len(small) >= 20 and sum(small) == pytest.approx(-180.0, abs=1e-6)
    # images on the top/bottom walls in view for part of the route but not all of it
    frac = _visible_fraction(p, "seed000")
    assert 0.2 < frac < 0.8, frac


def test_ftc_cycle_preset():
    p = load_preset("ftc_cycle")
    assert p.closed and p.cycles == 1
    assert len(p.stop_s) == 2  # hub, then back in the warehouse
    assert (p.xs[0], p.ys[0]) == (p.xs[-1], p.ys[-1])
    hub_stop = p.stop_indices[0]
    hub = np.array([-12.0, -24.0]) * INCH
    assert np.hypot(p.xs[hub_stop] - hub[0], p.ys[hub_stop] - hub[1]) == pytest.approx(20 * INCH)
    assert p.xs[0] > 24 * INCH and p.ys[0] < -24 * INCH  # warehouse corner (red, FTC axes)
    five = load_preset("ftc_cycle", cycles=5)
    assert five.length == pytest.approx(5 * p.length) and len(five.stop_s) == 10
    frac = _visible_fraction(p, "freight_frenzy")
    assert 0.2 < frac < 0.8, frac
