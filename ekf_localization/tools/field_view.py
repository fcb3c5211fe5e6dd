"""field_view: the field, the estimate and its plots live in a browser (docs/field_view.md).

    ros2 run ekf_localization field_view            # then open http://127.0.0.1:8765/

The node subscribes to the estimate (``odometry/filtered``), the ground truth, the path and the
target of pure_pursuit_node, ekf_node's markers (the camera fixes, accepted and gated),
tag_localizer's markers (the camera's field of view and the tags it sees) and ``/diagnostics``
(the status and each input's NIS), and keeps them in a
:class:`~ekf_localization.tools.view_state.ViewState`. An aiohttp server on its own thread and
event loop serves the page (static files shipped in ``ekf_localization/web``) and pushes the
state over a WebSocket at ``rate``. The ROS executor never waits on a browser: a page only
reads snapshots, each send has a timeout, and its commands (validated:
:func:`~ekf_localization.tools.view_state.parse_command`) go through a bounded queue that a
timer drains into ``set_pose`` and the ``reset`` service. A port in use: one line, exit 2.
"""

from __future__ import annotations

import asyncio
import errno
import json
import queue
import secrets
import sys
import threading
from collections.abc import Callable
from typing import Any
from urllib.parse import urlsplit

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PointStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from std_srvs.srv import Empty

from ekf_localization.core.angles import quaternion_to_yaw, yaw_to_quaternion
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.ros import extras, markers
from ekf_localization.ros.field_view_parameters import (
    FIELD_VIEW_PARAMETERS,
    NODE_NAME,
    parse_field_view_settings,
)
from ekf_localization.ros.node_parameters import declare_unset, given_values, refuse_changes
from ekf_localization.ros.node_runner import run_node
from ekf_localization.ros.parameters import ParameterError, Problem
from ekf_localization.ros.throttled_log import ThrottledLog
from ekf_localization.tools.view_export import load_field, web_dir
from ekf_localization.tools.view_state import Command, CommandError, ViewState, parse_command

WEB_FILES = ("index.html", "field_view.js", "field_view.css")
SEND_TIMEOUT_S = 1.0  # a page that takes longer to accept one message is disconnected
COMMAND_QUEUE = 16
LOCAL_ONLY_HOSTS = ("127.0.0.1", "localhost", "::1")  # served to this machine only: no token needed


