"""field_view without a browser: the drawing data, page-command validation, the view state, the
aiohttp server (pages, WebSocket, a page that stops reading) and the node's start-up errors."""

from __future__ import annotations

import asyncio
import json
import math
import socket
import subprocess
import time

import numpy as np
import pytest
from helpers.ros_helpers import REPO

from ekf_localization.core.ellipse import chi2_2dof_quantile
from ekf_localization.core.units import NS_PER_S
from ekf_localization.ros.parameters import parameters_from_yaml
from ekf_localization.tools.view_state import CommandError, ViewState, parse_command
from sim_robot.ros.sim_params import parse_parameters
from sim_robot.world.field_drawing import field_drawing


def _field() -> dict:
    world, _ = parse_parameters(parameters_from_yaml(REPO / "config" / "sim.yaml", "sim_node"))
    return field_drawing(world.field, world.ramp)


def test_field_drawing_of_the_shipped_sim_config() -> None:
    world, _ = parse_parameters(parameters_from_yaml(REPO / "config" / "sim.yaml", "sim_node"))
    d = json.loads(json.dumps(field_drawing(world.field, world.ramp)))  # JSON-able as it is
    assert d["size"] == pytest.approx(144 * 0.0254)
    assert d["tile"] == pytest.approx(24 * 0.0254)
    assert len(d["images"]) == len(world.field.images) == 4
    for im, src in zip(d["images"], world.field.images, strict=True):
        (ax, ay), (bx, by) = im["ends"]
        assert math.hypot(bx - ax, by - ay) == pytest.approx(src.width)
        assert ((ax + bx) / 2, (ay + by) / 2) == pytest.approx((src.x, src.y))
    assert d["ramp"] is None  # sim.yaml: ramp.enabled false
    ramp = parse_parameters({"ramp.enabled": True})[0].ramp
    assert field_drawing(world.field, ramp)["ramp"]["x_min"] == ramp.x_min


def test_parse_command_accepts_set_pose_and_reset() -> None:
    cmd = parse_command('{"type": "set_pose", "x": 1.0, "y": -0.5, "yaw": 7.0}', 1.8288)
    assert (cmd.action, cmd.x, cmd.y) == ("set_pose", 1.0, -0.5)
    assert cmd.yaw == pytest.approx(7.0 - 2 * math.pi)  # wrapped
    assert parse_command('{"type": "reset"}', 1.8).action == "reset"
    assert parse_command(b'{"type":"set_pose","x":0,"y":0,"yaw":0}', 1.8).action == "set_pose"


@pytest.mark.parametrize("text", [
    '{"type": "set_pose", "x": NaN, "y": 0, "yaw": 0}',
    '{"type": "set_pose", "x": 0, "y": Infinity, "yaw": 0}',
    '{"type": "set_pose", "x": 0, "y": 0, "yaw": 1e400}',  # overflows to inf
    '{"type": "set_pose", "x": "1", "y": 0, "yaw": 0}',
    '{"type": "set_pose", "x": true, "y": 0, "yaw": 0}',
    '{"type": "set_pose", "x": 0, "y": 0}',
    '{"type": "set_pose", "x": 5.0, "y": 0, "yaw": 0}',  # off the field
    '{"type": "teleport"}', '[1, 2]', 'not json', '"set_pose"', "{" + " " * 2000 + "}", "\x00binary",
])
def test_parse_command_refuses_bad_messages(text: str) -> None:
    with pytest.raises(CommandError):
        parse_command(text, 1.8288)


