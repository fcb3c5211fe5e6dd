"""The field view in a real browser: sim + EKF + pure pursuit + field_view over DDS, headless Chromium.

Checks that the robot marker moves, the 95 % ellipse and the camera fixes are drawn, that a
click on the field (after "Set pose") reaches ekf_node as a set_pose it applies
(/odometry/filtered jumps there), that bad page messages are counted and change nothing, and
that field_view outlives the browser. Saves output/field_view/live.png. Skips (with the
reason) where Chromium, chromedriver or selenium is missing.
"""

from __future__ import annotations

import json
import math
import os
import re
import socket
import subprocess
import sys
import time
import urllib.request
from contextlib import ExitStack
from pathlib import Path

import pytest
from helpers import browser
from helpers.images import assert_plot_png
from helpers.ros_helpers import REPO, allocate_domain, node_command, running_process, spin_until

from ekf_localization.control.field_path import load_path
from ekf_localization.core.angles import wrap_angle
from ekf_localization.tools.demo_params import known_start, write_ekf_params

pytestmark = [pytest.mark.ros, pytest.mark.slow,
              pytest.mark.skipif(browser.missing() is not None, reason=str(browser.missing()))]
SCREENSHOT = REPO / "output" / "field_view" / "live.png"
URL_RE = re.compile(r"field_view: (http://127\.0\.0\.1:\d+/)")
CLICK_AT = (1.0, 1.1)  # m, on the field, away from the seed path's start
DRAG_FROM = (-1.0, 1.0)
SET_POSE_LOG = re.compile(r"set_pose: x=(-?[\d.]+) y=(-?[\d.]+) yaw=(-?[\d.]+)")


def _command(name: str) -> list[str]:
    return ["field_view"] if name == "field_view" else node_command(name)


def _floats(v) -> str:
    return "[" + ", ".join(repr(float(x)) for x in v) + "]"


