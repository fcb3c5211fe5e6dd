"""thread_priority (ros/scheduling.py): over real DDS, ekf_node from the shipped config puts every
thread under SCHED_FIFO 40 (below controller_manager's 50) where the system allows it; where it
refuses, the node runs on, and says why in its log and on /diagnostics."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.ros_helpers import REPO, Diagnostics, fifo_allowed, node_command, running_process

from ekf_localization.ros import scheduling

SHIPPED_PRIORITY = 40  # config/ekf*.yaml: below controller_manager's 50


def test_priority_zero_changes_nothing() -> None:
    before = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    assert scheduling.use_fifo(0) is None
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before


def test_a_refusal_says_why_and_stops_at_the_first_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[int] = []

    def refuse(tid: int, policy: int, param) -> None:
        calls.append(tid)
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    assert scheduling.use_fifo(7) == "SCHED_FIFO 7 refused (Operation not permitted)"
    assert calls == scheduling.thread_ids()[:1]


def test_every_thread_of_a_process_is_listed() -> None:
    code = "import threading, time; [threading.Thread(target=time.sleep, args=(30,), daemon=True).start() " \
           "for _ in range(3)]; print('up', flush=True); time.sleep(30)"
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "up"
        tids = scheduling.thread_ids(child.pid)
        assert child.pid in tids and len(tids) == 4
    finally:
        child.kill()
        child.wait()


def _refusing_prefix() -> list[str] | None:
    """A command prefix under which SCHED_FIFO is refused: no rtprio limit and, for root, no
    CAP_SYS_NICE (util-linux's setpriv and prlimit)."""
    if not shutil.which("prlimit"):
        return None
    prefix = ["prlimit", "--rtprio=0:0", "--"]
    if os.geteuid() == 0:
        if not shutil.which("setpriv"):
            return None
        prefix = ["setpriv", "--bounding-set", "-sys_nice", "--", *prefix]
    return prefix


@pytest.mark.ros
@pytest.mark.parametrize("case", ["granted", "refused"])
def test_ekf_node_from_the_shipped_config_runs_under_sched_fifo_or_says_why_not(
        case: str, ros_context, tmp_path: Path) -> None:
    prefix: list[str] | None = []
    if case == "granted" and not fifo_allowed(SHIPPED_PRIORITY):
        pytest.skip("this user may not use SCHED_FIFO (no rtprio limit, no CAP_SYS_NICE)")
    if case == "refused":
        prefix = _refusing_prefix()
        if prefix is None:
            pytest.skip("prlimit (and, for root, setpriv) are needed to run a process without SCHED_FIFO")
    diag = Diagnostics(ros_context)
    filter_status = "ekf_node: filter"
    log = tmp_path / "ekf.log"
    params = REPO / "config" / "ekf.yaml"
    cmd = [*prefix, *node_command("ekf_node"), "--ros-args", "--params-file", str(params)]
    try:
        with running_process(cmd, log) as proc:
            said_any = diag.spin_until(lambda: diag.get(filter_status, "scheduling"), 30.0)
            assert said_any, log.read_text()[-2000:]
            said = diag.get(filter_status, "scheduling")
            policies = {tid: (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
                        for tid in scheduling.thread_ids(proc.pid)}
            assert proc.poll() is None
        text = log.read_text()
    finally:
        diag.close()
    assert len(policies) > 1  # the executor's and the DDS threads, not only the main one
    if case == "granted":
        assert said == f"SCHED_FIFO {SHIPPED_PRIORITY}"
        assert set(policies.values()) == {(os.SCHED_FIFO, SHIPPED_PRIORITY)}, policies
        assert f"scheduling SCHED_FIFO {SHIPPED_PRIORITY}" in text
    else:
        assert said == f"SCHED_FIFO {SHIPPED_PRIORITY} refused (Operation not permitted)"
        assert {p for p, _ in policies.values()} == {os.SCHED_OTHER}, policies
        assert f"thread_priority {SHIPPED_PRIORITY}: SCHED_FIFO {SHIPPED_PRIORITY} refused" in text
        assert "rtprio" in text and "Traceback" not in text


@pytest.mark.parametrize("value", [-1, 100, 50.0, True])
def test_a_thread_priority_outside_0_to_99_is_refused_naming_it(value) -> None:
    from ekf_localization.models.registry import MODELS
    from ekf_localization.ros.ekf_parameters import parse_ekf_settings
    from ekf_localization.ros.parameters import ParameterError, parameters_from_yaml

    values = parameters_from_yaml(REPO / "config" / "ekf.yaml", "ekf_node")
    assert parse_ekf_settings(values, MODELS).thread_priority == SHIPPED_PRIORITY
    with pytest.raises(ParameterError, match="thread_priority"):
        parse_ekf_settings({**values, "thread_priority": value}, MODELS)
