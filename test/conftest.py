"""Shared pytest setup: DDS stays on this machine, each ROS test gets its own domain."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

# Must be set before any rclpy import anywhere in the test session.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ.setdefault("MPLBACKEND", "Agg")

sys.path.insert(0, str(Path(__file__).parent))

from helpers.ros_helpers import allocate_domain  # noqa: E402


@pytest.fixture
def ros_domain(monkeypatch: pytest.MonkeyPatch) -> int:
    """A fresh ROS_DOMAIN_ID for this test, exported so child processes inherit it."""
    d = allocate_domain()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(d))
    return d


@pytest.fixture
def ros_context(ros_domain: int):
    """A fresh rclpy Context on this test's domain, shut down afterwards."""
    rclpy = pytest.importorskip("rclpy")
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    try:
        yield ctx
    finally:
        if ctx.ok():
            rclpy.shutdown(context=ctx)
