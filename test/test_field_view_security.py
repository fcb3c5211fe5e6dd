"""field_view off localhost (issue 35, case 9): a real field_view process and a real HTTP client.

127.0.0.1 is "this machine only": the page's set_pose and reset need no token. Any other
address is "served beyond this machine" (tested on another loopback address, 127.0.0.2, so
nothing leaves the machine): viewing stays open, set_pose and reset need the token printed at
start, and a WebSocket opened by another site's page (Origin) is refused in both modes.
"""

from __future__ import annotations

import asyncio
import json
import re
import time

import pytest
from helpers.ros_helpers import running_process, spin_until, wait_for_publishers

pytestmark = pytest.mark.ros

SET_POSE = json.dumps({"type": "set_pose", "x": 0.5, "y": 0.25, "yaw": 0.1})


async def _client(base: str, query: str = "", origin: str | None = None) -> tuple[int, str]:
    """GET the page, open the WebSocket (with ``query``, ``origin``), read the field, send a
    set_pose; (page status, "sent" or the handshake's refusal)."""
    import aiohttp

    async with aiohttp.ClientSession() as s:
        async with s.get(base) as r:
            status = r.status
        headers = {"Origin": origin} if origin else {}
        try:
            async with s.ws_connect(base + "ws" + query, headers=headers) as ws:
                first = json.loads((await ws.receive(timeout=5.0)).data)
                assert first["type"] == "field"  # viewing: the field and the state come
                json.loads((await ws.receive(timeout=5.0)).data)
                await ws.send_str(SET_POSE)
                await asyncio.sleep(0.3)
        except aiohttp.WSServerHandshakeError as exc:
            return status, f"refused {exc.status}"
    return status, "sent"


def _published(ex, got: list, base: str, query: str, origin: str | None = None,
               timeout: float = 15.0) -> bool:
    """Send set_pose from a page until one arrives on ``got``: field_view's publisher may not yet
    have matched this process's subscription (a late DDS peer takes ~2.5 s) when the first goes."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        assert asyncio.run(_client(base, query, origin)) == (200, "sent")
        if spin_until(ex, lambda: bool(got), timeout=1.0):
            return True
    return False


@pytest.mark.parametrize("host", ["127.0.0.1", "127.0.0.2"])
def test_set_pose_needs_the_token_off_localhost_and_cross_origin_is_refused(ros_context, tmp_path, host):
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    node = Node("view_security_probe", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    got: list = []
    sub = node.create_subscription(PoseWithCovarianceStamped, "set_pose", got.append, 10)
    log = tmp_path / "field_view.log"
    with running_process(["field_view", "--ros-args", "-p", f"host:={host}", "-p", "port:=0"], log):
        assert spin_until(ex, lambda: "field_view: http" in log.read_text(), timeout=30.0), log.read_text()
        url = re.search(r"field_view: (\S+)", log.read_text()).group(1)
        base, _, query = url.partition("?")
        assert base.startswith(f"http://{host}:")
        assert wait_for_publishers(ex, sub, 1, timeout=20.0)

        # another site's page in a browser: refused whatever the address (the WebSocket handshake)
        assert asyncio.run(_client(base, "?" + query if query else "", origin="http://evil.example")) \
            == (200, "refused 403")
        if host == "127.0.0.1":  # this machine only: the page's own origin needs no token
            assert not query, url
            assert _published(ex, got, base, "", origin=base.rstrip("/")), \
                "set_pose from the local page not published"
            return
        token = dict(p.split("=", 1) for p in query.split("&"))["token"]
        assert len(token) >= 16
        # the printed URL first: once its set_pose arrived, field_view's publisher has matched this
        # subscription, so a set_pose that does not arrive below was refused, not lost in discovery
        assert _published(ex, got, base, "?" + query), "set_pose with the token not published"
        n = len(got)
        assert asyncio.run(_client(base, origin=base.rstrip("/"))) == (200, "sent")  # no token
        spin_until(ex, lambda: len(got) > n, timeout=1.5)
        assert len(got) == n, "set_pose without the token was published"
        assert asyncio.run(_client(base, "?token=wrong" + token[5:])) == (200, "sent")
        spin_until(ex, lambda: len(got) > n, timeout=1.5)
        assert len(got) == n, "set_pose with a wrong token was published"
        assert (got[0].pose.pose.position.x, got[0].pose.pose.position.y) == (0.5, 0.25)
