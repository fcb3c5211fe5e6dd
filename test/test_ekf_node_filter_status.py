"""ekf_node's filter diagnostic after a failure (issue 15, defect 7): ERROR in the period of a
prediction failure, and no longer once the filter runs cleanly again (it stayed ERROR for good).

The node runs in this process on config/ekf.yaml; its /diagnostics are read as published.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers.ros_helpers import REPO

from ekf_localization.core.measurements import PoseMeasurement
from ekf_localization.core.units import NS_PER_S as SEC

pytestmark = pytest.mark.ros


def test_filter_error_clears_once_the_filter_runs_cleanly_again(ros_context) -> None:
    from diagnostic_msgs.msg import DiagnosticStatus

    from ekf_localization.nodes.ekf_node import EkfNode

    args = ["--ros-args", "--params-file", str(REPO / "config" / "ekf.yaml")]
    node = EkfNode(context=ros_context, cli_args=args)
    published: list = []
    node._diag_pub.publish = published.append  # what the node would send on /diagnostics
    try:
        loc = node.localizer
        now = node.get_clock().now().nanoseconds
        pose = PoseMeasurement(now, "map", np.array([0.5, -0.3, 0.0, 0.0, 0.0, 0.2]), np.eye(6) * 1e-4)
        assert loc.set_pose(pose, now) is None

        def filter_status() -> tuple[int, str]:
            node._publish_diagnostics()
            st = next(s for s in published[-1].status if s.name.endswith(": filter"))
            level = int.from_bytes(st.level, "little") if isinstance(st.level, bytes) else int(st.level)
            return level, st.message

        assert filter_status()[0] != DiagnosticStatus.ERROR[0]
        loc.predict_failures += 1  # one prediction failed in this period
        level, message = filter_status()
        assert level == DiagnosticStatus.ERROR[0] and "filter failures" in message, message
        loc.advance_to(now + SEC // 10)  # the filter runs on
        level, message = filter_status()
        assert level != DiagnosticStatus.ERROR[0] and "failures" not in message, message
    finally:
        node.destroy_node()
