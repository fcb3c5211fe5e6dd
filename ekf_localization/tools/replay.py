"""The offline replay engine: a bag's messages through a Localizer, in receive order.

Messages go through exactly the code ekf_node runs (:mod:`ekf_localization.ros.conversions`
-> :class:`ekf_localization.core.localizer.Localizer`), with the receive time as the
filter's clock. ``bag_replay`` is its command line; the demo and the tuner use it too.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.localizer import Estimate, Innovation, Localizer
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros.conversions import (
    UNREADABLE_ERRORS,
    control_from_message,
    feed_transforms,
    message_to_measurement,
    odometry_arrays,
)
from ekf_localization.ros.ekf_parameters import parse_ekf_config
from ekf_localization.ros.parameters import (
    ParameterError,
    expected,
    parameters_from_yaml,
    parse_parameter_value,
)
from ekf_localization.tools import bag_io
from ekf_localization.tools.evaluation import Trajectory

OUTPUT_TOPIC = "/odometry/filtered"
CONTROL_TOPIC = "/cmd_vel"
TF_TOPIC, TF_STATIC_TOPIC = "/tf", "/tf_static"


def abs_topic(topic: str) -> str:
    """The topic name with a leading slash (bags record absolute names)."""
    return topic if topic.startswith("/") else "/" + topic


@dataclass
class ReplayResult:
    estimates: list[Estimate] = field(default_factory=list)
    messages: int = 0
    seconds: float = 0.0
    localizer: Localizer | None = None

    def trajectory(self) -> Trajectory:
        """Planar trajectory [x y θ vx vy ω] with the (x, y, θ) covariance."""
        k = len(self.estimates)
        states = np.zeros((k, 6))
        covs = np.zeros((k, 3, 3))
        t = np.zeros(k, dtype=np.int64)
        for i, est in enumerate(self.estimates):
            pose, pcov, twist, _ = odometry_arrays(est)
            t[i] = est.stamp_ns
            states[i] = [pose[0], pose[1], pose[5], twist[0], twist[1], twist[5]]
            covs[i] = pcov[np.ix_([0, 1, 5], [0, 1, 5])]
        return Trajectory(t, states, covs)


def load_config(params: Path, node_name: str = "ekf_node", overrides: list[str] | None = None) -> EkfConfig:
    """The node's parameters from its YAML, with NAME=VALUE overrides (YAML syntax values)."""
    values = parameters_from_yaml(params, node_name)
    problems = []
    for item in overrides or []:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            problems.append(expected(item, "NAME=VALUE", item, what="--set"))
            continue
        values[name.strip()] = parse_parameter_value(text)
    if problems:
        raise ParameterError(problems)
    return parse_ekf_config(values, MODELS)


def missing_inputs(bag: Path | str, config: EkfConfig) -> str | None:
    """Why the bag cannot be replayed with ``config`` (none of its input topics), or None."""
    types = bag_io.topic_types(bag)
    wanted = [abs_topic(inp.topic) for inp in config.inputs] + ([CONTROL_TOPIC] if config.use_control else [])
    if any(t in types for t in wanted):
        return None
    has = ", ".join(sorted(types)) or "no topics"
    return (f"bag '{bag}' has none of the input topics of the parameters ({', '.join(wanted) or 'none'}); "
            f"expected a bag recording at least one of them (it has: {has})")


@dataclass(frozen=True, eq=False)
class ReplayInput:
    """A bag's input messages read and converted once, in receive order, for repeated replays.

    ``events``: (receive ns, input name, ``CONTROL_TOPIC`` or ``TF_TOPIC``, Measurement /
    ControlCommand / TF message, or None for an unreadable message). Valid for any config with
    the same input topics, kinds and ``use_control`` (``key``): only the noise may differ, as
    when tuning.
    """

    events: tuple[tuple[int, str, object], ...]
    recorded_stamps: tuple[int, ...]  # header stamps of the recorded output topic (may be empty)
    key: tuple
    static_transforms: tuple[object, ...] = ()  # /tf_static messages


def _input_key(config: EkfConfig) -> tuple:
    return (tuple((abs_topic(i.topic), i.name, i.kind) for i in config.inputs), config.use_control)


