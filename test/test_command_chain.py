"""A burst of drive commands keeps the command chain, and so the cost of each command and of
every prediction across it, bounded (issue 35, case 7: /odometry/filtered silent for 0.56 s
after a burst of cmd_vel, the chain growing by one link per command of the burst)."""

from __future__ import annotations

import numpy as np

from ekf_localization.core.command_model import MAX_PENDING_COMMANDS, Command, CommandModel

LATENCY = 20_000_000


def _length(command: Command | None) -> int:
    n = 0
    while command is not None:
        n, command = n + 1, command.previous
    return n


def _model() -> CommandModel:
    return CommandModel(LATENCY, 200_000_000, 10_000_000, np.zeros(3))


def test_a_burst_at_one_stamp_keeps_only_the_newest() -> None:
    model = _model()
    acting = model.then(None, 0, np.array([1.0, 0.0, 0.0]), True)
    chain = acting
    for k in range(1000):
        chain = model.then(chain, LATENCY // 2, np.array([0.0, float(k), 0.0]), True)
    assert _length(chain) == 2  # the newest of the burst and the command acting before it
    assert model.at(chain, LATENCY // 2 + LATENCY)[0][1] == 999.0
    assert model.at(chain, LATENCY // 2 + LATENCY - 1)[0][0] == 1.0


def test_a_burst_of_distinct_stamps_is_capped_keeping_the_newest_and_the_acting_one() -> None:
    model = _model()
    chain = model.then(None, 0, np.array([1.0, 0.0, 0.0]), True)
    t = LATENCY  # the first command acts from here
    for k in range(1000):  # 1 µs apart: all still pending
        chain = model.then(chain, t + 1000 * k, np.array([0.0, float(k), 0.0]), True)
    assert _length(chain) <= MAX_PENDING_COMMANDS
    assert model.at(chain, t + 1000 * 999 + LATENCY)[0][1] == 999.0  # the newest acts at its time
    assert model.at(chain, t + LATENCY - 1)[0][0] == 1.0  # the acting one until the first pending


def test_commands_slower_than_the_latency_keep_a_chain_of_one() -> None:
    model = _model()
    chain = None
    for k in range(100):
        chain = model.then(chain, k * 2 * LATENCY, np.array([float(k), 0.0, 0.0]), True)
        assert _length(chain) <= 2
