"""The one way every node process starts and stops (used by each node's ``main``)."""

from __future__ import annotations

import gc
import os
import signal
import sys
import threading
from collections.abc import Callable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.service import Service
from rclpy.signals import SignalHandlerOptions

from ekf_localization.ros.parameters import ParameterError
from ekf_localization.ros.params_file import ros_args_problem
from ekf_localization.ros.params_match import node_fqn, unmatched_params_files

EXECUTOR_ENV = "EKF_LOCALIZATION_EXECUTOR"  # "single" (SingleThreadedExecutor) or "events"
EXECUTORS = ("single", "events")
# events: the single-threaded executor loses input at 1 kHz (compare with EKF_LOCALIZATION_EXECUTOR=single
# python benchmarks/bench_ekf_node.py --odom-rate 1000); the events executor's sim-time timers: ros/due_timer
DEFAULT_EXECUTOR = "events"


def make_executor(name: str | None = None) -> Executor:
    """The executor every node spins on: ``name`` (default: $EKF_LOCALIZATION_EXECUTOR, else
    DEFAULT_EXECUTOR) is "single" (rclpy's SingleThreadedExecutor) or "events"
    (rclpy.experimental.EventsExecutor). Never the multi-threaded one (it drops messages at 1 kHz)."""
    name = name or os.environ.get(EXECUTOR_ENV) or DEFAULT_EXECUTOR
    if name == "single":
        return SingleThreadedExecutor()
    if name == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    raise ValueError(f"{EXECUTOR_ENV} must be one of {', '.join(EXECUTORS)}, got {name!r}")


_STOP = threading.Event()  # set by SIGINT / SIGTERM (init_rclpy's handlers)
STOP_POLL_S = 0.1  # how long one spin step may wait: a signal is seen within this


def init_rclpy(argv: list[str]) -> None:
    """``rclpy.init`` without rclpy's signal handlers, and SIGINT / SIGTERM that ask the spin
    loop to stop. rclpy's handlers shut the context down at once, under a running callback,
    whose next publish then raises (the EventsExecutor logs it as FATAL); here the loop ends
    between callbacks and the node is taken down after it."""
    _STOP.clear()
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda _signum, _frame: _STOP.set())


def running(executor: Executor) -> bool:
    """False once a stop signal came or the context was shut down."""
    return not _STOP.is_set() and executor.context.ok()


def serve_pending(service: Service) -> int:
    """Answer the requests waiting on ``service`` now, as rclpy's executors do; how many."""
    served = 0
    while True:
        with service.handle:
            request, header = service.handle.service_take_request(service.srv_type.Request)
        if header is None:
            return served
        service.send_response(service.callback(request, service.srv_type.Response()), header)
        served += 1


def spin_forever(executor: Executor, urgent: tuple[Service, ...] = ()) -> None:
    """Spin in steps of at most STOP_POLL_S until a stop signal or shutdown. (rclpy 7.1's
    EventsExecutor.spin() delivers only the first message from another process; its spin_once
    delivers every one.)

    The ``urgent`` services are answered before each step. The EventsExecutor runs its events
    in arrival order, one per message: in a burst a request waits behind every message that
    came before it (seconds at 10 kHz), and a spin step runs one of them."""
    while running(executor):
        for service in urgent:
            serve_pending(service)
        executor.spin_once(timeout_sec=STOP_POLL_S)


def run_node(name: str, make_node: Callable[[], Node],
             spin: Callable[[Executor, Node], None] | None = None,
             args: list[str] | None = None, empty_lists: bool = False) -> int:
    """Init rclpy, build the node, spin it on :func:`make_executor`'s executor until Ctrl-C or shutdown.

    Bad parameters (a :class:`ParameterError`, whose message names each of them and the
    expected form: one line for one problem, a line per problem for several), or
    ``--ros-args`` rcl cannot read (:mod:`ekf_localization.ros.params_file`), are printed on
    stderr without a traceback and give exit status 2; otherwise 0. ``spin`` replaces
    ``executor.spin()`` for a node with its own loop. ``empty_lists``: a ``[]`` in the node's
    parameters is fine (rcl passes it as "not set").
    """
    argv = sys.argv if args is None else args
    problem = ros_args_problem(argv, empty_lists)  # rcl's own parse errors raise inside rclpy.init
    if problem is None:
        try:
            init_rclpy(argv)
        except Exception as exc:  # rcl's RCLError: whatever else it refuses, in one line
            problem = " ".join(str(exc).split())
    if problem is not None:
        print(f"{name}: {problem}", file=sys.stderr, flush=True)
        return 2
    fqn = node_fqn(name, argv)  # a params file keyed for another namespace applies nothing: say so
    for message in unmatched_params_files(fqn, argv):
        get_logger(fqn.strip("/").replace("/", ".")).warning(message)
    node: Node | None = None
    executor: Executor | None = None
    try:
        try:
            executor = make_executor()
        except ValueError as exc:
            print(f"{name}: {exc}", file=sys.stderr, flush=True)
            return 2
        try:
            node = make_node()
        except ParameterError as exc:
            print(f"{name}: {exc}", file=sys.stderr, flush=True)
            return 2
        executor.add_node(node)
        # A full garbage collection scans every object start-up left (up to ~10^5: numpy, rclpy,
        # the message classes), up to ~100 ms here, during which no message is taken (a 1 kHz input's
        # 100-deep queue covers 100 ms). gc.freeze() moves them to a generation never collected;
        # what the node allocates while it runs is collected as before.
        gc.collect()
        gc.freeze()
        if spin is None:  # a node's urgent_services: answered ahead of queued messages
            spin_forever(executor, tuple(getattr(node, "urgent_services", ())))
        else:
            spin(executor, node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:  # noqa: BLE001 - re-raised unless it is a callback racing Ctrl-C
        if rclpy.ok():
            raise
        # the context was shut down (Ctrl-C) while a callback was publishing: rcl then raises
        # "publisher's context is invalid" from that publish; this is a normal stop
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
