"""The test run's ROS domains: each xdist worker allocates from a slice of its own."""

from __future__ import annotations

import pytest
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
