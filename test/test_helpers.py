"""The test helpers that other tests rely on to fail: ROS domains per xdist worker, PNG checks."""

from __future__ import annotations

import pytest
from helpers.images import assert_plot_png
from helpers.ros_helpers import worker_domains


def test_without_xdist_the_whole_range_is_used() -> None:
    assert worker_domains(56, 75, None, None) == (56, 75)


@pytest.mark.parametrize("count", [1, 2, 3, 20])
def test_workers_get_disjoint_slices_inside_the_range(count: int) -> None:
    slices = [worker_domains(56, 75, f"gw{i}", str(count)) for i in range(count)]
    ids = [d for lo, hi in slices for d in range(lo, hi + 1)]
    assert len(ids) == len(set(ids)) >= count  # no domain in two slices, none empty
    assert min(ids) >= 56 and max(ids) <= 75


def test_a_range_smaller_than_the_workers_is_an_error() -> None:
    with pytest.raises(ValueError, match="fewer ids"):
        worker_domains(56, 57, "gw0", "3")


def _figure(tmp_path, plot: bool):
    from ekf_localization.tools.plots import plt, save_figure

    fig, ax = plt.subplots(figsize=(4, 3), dpi=100)
    ax.grid(True)
    ax.set_xlabel("x [m]")
    if plot:
        ax.plot([0.0, 1.0, 2.0], [0.0, 1.0, 0.5])
    return save_figure(fig, tmp_path / ("line.png" if plot else "empty.png"))


def test_png_check_passes_a_plot_and_fails_empty_axes_wrong_sizes_and_no_png(tmp_path) -> None:
    assert assert_plot_png(_figure(tmp_path, True), 400, 300).shape[:2] == (300, 400)
    with pytest.raises(AssertionError, match="nothing plotted"):
        assert_plot_png(_figure(tmp_path, False), 400, 300)
    with pytest.raises(AssertionError, match="want 400x200"):
        assert_plot_png(tmp_path / "line.png", 400, 200)
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(AssertionError, match="not a PNG"):
        assert_plot_png(tmp_path / "text.png", 400)
