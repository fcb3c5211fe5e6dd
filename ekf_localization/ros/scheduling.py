"""Real-time scheduling for a node's process (Linux): ``thread_priority``, as ros2_control's
controller_manager names it and sets it (SCHED_FIFO 50 by default).

On a loaded computer the kernel shares the cores fairly, so any busy process can hold a node
off the CPU for 100-400 ms at a time (benchmarks/soak_dds.py at real-time factor 2 with two CPU
hogs: ekf_node ran 5 ms of CPU in a 0.2 s output gap). A SCHED_FIFO thread runs whenever it is
ready, ahead of every normal process. Every thread of the process is moved, the DDS threads
that receive the messages as well as the executor's; threads started later inherit it.

Setting it needs CAP_SYS_NICE or an ``rtprio`` limit (``@realtime - rtprio 99`` in
/etc/security/limits.conf; ``docker run --cap-add=sys_nice --ulimit rtprio=99``). Without
either, the process keeps its normal priority and the caller says so.
"""

from __future__ import annotations

import os

FIFO_PRIORITIES = range(0, 100)  # 0: the default scheduling; 1-99 SCHED_FIFO
HOW_TO_ALLOW = ("allow it with an rtprio limit (/etc/security/limits.conf: '@realtime - rtprio 99', the "
                "user in group realtime) or CAP_SYS_NICE (docker: --cap-add=sys_nice --ulimit rtprio=99)")


def thread_ids(pid: int | None = None) -> list[int]:
    """The threads of process ``pid`` (this one when None)."""
    task = f"/proc/{'self' if pid is None else pid}/task"
    try:
        return sorted(int(t) for t in os.listdir(task))
    except OSError:  # no /proc: the calling thread only
        return [0] if pid is None else [pid]


def use_fifo(priority: int, pid: int | None = None) -> str | None:
    """Put every thread of process ``pid`` (this one when None) under SCHED_FIFO at ``priority``
    (1-99; 0 changes nothing). Returns None when done, else why not (the process is unchanged
    when the first thread is refused)."""
    if priority == 0:
        return None
    if not hasattr(os, "sched_setscheduler"):
        return "SCHED_FIFO is not available on this system"
    param = os.sched_param(priority)
    for tid in thread_ids(pid):
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, param)
        except ProcessLookupError:  # a thread that has ended meanwhile
            continue
        except OSError as exc:
            return f"SCHED_FIFO {priority} refused ({exc.strerror or exc})"
    return None