def test_view_state_error_ellipse_nis_and_status() -> None:
    state = ViewState(_field(), history_s=5.0)
    t0 = 10 * NS_PER_S
    cov = np.array([[0.01, 0.002], [0.002, 0.004]])
    for k in range(40):  # 20 Hz for 2 s, truth 3 cm off in x
        t = t0 + k * NS_PER_S // 20
        state.set_truth(t, 0.1 * k / 40 + 0.03, 0.0, 0.0)
        state.set_estimate(t, 0.1 * k / 40, 0.0, 0.2, cov)
    snap = json.loads(json.dumps(state.snapshot()))
    assert snap["estimate"]["yaw"] == 0.2
    ring = np.array(snap["estimate"]["ellipse"])
    d = ring - [snap["estimate"]["x"], 0.0]
    np.testing.assert_allclose(np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d),
                               chi2_2dof_quantile(0.95), rtol=2e-3)  # rounded to 0.1 mm
    errors = np.array(snap["error"])
    assert 15 <= len(errors) <= 21  # at most MAX_PLOT_RATE_HZ (10 Hz) for 2 s
    np.testing.assert_allclose(errors[:, 1], 0.03, atol=1e-4)
    state.set_estimate(t0, 0.0, 0.0, 0.0, np.full((2, 2), np.nan))  # non-finite: no ellipse
    assert state.snapshot()["estimate"]["ellipse"] is None
    nees = np.array(snap["nees"])  # (x, y) against the truth, χ²(2): e = (-0.03, 0)
    np.testing.assert_allclose(nees[:, 1], np.array([-0.03, 0.0]) @ np.linalg.solve(cov, [-0.03, 0.0]),
                               rtol=1e-2)
    state.set_status("ekf_node: pose0", 0, "ok", {"nis_pose": "2.5", "nis_pose_dof": "3",
                                                 "nis_pose_band": "[1.876, 4.250]"}, t0, source="pose0")
    state.set_status("ekf_node: pose0", 1, "1 rejected", {"nis_pose": "none", "nis_pose_dof": "3"},
                     t0 + NS_PER_S, source="pose0")
    state.set_status("ekf_node: filter", 1, "stale inputs: imu0", {}, t0, filter_status=True)
    snap = state.snapshot()
    assert snap["nis"] == {"pose0/pose": {"dof": 3, "band": [1.876, 4.25], "points": [[0.0, 2.5]]}}
    assert snap["status"] == {"name": "ekf_node: filter", "level": "WARN", "message": "stale inputs: imu0"}
    assert [s["name"] for s in snap["statuses"]] == ["ekf_node: filter", "ekf_node: pose0"]


