"""ros/throttled_log.ThrottledLog: one line per key per period, counted, on a steady clock."""

from __future__ import annotations

from ekf_localization.ros.throttled_log import _MAX_KEYS, ThrottledLog


class _Lines:
    """A logger that keeps what it is given, by severity."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def warning(self, text: str) -> None:
        self.lines.append(("warning", text))

    def error(self, text: str) -> None:
        self.lines.append(("error", text))


def test_one_line_per_key_per_period_with_the_count_held_back() -> None:
    now = [0]
    sink = _Lines()
    log = ThrottledLog(sink, period_s=5.0, clock_ns=lambda: now[0])
    assert log.warning(("odom0", "twist", "no transform"), "odom0: rejected twist")
    for _ in range(999):  # the rest of one second at 1 kHz
        now[0] += 1_000_000
        assert not log.warning(("odom0", "twist", "no transform"), "odom0: rejected twist")
    assert log.warning(("imu0", "orientation", "gated"), "imu0: rejected orientation")  # another key: at once
    now[0] = 5_000_000_000
    assert log.error(("odom0", "twist", "no transform"), "odom0: rejected twist")
    assert sink.lines == [("warning", "odom0: rejected twist"), ("warning", "imu0: rejected orientation"),
                          ("error", "odom0: rejected twist (and 999 more since the last such line)")]


def test_text_is_built_only_when_logged() -> None:
    now = [0]
    built: list[int] = []
    sink = _Lines()
    log = ThrottledLog(sink, period_s=1.0, clock_ns=lambda: now[0])

    def text() -> str:
        built.append(now[0])
        return "slow"

    for t in range(0, 3_000_000_000, 100_000_000):  # 30 calls over 3 s: 3 lines
        now[0] = t
        log.warning("k", text)
    assert built == [0, 1_000_000_000, 2_000_000_000]
    assert [line for _, line in sink.lines] == ["slow", "slow (and 9 more since the last such line)",
                                                "slow (and 9 more since the last such line)"]


def test_keys_beyond_the_cap_forget_the_oldest() -> None:
    sink = _Lines()
    log = ThrottledLog(sink, period_s=5.0, clock_ns=lambda: 0)
    for k in range(_MAX_KEYS + 1):
        assert log.warning(k, f"line {k}")
    assert log.warning(0, "line 0 again")  # forgotten, so it logs
    assert not log.warning(_MAX_KEYS, "held")  # remembered
    assert len(sink.lines) == _MAX_KEYS + 2
