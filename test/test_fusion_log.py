"""ekf_node's fusion log (ros/fusion_log.py): rows survive the message, codes are distinct."""

from __future__ import annotations

import numpy as np
import pytest

from ekf_localization.ros import fusion_log


def test_rows_round_trip_through_the_message():
    rows = [1_700_000_000_123_456_789, 1_700_000_000_100_000_000, fusion_log.source_code("odom0"),
            -1, 5, fusion_log.source_code("cmd_vel"),
            1_700_000_000_200_000_000, 1_700_000_000_200_000_000, fusion_log.OUTPUT]
    msg = fusion_log.to_message(rows)
    back = fusion_log.rows_of(msg)
    assert back.dtype == np.int64 and back.shape == (3, 3)
    assert back.ravel().tolist() == rows  # int64 ns, no float on the way
    assert [d.size for d in msg.layout.dim] == [3, 3]


def test_codes_are_distinct_non_negative_and_a_clash_is_refused():
    names = [f"{k}{i}" for k in ("odom", "pose", "twist", "imu", "joint", "landmark") for i in range(10)]
    names += ["cmd_vel", "wheel_command", "set_pose"]
    codes = fusion_log.decode_names(names)
    assert len(codes) == len(names) and min(codes) >= 0
    assert fusion_log.OUTPUT < 0 and fusion_log.RESET < 0
    with pytest.raises(ValueError, match="not a whole number"):
        fusion_log.rows_of(type("M", (), {"data": [1, 2]})())
