"""The offline replay engine: a bag's messages through a Localizer, as ekf_node fed them.

Messages go through exactly the code ekf_node runs (:mod:`ekf_localization.ros.conversions`
-> :class:`ekf_localization.core.localizer.Localizer`). When the bag recorded ekf_node's
fusion log (``*/fusion_log``, :mod:`ekf_localization.ros.fusion_log`), the replay follows it:
the messages the node fused, in its order, with its clock, and the estimates at the moments it
published them, so the replay reproduces the recorded /odometry/filtered. Without a log, the
recorder's receive order and times stand in for the node's. ``bag_replay`` is its command line;
the demo and the tuner use it too.
"""

from __future__ import annotations

import time
from collections import defaultdict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.localizer import CONTROL_SOURCE, Estimate, Innovation, Localizer
from ekf_localization.core.measurements import ControlCommand
from ekf_localization.core.units import stamp_to_ns
from ekf_localization.models.registry import MODELS, make_localizer
from ekf_localization.ros import fusion_log
from ekf_localization.ros.conversions import (
    UNREADABLE_ERRORS,
    control_from_message,
    feed_transforms,
    message_to_measurement,
    odometry_arrays,
)
from ekf_localization.ros.ekf_node_settings import EkfNodeSettings
from ekf_localization.ros.ekf_parameters import parse_ekf_settings
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
    followed_log: bool = False  # fed as ekf_node's fusion log says
    missing: int = 0  # log rows whose message the bag lacks (the recorder missed it)
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


def load_settings(params: Path, node_name: str = "ekf_node",
                  overrides: list[str] | None = None) -> EkfNodeSettings:
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
    return parse_ekf_settings(values, MODELS)


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
    log: np.ndarray | None = None  # ekf_node's fusion log rows (k, 3), or None (none recorded)
    control_stamped: bool = True  # cmd_vel is TwistStamped (a Twist is stamped on receipt)


def find_log_topic(types: dict[str, str]) -> str | None:
    """The bag's one fusion log topic (``<node>/fusion_log``), or None."""
    found = [t for t, ty in types.items()
             if t.endswith("/" + fusion_log.TOPIC) and ty == "std_msgs/msg/Int64MultiArray"]
    return found[0] if len(found) == 1 else None


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
    log_topic = find_log_topic(types)
    log = None
    if log_topic is not None:
        chunks = [fusion_log.rows_of(m.msg) for m in bag_io.iter_messages(bag, [log_topic])]
        log = np.concatenate(chunks) if chunks else None
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
    return ReplayInput(tuple(events), stamps, _input_key(config), static, log,
                       types.get(CONTROL_TOPIC) != "geometry_msgs/msg/Twist")


def replay(bag: Path | str | ReplayInput, settings: EkfNodeSettings, output_stamps: str = "recorded",
           output_topic: str = OUTPUT_TOPIC, ties: str = "inputs_first",
           innovation_listener: Callable[[Innovation], None] | None = None,
           follow_log: bool = True) -> ReplayResult:
    """Feed the bag through a Localizer as ekf_node did with ``settings``; collect estimates.

    With ``output_stamps`` "recorded" and ``follow_log``, a bag with ekf_node's fusion log is
    replayed as the log says (:func:`replay_log`); otherwise in the recorder's receive order:

    ``bag``: a bag path, or a :class:`ReplayInput` read from one (to replay it many times).
    ``output_stamps``: "recorded" = at the header stamps of the ``output_topic`` messages in
    the bag, each taken when the bag's clock (receive times) reaches it, as the node's timer
    did (falls back to "grid" if there are none); "grid" = every 1/frequency (the settings') of
    bag time.
    ``ties``: an input received in the same clock tick as an output is fused before
    ("inputs_first") or after ("outputs_first") that output; the online node's executor may
    have done either. ``innovation_listener`` receives every update's innovation.
    """
    if ties not in ("inputs_first", "outputs_first"):
        raise ValueError(f"ties must be 'inputs_first' or 'outputs_first', got {ties!r}")
    config = settings.config
    source = bag if isinstance(bag, ReplayInput) else read_replay_input(bag, config, output_topic)
    if source.key != _input_key(config):
        raise ValueError("the ReplayInput was read for other inputs or another use_control")
    loc = make_localizer(config)
    loc.innovation_listener = innovation_listener
    res = ReplayResult(localizer=loc)
    if output_stamps == "recorded" and follow_log and source.log is not None:
        return replay_log(source, loc, res)
    if output_stamps == "recorded" and not source.recorded_stamps:
        output_stamps = "grid"
    stamps = source.recorded_stamps if output_stamps == "recorded" else ()
    # /tf_static holds for all time (as in tf2): loaded before the first message; /tf in receive order
    for msg in source.static_transforms:
        feed_transforms(loc.transforms, msg, static=True)
    period = settings.publish_period_ns
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


def replay_log(source: ReplayInput, loc: Localizer, res: ReplayResult) -> ReplayResult:
    """Follow ekf_node's fusion log: each row's message (found in the bag by its input and
    header stamp) given to ``loc`` with the node's receive time, in the node's order, and the
    estimate taken where the node published one (``advance_to`` at its clock, as its timer).
    Rows of inputs ``loc`` does not fuse are skipped; /tf is fed in the recorder's order."""
    t0 = time.perf_counter()
    res.followed_log = True
    inputs = {inp.name for inp in loc.config.inputs} | ({CONTROL_SOURCE} if loc.config.use_control else set())
    names = fusion_log.decode_names(inputs)
    waiting: dict[tuple[str, int], deque] = defaultdict(deque)  # (input, stamp) -> its messages
    unstamped: deque = deque()  # cmd_vel as Twist: stamped on receipt, so taken in order
    tf = deque()
    for now, name, item in source.events:
        if name == TF_TOPIC:
            tf.append((now, item))
        elif name == CONTROL_TOPIC and not source.control_stamped:
            unstamped.append(item)
        elif item is not None:  # an unreadable message was not fused
            waiting[(CONTROL_SOURCE if name == CONTROL_TOPIC else name, item.stamp_ns)].append(item)
    for now, stamp, code in source.log.tolist():
        clock = None if now == fusion_log.NO_CLOCK else now
        while tf and clock is not None and tf[0][0] <= clock:
            feed_transforms(loc.transforms, tf.popleft()[1], static=False)
        if code == fusion_log.OUTPUT:
            est = loc.advance_to(now)
            if est is not None and est.is_finite():
                res.estimates.append(est)
            continue
        if code == fusion_log.RESET:
            loc.reset("reset service called")
            continue
        name = names.get(code)
        if name is None:
            continue
        if name == CONTROL_SOURCE and not source.control_stamped:
            found = unstamped.popleft() if unstamped else None
            item = None if found is None else ControlCommand(stamp_ns=stamp, twist=found.twist)
        else:
            queue = waiting.get((name, stamp))
            item = queue.popleft() if queue else None
        if item is None:
            res.missing += 1
            continue
        res.messages += 1
        if name == CONTROL_SOURCE:
            loc.add_control(item, clock)
        else:
            loc.add_measurement(name, item, clock)
    res.seconds = time.perf_counter() - t0
    return res