def read_replay_input(bag: Path | str, config: EkfConfig, output_topic: str = OUTPUT_TOPIC) -> ReplayInput:
    """Read the messages of ``config``'s inputs (and cmd_vel with ``use_control``) from ``bag``."""
    inputs = {abs_topic(inp.topic): inp for inp in config.inputs}
    types = bag_io.topic_types(bag)
    out_topic = abs_topic(output_topic)
    stamps: tuple[int, ...] = ()
    if out_topic in types:
        stamps = tuple(sorted({stamp_to_ns(m.msg.header.stamp)
                               for m in bag_io.iter_messages(bag, [out_topic])}))
    static_topics = [TF_STATIC_TOPIC] if TF_STATIC_TOPIC in types else []
    static = tuple(m.msg for m in bag_io.iter_messages(bag, static_topics))
    topics = [t for t in types if t in inputs or (config.use_control and t == CONTROL_TOPIC)
              or (t == TF_TOPIC and t not in inputs)]
    events = []
    for m in bag_io.iter_messages(bag, topics):
        now = m.log_time_ns
        if m.topic == TF_TOPIC and m.topic not in inputs:
            events.append((now, TF_TOPIC, m.msg))
            continue
        if m.topic == CONTROL_TOPIC and m.topic not in inputs:
            events.append((now, CONTROL_TOPIC, control_from_message(m.msg, now)))
            continue
        inp = inputs[m.topic]
        try:
            item = message_to_measurement(inp.kind, m.msg)
        except UNREADABLE_ERRORS:
            item = None
        events.append((now, inp.name, item))
    return ReplayInput(tuple(events), stamps, _input_key(config), static)


def replay(bag: Path | str | ReplayInput, config: EkfConfig, output_stamps: str = "recorded",
           output_topic: str = OUTPUT_TOPIC, ties: str = "inputs_first",
           innovation_listener: Callable[[Innovation], None] | None = None) -> ReplayResult:
    """Feed the bag through a Localizer in receive order; collect estimates.

    ``bag``: a bag path, or a :class:`ReplayInput` read from one (to replay it many times).
    ``output_stamps``: "recorded" = at the header stamps of the ``output_topic`` messages in
    the bag, each taken when the bag's clock (receive times) reaches it, as the node's timer
    did (falls back to "grid" if there are none); "grid" = every 1/frequency of bag time.
    ``ties``: an input received in the same clock tick as an output is fused before
    ("inputs_first") or after ("outputs_first") that output; the online node's executor may
    have done either. ``innovation_listener`` receives every update's innovation.
    """
    if ties not in ("inputs_first", "outputs_first"):
        raise ValueError(f"ties must be 'inputs_first' or 'outputs_first', got {ties!r}")
    source = bag if isinstance(bag, ReplayInput) else read_replay_input(bag, config, output_topic)
    if source.key != _input_key(config):
        raise ValueError("the ReplayInput was read for other inputs or another use_control")
    loc = make_localizer(config)
    loc.innovation_listener = innovation_listener
    res = ReplayResult(localizer=loc)
    if output_stamps == "recorded" and not source.recorded_stamps:
        output_stamps = "grid"
    stamps = source.recorded_stamps if output_stamps == "recorded" else ()
    # /tf_static holds for all time (as in tf2): loaded before the first message; /tf in receive order
    for msg in source.static_transforms:
        feed_transforms(loc.transforms, msg, static=True)
    period = config.publish_period_ns
    next_grid: int | None = None
    k = 0
    t0 = time.perf_counter()

    def emit(t_ns: int) -> None:
        est = loc.advance_to(t_ns) if output_stamps == "grid" else loc.estimate_at(t_ns)
        if est is not None and est.is_finite():
            res.estimates.append(est)

    for now, name, item in source.events:
        if output_stamps == "grid":
            if next_grid is None:
                next_grid = now - now % period + period
            while next_grid <= now:
                emit(next_grid)
                next_grid += period
        else:  # the node's timer fired at these stamps before this message arrived
            while k < len(stamps) and (stamps[k] < now or (ties == "outputs_first" and stamps[k] == now)):
                emit(stamps[k])
                k += 1
        res.messages += 1
        if name == TF_TOPIC:
            feed_transforms(loc.transforms, item, static=False)
        elif name == CONTROL_TOPIC:
            loc.add_control(item, now)
        elif item is None:
            loc.note_unreadable(name)
        else:
            loc.add_measurement(name, item, now)
    for t in stamps[k:]:
        emit(t)
    res.seconds = time.perf_counter() - t0
    return res