def _wait_for_url(log: Path, timeout: float = 30.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        m = URL_RE.search(log.read_text(errors="replace")) if log.exists() else None
        if m:
            return m.group(1)
        time.sleep(0.1)  # polling a log file for a line, not waiting for DDS
    raise AssertionError("field_view printed no URL:\n" + log.read_text(errors="replace")[-2000:])


def _js(driver, expr: str):
    return driver.execute_script(f"return JSON.parse(JSON.stringify({expr}));")


def _until(driver, predicate, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"{what} within {timeout:g} s; page state: "
                         + json.dumps(_js(driver, "{frames: fieldView.frames, drawn: fieldView.drawn, "
                                                  "status: fieldView.state && fieldView.state.status}")))


def test_field_view_in_chromium(ros_context, tmp_path) -> None:
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    cfg = REPO / "config"
    path_file = cfg / "paths" / "seed000_test_path.yaml"
    x0, y0, th0 = load_path(path_file).start
    start = known_start(cfg / "ekf.yaml", x0, y0, th0)
    ekf_params = write_ekf_params(cfg / "ekf.yaml", tmp_path / "ekf.yaml", start)
    sim_time = ["-p", "use_sim_time:=true"]
    cmds = {
        "sim_node": ["--params-file", str(cfg / "sim.yaml"), "-p", "publish_clock:=true",
                     "-p", f"initial_pose:={_floats([x0, y0, th0])}",
                     "-p", "wait_for_topics:=[odometry/filtered, cmd_vel]"],
        "ekf_node": ["--params-file", str(ekf_params), *sim_time, "-p", "publish_markers:=true",
                     "-p", "marker_frequency:=10.0"],
        "pure_pursuit_node": ["--params-file", str(cfg / "pure_pursuit.yaml"), *sim_time,
                              "-p", "publish_markers:=true"],
        "field_view": [*sim_time, "-p", "port:=0"],
    }
    node = Node("field_view_test", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    odom: list[tuple[float, float]] = []
    node.create_subscription(Odometry, "odometry/filtered",
                             lambda m: odom.append((m.pose.pose.position.x, m.pose.pose.position.y)), 50)
    logs = {name: tmp_path / f"{name}.log" for name in cmds}
    with ExitStack() as stack:
        def start(name: str) -> None:
            procs[name] = stack.enter_context(running_process([*_command(name), "--ros-args", *cmds[name]],
                                                              logs[name]))

        procs: dict = {}
        for name in ("sim_node", "ekf_node", "field_view"):
            start(name)
        url = _wait_for_url(logs["field_view"])
        driver = browser.chromium(1280, 1000)
        try:
            driver.get(url)
            # the page is up and receiving; only then the follower, whose cmd_vel starts sim time
            _until(driver, lambda: _js(driver, "fieldView.frames") > 0, 20.0, "the page got no state")
            start("pure_pursuit_node")
            # the robot marker is drawn, with its ellipse and camera fixes, and it moves
            first = _until(driver, lambda: _js(driver, "fieldView.drawn.robot"), 40.0, "no robot drawn")
            def moved():
                r = _js(driver, "fieldView.drawn.robot")
                return r and math.dist(r, first) > 0.15

            def complete():
                d = _js(driver, "fieldView.drawn")
                return d if d["ellipse"] > 10 and d["accepted"] > 0 and d["path"] > 1 else None

            _until(driver, moved, 20.0, "the robot marker did not move")
            drawn = _until(driver, complete, 10.0, "no ellipse, accepted camera fix or path drawn")
            assert drawn["truth"] is not None
            assert _js(driver, "fieldView.state.status.level") in ("OK", "WARN")
            # bad messages from a page: counted, nothing reaches set_pose
            driver.execute_script("""
                const ws = new WebSocket("ws://" + location.host + "/ws");
                ws.onopen = function () {
                  ['{"type":"set_pose","x":NaN,"y":0,"yaw":0}', '{"type":"set_pose","x":1e9,"y":0,"yaw":0}',
                   '{"type":"set_pose","x":"1","y":0,"yaw":0}', 'not json', '{"type":"launch"}']
                    .forEach(function (m) { ws.send(m); });
                };""")
            _until(driver, lambda: _js(driver, "fieldView.state.counters.bad_messages") >= 5, 5.0,
                   "bad page messages not counted")
            assert _js(driver, "fieldView.state.counters.set_pose") == 0
            # Set pose, then a click on the field: ekf_node applies it
            canvas = driver.find_element(By.ID, "field")
            px, py = _js(driver, f"fieldView.toCanvas({CLICK_AT[0]}, {CLICK_AT[1]})")
            w, h = _js(driver, "[document.getElementById('field').clientWidth, "
                               "document.getElementById('field').clientHeight]")
            driver.find_element(By.ID, "set-pose").click()
            odom.clear()
            chain = ActionChains(driver).move_to_element_with_offset(canvas, int(px - w / 2), int(py - h / 2))
            chain.click().perform()
            assert spin_until(ex, lambda: any(math.dist(p, CLICK_AT) < 0.1 for p in odom), timeout=10.0), (
                f"/odometry/filtered never near {CLICK_AT}: last {odom[-3:]}\n"
                + logs["ekf_node"].read_text()[-1500:])
            assert _js(driver, "fieldView.sent.slice(-1)[0].type") == "set_pose"
            _until(driver, lambda: _js(driver, "fieldView.state.counters.set_pose") == 1, 5.0,
                   "set_pose not counted")
            # the estimate jumped: the camera now disagrees with it, and its fixes are gated (red)
            _until(driver, lambda: _js(driver, "fieldView.drawn.gated") > 0, 10.0, "no gated fix drawn")
            browser.save_screenshot(driver, SCREENSHOT)
            # Set pose with a drag: the heading points along it (north-east: 45 degrees)
            qx, qy = _js(driver, f"fieldView.toCanvas({DRAG_FROM[0]}, {DRAG_FROM[1]})")
            driver.find_element(By.ID, "set-pose").click()
            odom.clear()
            drag = ActionChains(driver).move_to_element_with_offset(canvas, int(qx - w / 2), int(qy - h / 2))
            drag.click_and_hold().move_by_offset(30, -30).move_by_offset(30, -30).release().perform()

            # the position stays until the camera's fixes win it back (pose recovery); the IMU's
            # absolute yaw (variance 7.6e-5 rad² against set_pose's 1e-2) takes the heading back at
            # its next update, so the applied heading is read from ekf_node's own log line
            assert spin_until(ex, lambda: any(math.dist(p, DRAG_FROM) < 0.1 for p in odom), timeout=10.0), (
                f"no estimate at {DRAG_FROM}: {odom[-2:]}; sent {_js(driver, 'fieldView.sent')}\n"
                + logs["field_view"].read_text()[-1000:] + logs["ekf_node"].read_text()[-1500:])
            applied = SET_POSE_LOG.findall(logs["ekf_node"].read_text())
            assert len(applied) == 2, applied
            x, y, yaw = (float(v) for v in applied[-1])
            assert math.dist((x, y), DRAG_FROM) < 0.02 and abs(wrap_angle(yaw - math.pi / 4)) < 0.02, applied
        finally:
            driver.quit()
        # the page is gone: field_view still runs and serves
        assert all(p.poll() is None for p in procs.values()), {n: p.poll() for n, p in procs.items()}
        with urllib.request.urlopen(url, timeout=5.0) as res:
            assert res.status == 200 and b"field view" in res.read()
    assert_plot_png(SCREENSHOT, 1280)  # browser.chromium's window width; the field's colours on it
    log = logs["field_view"].read_text()
    assert "Traceback" not in log, log[-2000:]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_camera_view_and_tags_seen_in_chromium(tmp_path) -> None:
    """``ekf_demo --camera images --view``: the page draws tag_localizer's field of view from the
    robot (its apex at the camera, 0.1 m ahead of base_link in config/sim.yaml, within the
    estimate's error) and rings on the tags it sees, with their fixes fused (ekf_node's accepted
    camera fixes). Saves output/field_view/camera.png (docs/field_view_camera.png)."""
    port = _free_port()
    log = tmp_path / "demo.log"
    env = dict(os.environ, ROS_DOMAIN_ID=str(allocate_domain()))
    cmd = [sys.executable, "-m", "ekf_localization.tools.demo", "--camera", "images", "--view",
           "--view-port", str(port), "--out", str(tmp_path / "out"), "--timeout", "120"]
    with open(log, "w") as out, subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, cwd=REPO,
                                                 env=env) as demo:
        driver = None
        try:
            deadline = time.monotonic() + 30.0
            while f"127.0.0.1:{port}" not in log.read_text() and time.monotonic() < deadline:
                assert demo.poll() is None, log.read_text()[-3000:]
                time.sleep(0.1)  # polling a log file for a line, not waiting for DDS
            driver = browser.chromium(1280, 1000)

            def page_up():
                try:
                    driver.get(f"http://127.0.0.1:{port}/")
                    return True
                except Exception:  # noqa: BLE001 - the server is still starting
                    return False

            _until(driver, page_up, 20.0, "the page did not load")

            def camera_drawn():  # one evaluation: the frame drawn and the state it was drawn from
                f = _js(driver, "{d: fieldView.drawn, cam: fieldView.state && fieldView.state.camera, "
                                "est: fieldView.state && fieldView.state.estimate}")
                d = f["d"]
                return f if d["fov"] == 3 and d["seen"] > 0 and d["accepted"] > 0 and d["robot"] else None

            frame = _until(driver, camera_drawn, 60.0, "no field of view, tags seen and fixes fused")
            drawn, cam, est = frame["d"], frame["cam"], frame["est"]
            apex = cam["fov"][1]
            assert abs(math.dist(apex, (est["x"], est["y"])) - 0.1) < 0.02, (apex, est)
            reach = [math.dist(apex, end) for end in (cam["fov"][0], cam["fov"][2])]
            assert max(abs(r - 2.0) for r in reach) < 1e-3, reach  # fov_marker_reach default
            assert drawn["seen"] == len(cam["seen"])
            browser.save_screenshot(driver, REPO / "output" / "field_view" / "camera.png")
        finally:
            if driver is not None:
                driver.quit()
            demo.terminate()
            demo.wait(timeout=30)