def test_view_state_draws_the_camera_view_from_the_estimate_while_it_is_fresh() -> None:
    """tag_localizer's field of view (base_link) is drawn from the estimate: rotated by its yaw
    and moved to its position; the tags seen as given; nothing once the image is 1 s old."""
    state = ViewState(_field())
    t = 5 * NS_PER_S
    assert state.snapshot()["camera"] is None
    state.set_camera(t, [(2.0, 1.0), (0.1, 0.0), (2.0, -1.0)], [(1.5, 0.25)])
    assert state.snapshot()["camera"] is None  # no estimate to draw it from
    state.set_estimate(t + NS_PER_S // 2, 1.0, -0.5, math.pi / 2, np.eye(2) * 1e-4)
    cam = json.loads(json.dumps(state.snapshot()))["camera"]
    np.testing.assert_allclose(cam["fov"], [[0.0, 1.5], [1.0, -0.4], [2.0, 1.5]], atol=1e-12)
    assert cam["seen"] == [[1.5, 0.25]]
    state.set_estimate(t + NS_PER_S + 1, 1.0, -0.5, math.pi / 2, np.eye(2) * 1e-4)
    assert state.snapshot()["camera"] is None


# -- the server (aiohttp on its own thread), no ROS -----------------------------------------------
@pytest.fixture
def server():
    from ekf_localization.tools.field_view import ViewServer

    commands: list = []
    srv = ViewServer("127.0.0.1", 0, ViewState(_field()), commands.append, rate=20.0, max_clients=2,
                     history_s=30.0)
    srv.start()
    srv.commands = commands
    yield srv
    srv.stop()


def test_server_pages_and_websocket(server) -> None:
    import aiohttp

    async def session() -> tuple:
        async with aiohttp.ClientSession() as s:
            base = server.url
            async with s.get(base) as r:
                page = (r.status, await r.text())
            async with s.get(base + "static/field_view.js") as r:
                js = r.status
            async with s.get(base + "static/..%2Fsetup.py") as r:
                outside = r.status
            async with s.ws_connect(base + "ws") as ws:
                first = json.loads((await ws.receive(timeout=5.0)).data)
                second = json.loads((await ws.receive(timeout=5.0)).data)
                await ws.send_str('{"type": "reset"}')
                await ws.send_bytes(b"\x01")
                deadline = time.monotonic() + 5.0
                while len(server.commands) < 2 and time.monotonic() < deadline:
                    await asyncio.sleep(0.02)
            return page, js, outside, first, second

    page, js, outside, first, second = asyncio.run(session())
    assert page[0] == 200 and "<canvas id=\"field\"" in page[1] and "http" not in page[1].split("<body>")[1]
    assert js == 200 and outside == 404
    assert first["type"] == "field" and first["field"]["size"] == pytest.approx(3.6576)
    assert second["type"] == "state" and second["estimate"] is None
    assert server.commands[0] == '{"type": "reset"}' and len(server.commands) == 2


def test_a_page_that_stops_reading_is_dropped_and_blocks_nothing(server) -> None:
    """A client that never reads: the sends time out, the server drops it; writers never wait."""
    server.state.set_path([(0.001 * i, 0.0) for i in range(60_000)])  # ~1 MB a snapshot
    sock = socket.create_connection(("127.0.0.1", server.port))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.sendall(b"GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                 b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n")
    try:
        deadline = time.monotonic() + 20.0
        slowest = 0.0
        while server.slow_disconnects == 0 and time.monotonic() < deadline:
            t = time.perf_counter()
            server.state.set_estimate(0, 0.0, 0.0, 0.0, np.eye(2) * 1e-3)  # what a ROS callback does
            slowest = max(slowest, time.perf_counter() - t)
            time.sleep(0.01)
        assert server.slow_disconnects == 1
        deadline = time.monotonic() + 5.0  # the connection is aborted, then its handler ends
        while server.clients and time.monotonic() < deadline:
            time.sleep(0.05)
        assert server.clients == 0
        assert slowest < 0.5  # a snapshot under the lock takes ms; never a send
    finally:
        sock.close()


def test_port_in_use_raises_oserror(server) -> None:
    from ekf_localization.tools.field_view import ViewServer

    other = ViewServer("127.0.0.1", server.port, server.state, lambda t: None, 20.0, 1, 30.0)
    with pytest.raises(OSError):
        other.start()


@pytest.mark.ros
def test_node_port_in_use_is_one_line_and_exit_2(ros_domain) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        res = subprocess.run(["field_view", "--ros-args", "-p", f"port:={port}"], capture_output=True,
                             text=True, timeout=60, cwd=REPO)
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert lines == [f"field_view: parameter 'port': 127.0.0.1:{port} is already in use: stop the other "
                     "server or choose another with -p port:=N"], res.stderr
    res = subprocess.run(["field_view", "--ros-args", "-p", "rate:=0.0", "-p", "sim_params_file:=nope.yaml"],
                         capture_output=True, text=True, timeout=60, cwd=REPO)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "'rate'" in res.stderr


# -- bag_replay --html ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def replayed_html(tmp_path_factory):
    """A simulated drive (camera outliers, so some fixes are gated) replayed with --html."""
    import dataclasses

    from ekf_localization.tools import bag_replay
    from sim_robot.ros.sim_bag import write_sim_bag
    from sim_robot.world.world import WorldConfig

    root = tmp_path_factory.mktemp("html")
    base = WorldConfig()
    world = dataclasses.replace(base, camera=dataclasses.replace(base.camera, outlier_probability=0.1))
    bag = write_sim_bag(root / "bag", duration_s=6.0, seed=0, world_config=world)
    out = root / "view.html"
    rc = bag_replay.main([str(bag), "--out", str(root / "replay"), "--html", str(out),
                          "--set", "initial_state=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, "
                                   "0.0, 0.0, 0.0, 0.0]"])
    assert rc == 0
    return out


def _embedded(html: str) -> dict:
    start = html.index("window.FIELD_VIEW_EMBEDDED = ") + len("window.FIELD_VIEW_EMBEDDED = ")
    end = html.index(";</script>", start)
    return json.loads(html[start:end].replace("<\\/", "</"))


def test_bag_replay_html_is_self_contained_with_the_run_embedded(replayed_html) -> None:
    import re

    html = replayed_html.read_text()
    assert re.search(r"""(src|href)\s*=""", html) is None  # no file, no CDN: everything is inline
    assert "function drawState" in html and "--ok:" in html  # the page's own JS and CSS
    data = _embedded(html)
    assert data["field"]["size"] == pytest.approx(3.6576) and len(data["field"]["images"]) == 4
    assert 55 <= len(data["frames"]) <= 61  # 6 s at 10 Hz
    last = data["frames"][-1]
    assert last["estimate"]["ellipse"] and last["truth"] is not None
    accepted = sum(len(f["fixes"]["accepted"]) for f in data["frames"])
    gated = sum(len(f["fixes"]["gated"]) for f in data["frames"])
    assert accepted > 0 and gated > 0, (accepted, gated)
    err = np.array(data["error"])
    assert len(err) == len(data["frames"]) and np.all(err[:, 1] < 0.2)  # the replay tracks the truth
    assert {"odom0/twist", "pose0/pose"} <= set(data["nis"])
    assert data["nis"]["pose0/pose"]["dof"] == 3


def test_bag_replay_html_in_the_browser(replayed_html) -> None:
    from helpers import browser

    reason = browser.missing()
    if reason is not None:
        pytest.skip(reason)
    data = _embedded(replayed_html.read_text())
    driver = browser.chromium(1280, 1000)
    try:
        driver.get(replayed_html.resolve().as_uri())
        k = len(data["frames"]) // 2
        driver.execute_script(f"const s = document.getElementById('slider'); s.value = '{k}';"
                              "s.dispatchEvent(new Event('input'));")
        drawn = driver.execute_script("return fieldView.drawn;")
        frame = data["frames"][k]
        assert drawn["robot"] == [frame["estimate"]["x"], frame["estimate"]["y"]]
        assert drawn["ellipse"] == len(frame["estimate"]["ellipse"])
        assert drawn["accepted"] == len(frame["fixes"]["accepted"])
        assert drawn["gated"] == len(frame["fixes"]["gated"])
        assert driver.execute_script("return document.getElementById('clock').textContent;") == \
            f"{frame['t']:.2f} s"
        assert driver.get_log("browser") == []  # no script error
        browser.save_screenshot(driver, REPO / "output" / "field_view" / "replay.png")
    finally:
        driver.quit()


def test_demo_view_draws_the_field_the_run_uses(tmp_path) -> None:
    """ekf_demo --view: field_view reads sim.yaml with the run's field preset and ramp."""
    from ekf_localization.tools.demo_params import write_view_sim_params
    from ekf_localization.tools.view_export import load_field

    sim = REPO / "config" / "sim.yaml"
    field = load_field(write_view_sim_params(sim, tmp_path / "sim_view.yaml", "freight_frenzy", True))
    assert [im["name"] for im in field["images"]][0] == "Blue Storage"
    assert field["ramp"] is not None
    plain = load_field(write_view_sim_params(sim, tmp_path / "plain.yaml", None, False))
    assert plain == _field()


def test_a_sim_params_file_that_does_not_load_is_one_parameter_error(tmp_path) -> None:
    """load_field runs the simulator's field_json command; its error comes back naming the parameter."""
    from ekf_localization.ros.parameters import ParameterError
    from ekf_localization.tools.view_export import load_field

    bad = tmp_path / "bad_sim.yaml"
    bad.write_text("sim_node:\n  ros__parameters:\n    field.preset: no_such_field\n")
    with pytest.raises(ParameterError, match=r"parameter 'sim_params_file': .*field\.preset") as info:
        load_field(bad)
    assert "\n" not in str(info.value) and "Traceback" not in str(info.value)
    with pytest.raises(ParameterError, match="--field-params"):
        load_field(tmp_path / "missing.yaml", "--field-params", "option")
