"""Each job plans in a child process the worker can kill: cancel, shutdown, memory limit.

The planner's long stages (reading and remeshing, candidate generation, Embree) run in C and
do not look at a cancel flag, and a Python thread cannot be stopped. So the worker forks a
child per job and only waits on a pipe itself: on a DELETE, a shutdown or a lost claim it
sends the child SIGKILL, which frees its memory at once, whatever stage it is in. The child
runs under ``RLIMIT_AS`` (the worker is not limited), so a plan that outgrows its share gets a
``MemoryError`` (or dies) and fails as "out of memory" while the worker lives on.

The child never touches the database or the queue: it sends ``(stage, fraction)`` progress
messages and one final message over the pipe; the worker does all the bookkeeping.

``os.fork`` rather than ``multiprocessing``: huey's worker processes are daemonic, and
multiprocessing refuses to start children of a daemonic process.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import resource
import signal
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection, Pipe
from typing import Any

log = logging.getLogger("scanplan.worker")

# progress(stage, fraction 0..1): the child's side never cancels (the worker kills it)
Progress = Callable[[str, float], bool]
# the work done in the child: gets the progress callback, returns picklable data
Work = Callable[[Progress], Any]

_PR_SET_PDEATHSIG = 1
# least time between two progress messages of the same stage from the child
_PROGRESS_EVERY_S = 0.1


class PlanProcessError(Exception):
    """The child ended without a result: out of memory, or killed by a signal."""

    def __init__(self, message: str, *, out_of_memory: bool) -> None:
        super().__init__(message)
        self.out_of_memory = out_of_memory


class ChildFailedError(Exception):
    """The work raised in the child; carries the problem document made there."""

    def __init__(self, problem: dict[str, Any], message: str) -> None:
        super().__init__(message)
        self.problem = problem


class StoppedError(Exception):
    """The worker killed the child because ``should_stop`` said so."""


@dataclass
class ChildLimits:
    """What the child may use. ``memory_bytes`` None: no limit.

    ``nice``: added to the child's CPU niceness, so that planning takes the CPU the API and
    the workers' own bookkeeping (heartbeats, cancel checks, shutdown) leave idle.
    """

    memory_bytes: int | None
    nice: int = 0


def run_in_child(work: Work, *, limits: ChildLimits,
                 on_progress: Callable[[str, float], bool],
                 should_stop: Callable[[], bool], poll_interval_s: float,
                 describe_error: Callable[[BaseException], dict[str, Any]]) -> Any:
    """Run ``work`` in a forked child and return its result.

    Parameters
    ----------
    on_progress : called in this process for each progress message; True stops the child
    should_stop : called every ``poll_interval_s``; True stops the child
    describe_error : the problem document of an exception raised by ``work`` (in the child)

    Raises
    ------
    StoppedError : ``on_progress`` or ``should_stop`` asked to stop; the child is gone
    ChildFailedError : ``work`` raised; ``problem`` is ``describe_error`` of it
    PlanProcessError : the child ran out of memory or died without a result
    KeyboardInterrupt : (the worker is being stopped) after the child was killed
    """
    receiver, sender = Pipe(duplex=False)
    parent_pid = os.getpid()
    pid = os.fork()
    if pid == 0:  # the child: never returns
        receiver.close()
        _child_main(work, sender, parent_pid, limits, describe_error)
    sender.close()
    try:
        return _wait_for_child(pid, receiver, limits, on_progress, should_stop,
                               poll_interval_s)
    finally:
        _kill(pid)
        receiver.close()


def _wait_for_child(pid: int, receiver: Connection, limits: ChildLimits,
                    on_progress: Callable[[str, float], bool],
                    should_stop: Callable[[], bool], poll_interval_s: float) -> Any:
    next_check = time.monotonic() + poll_interval_s
    while True:
        if receiver.poll(poll_interval_s):
            try:
                kind, *payload = receiver.recv()
            except EOFError:  # the child died before its final message
                raise _death(pid, limits) from None
            if kind == "progress":
                if on_progress(payload[0], payload[1]):
                    raise StoppedError("cancelled while running")
            elif kind == "result":
                return payload[0]
            elif kind == "error":
                raise ChildFailedError(payload[0], payload[1])
            elif kind == "out-of-memory":
                raise PlanProcessError(_oom_message(limits, payload[0]), out_of_memory=True)
        if time.monotonic() >= next_check:
            if should_stop():
                raise StoppedError("cancelled while running")
            next_check = time.monotonic() + poll_interval_s


def _death(pid: int, limits: ChildLimits) -> PlanProcessError:
    """Why the child ended without a message (reaps it)."""
    _, status = os.waitpid(pid, 0)
    if os.WIFSIGNALED(status):
        name = signal.Signals(os.WTERMSIG(status)).name
        if limits.memory_bytes is not None or os.WTERMSIG(status) == signal.SIGKILL:
            # SIGKILL is the kernel's OOM killer; SIGSEGV/SIGABRT are how C++ allocators
            # (Embree) fail when the address-space limit refuses them memory
            return PlanProcessError(_oom_message(limits, f"the planning process died ({name})"),
                                    out_of_memory=True)
        return PlanProcessError(f"the planning process died ({name})", out_of_memory=False)
    return PlanProcessError(f"the planning process exited with status "
                            f"{os.WEXITSTATUS(status)} without a result", out_of_memory=False)


def _oom_message(limits: ChildLimits, what: str) -> str:
    limit = ("" if limits.memory_bytes is None
             else f" of {limits.memory_bytes / 2**20:.0f} MiB (SCANPLAN_JOB_MEMORY_LIMIT_MB)")
    return (f"out of memory: the plan needs more than the worker's memory limit{limit} "
            f"({what}); use a larger max_edge_m or grid_spacing_m, fewer candidates, or a "
            "smaller model")


def _kill(pid: int) -> None:
    """SIGKILL and reap the child (a no-op when it was reaped already)."""
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)
    with contextlib.suppress(ChildProcessError):
        os.waitpid(pid, 0)


def _child_main(work: Work, sender: Connection, parent_pid: int, limits: ChildLimits,
                describe_error: Callable[[BaseException], dict[str, Any]]) -> None:
    """The child's whole life; leaves with ``os._exit`` (no atexit of the worker runs)."""
    code = 0
    try:
        _die_with_parent(parent_pid)
        # huey's handlers would turn SIGTERM into KeyboardInterrupt inside the plan
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        if limits.nice:
            os.nice(limits.nice)
        if limits.memory_bytes is not None:
            resource.setrlimit(resource.RLIMIT_AS, (limits.memory_bytes, limits.memory_bytes))
        last: dict[str, float] = {}

        def progress(stage: str, fraction: float) -> bool:
            now = time.monotonic()
            if fraction >= 1.0 or now - last.get(stage, -1e9) >= _PROGRESS_EVERY_S:
                last[stage] = now
                sender.send(("progress", stage, fraction))
            return False

        try:
            result = work(progress)
        except MemoryError:
            sender.send(("out-of-memory", "a MemoryError in the planner"))
        except Exception as exc:
            log.debug("plan failed in the child:\n%s", traceback.format_exc())
            sender.send(("error", describe_error(exc), str(exc)))
        else:
            sender.send(("result", result))
    except BaseException:  # nothing may escape into the worker's code in the child
        code = 1
    finally:
        os._exit(code)


def _die_with_parent(parent_pid: int) -> None:
    """SIGKILL this child when the worker dies, even by SIGKILL (Linux prctl PDEATHSIG)."""
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent_pid:  # the worker died before prctl took effect
        os._exit(1)

