"""Each job plans in a child process the worker can kill: cancel, shutdown, memory limit.

The planner's long stages (reading and remeshing, candidate generation, Embree) run in C and
do not look at a cancel flag, and a Python thread cannot be stopped. So the worker forks a
child per job and only waits on a pipe itself: on a DELETE, a shutdown or a lost claim it
sends the child SIGKILL, which frees its memory at once, whatever stage it is in. The child
runs under ``RLIMIT_AS`` (the worker is not limited), so a plan that outgrows its share gets a
``MemoryError`` (or dies) and fails as "out of memory" while the worker lives on.

A child that ends without a result is told apart by its exit status and its peak memory
(``wait4``'s ``ru_maxrss``, and the address space last read from ``/proc``): a
``MemoryError``, or a death with a peak near the limit, is out of memory (a re-run would
end the same); a signal with the peak far below the limit came from outside (an operator,
the container runtime, the host's OOM killer when the machine ran short), and a re-run can
succeed. :class:`ChildEnd` carries the figures the worker records of the attempt.

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
from pathlib import Path
from typing import Any

log = logging.getLogger("scanplan.worker")

# progress(stage, fraction 0..1): the child's side never cancels (the worker kills it)
Progress = Callable[[str, float], bool]
# the work done in the child: gets the progress callback, returns picklable data
Work = Callable[[Progress], Any]

_PR_SET_PDEATHSIG = 1
# least time between two progress messages of the same stage from the child
_PROGRESS_EVERY_S = 0.1


# a death counts as out of memory when the child's peak reached this share of its limit:
# RLIMIT_AS refuses the allocation that would cross it, and C++ code (Embree) then ends
# with SIGABRT or SIGSEGV instead of a MemoryError
NEAR_LIMIT_SHARE = 0.9
_MIB = 2**20


@dataclass(frozen=True)
class ChildEnd:
    """How a child ended without a result: the figures of one attempt.

    ``peak_rss_mib``: resident peak (``wait4`` ``ru_maxrss``); ``peak_address_space_mib``:
    VmPeak as last read while it ran (None when never read); ``signal``: e.g. ``SIGKILL``,
    None when it exited; ``stage``: the last stage it reported.
    """

    out_of_memory: bool
    stage: str | None
    signal: str | None
    exit_code: int | None
    peak_rss_mib: float | None
    peak_address_space_mib: float | None
    memory_limit_mib: float | None

    @property
    def killed(self) -> bool:
        """Ended by a signal far below its memory limit: from outside; a re-run can succeed."""
        return self.signal is not None and not self.out_of_memory

    def figures(self) -> str:
        """Words for a message: stage, peak resident and (when read) address space."""
        parts = [f"stage {self.stage or 'starting'}"]
        if self.peak_rss_mib is not None:
            peak = f"peak {self.peak_rss_mib:,.0f} MiB resident"
            if self.peak_address_space_mib is not None:
                peak += f" ({self.peak_address_space_mib:,.0f} MiB address space)"
            parts.append(peak)
        return ", ".join(parts)


class PlanProcessError(Exception):
    """The child ended without a result: out of memory, killed by a signal, or exited."""

    def __init__(self, message: str, end: ChildEnd) -> None:
        super().__init__(message)
        self.end = end

    @property
    def out_of_memory(self) -> bool:
        return self.end.out_of_memory


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
                 describe_error: Callable[[BaseException], dict[str, Any]],
                 measured: dict[str, float] | None = None) -> Any:
    """Run ``work`` in a forked child and return its result.

    Parameters
    ----------
    on_progress : called in this process for each progress message; True stops the child
    should_stop : called every ``poll_interval_s``; True stops the child
    describe_error : the problem document of an exception raised by ``work`` (in the child)
    measured : when given, receives the child's ``peak_rss_mib`` (and
        ``peak_address_space_mib`` when read) once it is gone, whatever the outcome

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
    child = _Child(pid, limits)
    try:
        return _wait_for_child(child, receiver, on_progress, should_stop, poll_interval_s)
    finally:
        if not child.reaped:  # SIGKILL (it may be exiting by itself already) and reap
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError):
                child.reap()
        receiver.close()
        if measured is not None and child.peak_rss_mib is not None:
            measured["peak_rss_mib"] = round(child.peak_rss_mib, 1)
            if child.address_space_mib is not None:
                measured["peak_address_space_mib"] = round(child.address_space_mib, 1)