class ViewServer:
    """aiohttp (HTTP + WebSocket) on its own thread and event loop (module docstring)."""

    def __init__(self, host: str, port: int, state: ViewState, on_command: Callable[[str], None],
                 rate: float, max_clients: int, history_s: float) -> None:
        self.host, self.port = host, port
        self.state = state
        self.on_command = on_command
        self.period = 1.0 / rate
        self.max_clients = max_clients
        self.history_s = history_s
        self.clients = 0
        self.refused = 0
        self.slow_disconnects = 0
        self.cross_origin_refused = 0  # WebSocket handshakes from another site's page
        self.commands_refused = 0  # set_pose / reset on a connection without the token
        # Bound beyond this machine: state-changing commands need this token (printed at start)
        self.token = None if host in LOCAL_ONLY_HOSTS else secrets.token_urlsafe(16)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner = None
        self._stop: asyncio.Event | None = None
        self._cache: tuple[float, str] = (-1.0, "")
        self._files = {name: (web_dir() / name) for name in WEB_FILES}

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    @property
    def page_url(self) -> str:
        """The URL to open: with the token when one is needed for set_pose and reset."""
        return self.url + (f"?token={self.token}" if self.token else "")

    def _may_command(self, request) -> bool:
        """Whether a page's connection may change state: always on this machine only, else
        with the token in its URL's query."""
        return self.token is None or secrets.compare_digest(request.query.get("token", ""), self.token)

    @staticmethod
    def _same_origin(request) -> bool:
        """A browser names the page that opens a WebSocket (Origin): another site's page, which
        could drive the robot's estimate from a visitor's browser, is refused. A client that is
        no browser sends none (the token still guards its commands)."""
        origin = request.headers.get("Origin")
        return origin is None or urlsplit(origin).netloc == request.host

    def start(self) -> None:
        """Bind and serve; raises OSError (e.g. the port is in use) before returning."""
        ready = threading.Event()
        failure: list[BaseException] = []
        self._thread = threading.Thread(target=self._run, args=(ready, failure), name="field_view_http",
                                        daemon=True)
        self._thread.start()
        ready.wait()
        if failure:
            self._thread.join(timeout=5.0)
            raise failure[0]

    def stop(self) -> None:
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def _run(self, ready: threading.Event, failure: list[BaseException]) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._serve(ready, failure))
        finally:
            ready.set()
            loop.close()

    async def _serve(self, ready: threading.Event, failure: list[BaseException]) -> None:
        from aiohttp import web

        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name}", self._static)
        app.router.add_get("/ws", self._websocket)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await self._runner.setup()
        self._stop = asyncio.Event()
        try:
            site = web.TCPSite(self._runner, self.host, self.port, reuse_address=False)
            await site.start()
            sockets = site._server.sockets if site._server is not None else []
            if sockets:
                self.port = sockets[0].getsockname()[1]  # port 0: the one the OS chose
        except OSError as exc:
            failure.append(exc)
            await self._runner.cleanup()
            ready.set()
            return
        ready.set()
        await self._stop.wait()
        await self._runner.cleanup()

    async def _index(self, request):
        from aiohttp import web

        return web.FileResponse(self._files["index.html"], headers={"Cache-Control": "no-store"})

    async def _static(self, request):
        from aiohttp import web

        path = self._files.get(request.match_info["name"])  # only the shipped files, by name
        if path is None or request.match_info["name"] == "index.html":
            raise web.HTTPNotFound()
        return web.FileResponse(path, headers={"Cache-Control": "no-store"})

    def _state_text(self) -> str:
        """The snapshot as JSON, built once per period however many pages there are."""
        now = self._loop.time()
        if now - self._cache[0] >= 0.5 * self.period:
            self._cache = (now, json.dumps(self.state.snapshot(), separators=(",", ":")))
        return self._cache[1]

    async def _websocket(self, request):
        from aiohttp import WSMsgType, web

        if not self._same_origin(request):
            self.cross_origin_refused += 1
            raise web.HTTPForbidden(text="cross-origin WebSocket refused")
        may_command = self._may_command(request)
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=4096, compress=False)
        await ws.prepare(request)
        if self.clients >= self.max_clients:
            self.refused += 1
            await ws.close(message=b"too many pages open")
            return ws
        self.clients += 1
        sender = asyncio.ensure_future(self._push(ws, request))
        try:
            async for msg in ws:
                if msg.type in (WSMsgType.TEXT, WSMsgType.BINARY) and not may_command:
                    self.commands_refused += 1  # viewing stays open; changing state needs the token
                elif msg.type == WSMsgType.TEXT:
                    self.on_command(msg.data)
                elif msg.type == WSMsgType.BINARY:
                    self.on_command(b"\x00binary")  # counted as a bad message
        finally:
            sender.cancel()
            self.clients -= 1
        return ws

    async def _push(self, ws, request) -> None:
        try:
            await asyncio.wait_for(ws.send_str(json.dumps({"type": "field", "field": self.state.field,
                                                           "history": self.history_s})), SEND_TIMEOUT_S)
            while not ws.closed:
                await asyncio.wait_for(ws.send_str(self._state_text()), SEND_TIMEOUT_S)
                await asyncio.sleep(self.period)
        except asyncio.TimeoutError:  # its buffers are full: drop the connection, unsent data too
            self.slow_disconnects += 1
            if request.transport is not None:
                request.transport.abort()
        except (ConnectionError, RuntimeError):  # the page went away mid-send
            pass


