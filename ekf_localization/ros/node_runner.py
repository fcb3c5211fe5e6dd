"""The one way every node process starts and stops (used by each node's ``main``)."""

from __future__ import annotations

import sys
from collections.abc import Callable

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.logging import get_logger
from rclpy.node import Node


def run_node(name: str, make_node: Callable[[], Node],
             config_errors: tuple[type[Exception], ...],
             spin: Callable[[SingleThreadedExecutor, Node], None] | None = None,
             args: list[str] | None = None) -> int:
    """Init rclpy, build the node, spin it on a SingleThreadedExecutor until Ctrl-C or shutdown.

    A bad parameter (one of ``config_errors``, whose message names the parameter and the
    expected form) is logged and printed and gives exit status 2; otherwise 0. ``spin``
    replaces ``executor.spin()`` for a node with its own loop.
    """
    rclpy.init(args=sys.argv if args is None else args)
    node: Node | None = None
    executor: SingleThreadedExecutor | None = None
    try:
        try:
            node = make_node()
        except config_errors as exc:
            get_logger(name).fatal(str(exc))
            print(f"{name}: {exc}", file=sys.stderr, flush=True)
            return 2
        executor = SingleThreadedExecutor()  # the multi-threaded one drops messages at 1 kHz
        executor.add_node(node)
        if spin is None:
            executor.spin()
        else:
            spin(executor, node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
