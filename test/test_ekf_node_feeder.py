"""The feeder's poison rules (helpers/ekf_node_feeder.py) corrupt what they claim."""

from __future__ import annotations

import pytest
from helpers.ekf_node_feeder import build_message, poison
from helpers.fusion_scenario import config, make_scenario


def test_poison_rules_corrupt_what_they_claim() -> None:
    pytest.importorskip("rclpy")
    from ekf_localization.models.registry import make_localizer
    from ekf_localization.ros.conversions import message_to_measurement

    scn = make_scenario(duration_s=1.0, seed=1)
    loc = make_localizer(config())
    now = int(scn.t_ns[-1])
    loc.start(int(scn.t_ns[0]))
    kinds = {"odom0": "odom", "pose0": "pose", "imu0": "imu"}
    seen = 0
    for source, n in (("odom0", 20), ("pose0", 8), ("imu0", 10)):
        for j in range(n):
            msg = build_message(scn, source, j)
            reason = poison(source, j, msg, now)
            res = loc.add_measurement(source, message_to_measurement(kinds[source], msg), now)
            if reason is not None:
                seen += 1
                assert res.applied == () and res.rejected[0][1] == reason, (source, j, res)
    assert seen == 8 + 4 + 4