class FieldViewNode(Node):
    """The ROS side of the view (module docstring). Raises ParameterError on a bad parameter
    or a port in use."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.settings = s = parse_field_view_settings(given_values(self))
        self._throttled = ThrottledLog(self.get_logger())
        declare_unset(self, FIELD_VIEW_PARAMETERS, FIELD_VIEW_PARAMETERS.defaults())
        refuse_changes(self, FIELD_VIEW_PARAMETERS)
        field = load_field(s.sim_params_file)
        self.position_limit = 0.5 * field["size"]
        self.state = ViewState(field, s.history)
        self._commands: queue.Queue[Command] = queue.Queue(maxsize=COMMAND_QUEUE)
        self._counts_lock = threading.Lock()
        self._frame_id = "map"
        self._filter_name = f"{s.ekf_node_name}: filter"
        sensor = qos_profile_sensor_data  # best effort matches reliable and best-effort publishers
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(Odometry, s.odom_topic, self._on_estimate, 10)
        self.create_subscription(Odometry, s.ground_truth_topic, self._on_truth, sensor)
        self.create_subscription(PathMsg, "pure_pursuit/path", self._on_path, latched)
        self.create_subscription(PointStamped, "pure_pursuit/target", self._on_target, 10)
        from visualization_msgs.msg import MarkerArray

        self.create_subscription(MarkerArray, markers.EKF_MARKER_TOPIC_OUTSIDE, self._on_ekf_markers, 5)
        self.create_subscription(MarkerArray, markers.PURE_PURSUIT_MARKER_TOPIC, self._on_pp_markers, 5)
        self.create_subscription(MarkerArray, markers.TAG_LOCALIZER_MARKER_TOPIC_OUTSIDE,
                                 self._on_tag_markers, 5)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 50)
        self._set_pose = self.create_publisher(PoseWithCovarianceStamped, "set_pose", 10)
        self._reset = self.create_client(Empty, "ekf_node/reset")  # ekf_node's ~/reset
        self._diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(0.05, self._drain_commands, clock=steady)
        self.create_timer(1.0, self._publish_diagnostics, clock=steady)
        self.server = ViewServer(s.host, s.port, self.state, self.command_from_page, s.rate, s.max_clients,
                                 s.history)
        try:
            self.server.start()
        except OSError as exc:
            in_use = getattr(exc, "errno", None) == errno.EADDRINUSE
            reason = "is already in use" if in_use else f"cannot be served ({exc})"
            raise ParameterError(Problem("port", f"{s.host}:{s.port} {reason}: stop the other server or "
                                         "choose another with -p port:=N")) from None
        url = self.server.page_url
        if self.server.token:
            self.get_logger().warning(f"field view served beyond this machine ({s.host}): set_pose and reset "
                                      "need the token in this URL; viewing is open")
        self.get_logger().info(f"field view: {url}")
        print(f"field_view: {url}", flush=True)

    def destroy_node(self) -> None:
        self.server.stop()
        super().destroy_node()

    # -- page commands (the server's thread) ------------------------------------------------
    def command_from_page(self, text: str | bytes) -> None:
        """Validate a page's message and queue it for the ROS thread (never blocks)."""
        try:
            cmd = parse_command(text, self.position_limit)
        except CommandError as exc:
            self._count("bad_messages")
            self._throttled.warning("page", f"page message rejected: {exc}")
            return
        try:
            self._commands.put_nowait(cmd)
        except queue.Full:
            self._count("dropped_commands")

    def _count(self, name: str) -> None:
        with self._counts_lock:
            self.state.counters[name] += 1

    def _drain_commands(self) -> None:
        while True:
            try:
                cmd = self._commands.get_nowait()
            except queue.Empty:
                return
            if cmd.action == "reset":
                if self._reset.service_is_ready():
                    self._reset.call_async(Empty.Request())
                    self._count("reset")
                    self.get_logger().info("reset requested from the page")
                else:
                    self._count("dropped_commands")
                    self.get_logger().warning("reset: ekf_node's reset service is not available")
                continue
            s = self.settings
            msg = PoseWithCovarianceStamped()
            msg.header.frame_id = self._frame_id
            msg.header.stamp = self.get_clock().now().to_msg()
            msg.pose.pose.position.x, msg.pose.pose.position.y = cmd.x, cmd.y
            q = yaw_to_quaternion(cmd.yaw)
            o = msg.pose.pose.orientation
            o.x, o.y, o.z, o.w = q
            cov = [0.0] * 36
            cov[0] = cov[7] = s.set_pose_position_variance
            cov[14] = cov[21] = cov[28] = 1e-6
            cov[35] = s.set_pose_yaw_variance
            msg.pose.covariance = cov
            self._set_pose.publish(msg)
            self._count("set_pose")
            self.get_logger().info(f"set_pose from the page: x={cmd.x:.3f} y={cmd.y:.3f} yaw={cmd.yaw:.3f}")

    # -- ROS inputs ---------------------------------------------------------------------------
    def _on_estimate(self, msg: Odometry) -> None:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        self._frame_id = msg.header.frame_id or self._frame_id
        cov = msg.pose.covariance
        yaw = quaternion_to_yaw(q.x, q.y, q.z, q.w)
        self.state.set_estimate(stamp_to_ns(msg.header.stamp), p.x, p.y, yaw,
                                [[cov[0], cov[1]], [cov[6], cov[7]]])

    def _on_truth(self, msg: Odometry) -> None:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        self.state.set_truth(stamp_to_ns(msg.header.stamp), p.x, p.y, quaternion_to_yaw(q.x, q.y, q.z, q.w))

    def _on_path(self, msg: PathMsg) -> None:
        self.state.set_path([(ps.pose.position.x, ps.pose.position.y) for ps in msg.poses])

    def _on_target(self, msg: PointStamped) -> None:
        self.state.set_target((msg.point.x, msg.point.y))

    def _on_ekf_markers(self, msg) -> None:
        accepted = markers.points_of(msg, markers.NS_FIXES_ACCEPTED)
        gated = markers.points_of(msg, markers.NS_FIXES_GATED)
        if accepted is not None or gated is not None:
            self.state.set_fixes(accepted or [], gated or [])

    def _on_pp_markers(self, msg) -> None:
        ring = markers.points_of(msg, markers.NS_LOOKAHEAD)
        if ring and len(ring) > 2:  # a closed circle: its radius is half the widest extent
            xs = [p[0] for p in ring]
            self.state.set_lookahead(0.5 * (max(xs) - min(xs)))

    def _on_tag_markers(self, msg) -> None:
        fov = markers.points_of(msg, markers.NS_CAMERA_FOV)
        seen = markers.points_of(msg, markers.NS_TAGS_SEEN)
        if seen is not None and msg.markers:
            self.state.set_camera(stamp_to_ns(msg.markers[0].header.stamp), fov or None, seen)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        prefix = f"{self.settings.ekf_node_name}: "
        for st in msg.status:
            if st.name.startswith(f"{NODE_NAME}: "):
                continue  # our own
            values = {kv.key: kv.value for kv in st.values}
            level = st.level if isinstance(st.level, int) else int.from_bytes(st.level, "little")
            source = None
            if st.name.startswith(prefix) and st.name != self._filter_name:
                source = st.name[len(prefix):]
            self.state.set_status(st.name, level, st.message, values, stamp,
                                  filter_status=st.name == self._filter_name, source=source)

    def _publish_diagnostics(self) -> None:
        srv = self.server
        c = self.state.counters
        st = DiagnosticStatus(name=f"{NODE_NAME}: server", hardware_id=srv.url, level=DiagnosticStatus.OK,
                              message=f"serving {srv.url} to {srv.clients} page(s)")
        if c["bad_messages"]:
            st.level = DiagnosticStatus.WARN
            st.message += f"; {c['bad_messages']} bad page message(s) rejected"
        values = {"url": srv.url, "pages": srv.clients, "pages_refused": srv.refused,
                  "slow_disconnects": srv.slow_disconnects, "cross_origin_refused": srv.cross_origin_refused,
                  "commands_refused_no_token": srv.commands_refused, **c}
        st.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag.publish(arr)


def main(args: list[str] | None = None) -> int:
    return extras.check(NODE_NAME, "aiohttp") or run_node(NODE_NAME, FieldViewNode, args=args)


if __name__ == "__main__":
    sys.exit(main())