@dataclass
class _Child:
    """The worker's view of a running child: last stage, address space, reaped or not."""

    pid: int
    limits: ChildLimits
    stage: str | None = None
    address_space_mib: float | None = None
    peak_rss_mib: float | None = None  # once reaped
    reaped: bool = False

    def sample(self) -> None:
        """Read the child's peak address space (VmPeak) from /proc."""
        with contextlib.suppress(OSError, ValueError):
            for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
                if line.startswith("VmPeak:"):
                    self.address_space_mib = int(line.split()[1]) / 1024
                    return

    def reap(self) -> tuple[int, float]:
        """Wait for the child's end: its wait status and resident peak in MiB."""
        _, status, usage = os.wait4(self.pid, 0)
        self.reaped = True
        self.peak_rss_mib = usage.ru_maxrss / 1024  # Linux: ru_maxrss in KiB
        return status, self.peak_rss_mib

    def end(self, *, signal_name: str | None, exit_code: int | None, peak_rss_mib: float,
            out_of_memory: bool | None = None) -> ChildEnd:
        limit = self.limits.memory_bytes
        limit_mib = None if limit is None else limit / _MIB
        if out_of_memory is None:  # a death: out of memory when the peak neared the limit
            peak = max(peak_rss_mib, self.address_space_mib or 0.0)
            out_of_memory = limit_mib is not None and peak >= NEAR_LIMIT_SHARE * limit_mib
        return ChildEnd(out_of_memory=out_of_memory, stage=self.stage, signal=signal_name,
                        exit_code=exit_code, peak_rss_mib=round(peak_rss_mib, 1),
                        peak_address_space_mib=None if self.address_space_mib is None
                        else round(self.address_space_mib, 1),
                        memory_limit_mib=None if limit_mib is None else round(limit_mib, 1))


def _wait_for_child(child: _Child, receiver: Connection,
                    on_progress: Callable[[str, float], bool],
                    should_stop: Callable[[], bool], poll_interval_s: float) -> Any:
    next_check = time.monotonic() + poll_interval_s
    child.sample()
    while True:
        if receiver.poll(poll_interval_s):
            try:
                kind, *payload = receiver.recv()
            except EOFError:  # the child died before its final message
                raise _death(child) from None
            if kind == "progress":
                child.stage = payload[0]
                if on_progress(payload[0], payload[1]):
                    raise StoppedError("cancelled while running")
            elif kind == "result":
                return payload[0]
            elif kind == "error":
                raise ChildFailedError(payload[0], payload[1])
            elif kind == "out-of-memory":
                child.sample()
                _, peak_rss_mib = child.reap()  # it exits right after this message
                end = child.end(signal_name=None, exit_code=0, peak_rss_mib=peak_rss_mib,
                                out_of_memory=True)
                raise PlanProcessError(_oom_message(end, payload[0]), end)
        if time.monotonic() >= next_check:
            child.sample()
            if should_stop():
                raise StoppedError("cancelled while running")
            next_check = time.monotonic() + poll_interval_s


def _death(child: _Child) -> PlanProcessError:
    """Why the child ended without a message (reaps it): out of memory, killed, or exited."""
    status, peak_rss_mib = child.reap()
    if os.WIFSIGNALED(status):
        name = signal.Signals(os.WTERMSIG(status)).name
        end = child.end(signal_name=name, exit_code=None, peak_rss_mib=peak_rss_mib)
        if end.out_of_memory:
            return PlanProcessError(_oom_message(end, f"the planning process died ({name})"),
                                    end)
        limit = ("" if end.memory_limit_mib is None
                 else f", far below the memory limit of {end.memory_limit_mib:,.0f} MiB")
        return PlanProcessError(
            f"the planning process was ended by {name} ({end.figures()}{limit}): stopped "
            "from outside the service (an operator, the container runtime, or the host's "
            "OOM killer when the machine ran short of memory)", end)
    code = os.WEXITSTATUS(status)
    end = child.end(signal_name=None, exit_code=code, peak_rss_mib=peak_rss_mib,
                    out_of_memory=False)
    return PlanProcessError(f"the planning process exited with status {code} without a "
                            f"result ({end.figures()})", end)


def _oom_message(end: ChildEnd, what: str) -> str:
    limit = ("" if end.memory_limit_mib is None
             else f" of {end.memory_limit_mib:,.0f} MiB (SCANPLAN_JOB_MEMORY_LIMIT_MB)")
    return (f"out of memory: the plan needs more than the worker's memory limit{limit} "
            f"({what} in {end.figures()}); use a larger max_edge_m or grid_spacing_m, fewer "
            "candidates, or a smaller model")


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

