"""HiGHS in a child process that can be stopped: the time limit holds whatever HiGHS does.

HiGHS checks its ``time_limit`` between steps, and some steps (presolve on a large program)
run long without checking. The parent therefore sends each program to a child process and
waits only until its own deadline; a child that has not answered by then is killed and the
caller gets ``None``. One child serves many programs (imports are paid once).

Protocol on the child's stdin/stdout: 8-byte little-endian length + pickle, both ways.
The child runs :func:`main` of this module (imported, so pickled classes resolve).
"""

from __future__ import annotations

import math
import os
import pickle
import select
import signal
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import IO, Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

_HEADER = struct.Struct("<Q")
# HiGHS checks its own time limit only between steps (an LP iteration on a large program can
# take seconds), so it is asked to stop this share of the time early, and at least
# ANSWER_MARGIN_S early; the parent kills it at the deadline proper.
ANSWER_SHARE = 0.85
ANSWER_MARGIN_S = 0.4
# how often the parent looks at its tick (progress, cancellation) while HiGHS works
POLL_S = 0.5


@dataclass(frozen=True)
class Program:
    """``min cost @ v`` subject to ``row_lower <= rows @ v <= row_upper``, bounds, integrality.

    Arrays: cost, integrality, lower, upper (V,); rows (R, V) CSR; row_lower, row_upper (R,).
    """

    cost: NDArray[np.float64]
    integrality: NDArray[np.float64]
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]
    rows: sp.csr_matrix
    row_lower: NDArray[np.float64]
    row_upper: NDArray[np.float64]
    start: NDArray[np.float64] | None = None  # (V,) a feasible solution to start from
    # branch-and-bound nodes HiGHS may explore (work, the same on any machine); None: no limit
    node_limit: int | None = None


@dataclass(frozen=True)
class Answer:
    """What HiGHS returned: ``x`` None when it found no solution; ``dual_bound`` on the cost."""

    status: int  # 0 optimal, 1 time limit, 2 infeasible, 3 anything else
    x: NDArray[np.float64] | None
    cost: float | None
    dual_bound: float | None
    message: str


def solve(program: Program, time_limit_s: float) -> Answer:
    """Run HiGHS (highspy) on ``program`` in this process, from ``program.start`` if given."""
    import highspy

    highs = highspy.Highs()  # type: ignore[no-untyped-call]
    highs.setOptionValue("output_flag", False)
    highs.setOptionValue("time_limit", max(float(time_limit_s), 0.01))
    if program.node_limit is not None:
        highs.setOptionValue("mip_max_nodes", int(program.node_limit))
    rows = program.rows
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = len(program.cost), rows.shape[0]
    lp.col_cost_, lp.col_lower_, lp.col_upper_ = program.cost, program.lower, program.upper
    lp.row_lower_, lp.row_upper_ = program.row_lower, program.row_upper
    lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
    lp.a_matrix_.num_col_, lp.a_matrix_.num_row_ = lp.num_col_, lp.num_row_
    lp.a_matrix_.start_ = rows.indptr.astype(np.int32)
    lp.a_matrix_.index_ = rows.indices.astype(np.int32)
    lp.a_matrix_.value_ = rows.data.astype(np.float64)
    lp.integrality_ = [highspy.HighsVarType.kInteger if i else highspy.HighsVarType.kContinuous
                       for i in program.integrality]
    highs.passModel(lp)
    if program.start is not None:  # a MIP start: HiGHS begins from this incumbent
        start = highspy.HighsSolution()
        start.col_value = list(program.start)
        start.value_valid = True
        highs.setSolution(start)
    highs.run()
    model_status = highs.getModelStatus()
    info = highs.getInfo()
    kinds = highspy.HighsModelStatus
    status = {kinds.kOptimal: 0, kinds.kTimeLimit: 1, kinds.kInterrupt: 1,
              kinds.kInfeasible: 2}.get(model_status, 3)
    has_solution = info.primal_solution_status == highspy.SolutionStatus.kSolutionStatusFeasible
    bound = float(info.mip_dual_bound) if status != 2 else math.inf
    return Answer(
        status=status,
        x=np.asarray(highs.getSolution().col_value, np.float64) if has_solution else None,
        cost=float(info.objective_function_value) if has_solution else None,
        dual_bound=bound if np.isfinite(bound) else None,
        message=highs.modelStatusToString(model_status),
    )


class HighsProcess:
    """A child process running :func:`solve`; killed when an answer is late. Use ``with``.

    ``tick`` is called about every POLL_S seconds while HiGHS works; it may raise (a
    cancelled plan), and the child is then killed on the way out of ``with``.
    """

    def __init__(self, tick: Callable[[], None] | None = None) -> None:
        self._child: subprocess.Popen[bytes] | None = None
        self._tick = tick

    def start(self) -> None:
        """Start the child now (it imports scipy while the caller does other work)."""
        if self._child is None or self._child.poll() is not None:
            self._child = subprocess.Popen(
                [sys.executable, "-c",
                 f"from planner.selection.highs_worker import main; main({os.getpid()})"],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
            )

    def solve(self, program: Program, deadline: float) -> Answer | None:
        """HiGHS's answer, or None when the child did not answer by ``deadline``
        (``time.monotonic()`` seconds); the child is then killed."""
        self.start()
        child = self._child
        assert child is not None and child.stdin is not None and child.stdout is not None
        left_s = deadline - time.monotonic()
        limit_s = min(left_s * ANSWER_SHARE, left_s - ANSWER_MARGIN_S)
        if limit_s <= 0.05:
            return None
        try:
            _send(child.stdin, (program, limit_s))
            reply = _receive(child.stdout, deadline, self._tick)
        except (BrokenPipeError, EOFError, TimeoutError):
            self.close()
            return None
        assert isinstance(reply, Answer)
        return reply

    def close(self) -> None:
        if self._child is not None:
            if self._child.poll() is None:
                self._child.kill()
            self._child.wait()
            for stream in (self._child.stdin, self._child.stdout):
                if stream is not None:
                    stream.close()
            self._child = None

    def __enter__(self) -> HighsProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _send(stream: IO[bytes], message: Any) -> None:
    """``message`` pickled with its arrays out of band (pickle protocol 5): their memory
    is written as it is after the pickle, so a program's rows are never copied into it
    (NiedriHa's exact program: 17 MiB less at the peak of sending it)."""
    buffers: list[pickle.PickleBuffer] = []
    data = pickle.dumps(message, protocol=5, buffer_callback=buffers.append)
    views = [buffer.raw() for buffer in buffers]
    stream.write(_HEADER.pack(len(data)) + _HEADER.pack(len(views))
                 + b"".join(_HEADER.pack(view.nbytes) for view in views))
    stream.write(data)
    for view in views:
        stream.write(view)
    stream.flush()


def _read_exactly(stream: IO[bytes], size: int, deadline: float | None,
                  tick: Callable[[], None] | None = None) -> bytearray:
    """``size`` bytes of ``stream``, read into one buffer (no chunks joined)."""
    out = bytearray(size)
    view = memoryview(out)
    fd = stream.fileno()
    done = 0
    while done < size:
        if deadline is not None:
            while True:
                left_s = deadline - time.monotonic()
                if left_s <= 0:
                    raise TimeoutError("HiGHS did not answer in time")
                if select.select([fd], [], [], min(left_s, POLL_S))[0]:
                    break
                if tick is not None:
                    tick()
        got = os.readv(fd, [view[done:done + min(size - done, 1 << 20)]])
        if not got:
            raise EOFError("the HiGHS process ended")
        done += got
    return out


def _receive(stream: IO[bytes], deadline: float | None,
             tick: Callable[[], None] | None = None) -> Any:
    (size,) = _HEADER.unpack(_read_exactly(stream, _HEADER.size, deadline, tick))
    (n_buffers,) = _HEADER.unpack(_read_exactly(stream, _HEADER.size, deadline))
    sizes = [n for (n,) in _HEADER.iter_unpack(
        _read_exactly(stream, n_buffers * _HEADER.size, deadline))]
    data = _read_exactly(stream, size, deadline)
    buffers = [_read_exactly(stream, n, deadline) for n in sizes]
    return pickle.loads(data, buffers=buffers)  # our own child's bytes


def _die_with_parent(parent_pid: int) -> None:
    """SIGKILL this child when the planning process dies, even by SIGKILL (Linux prctl
    PDEATHSIG): a cancelled job must not leave HiGHS solving until its time limit."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return  # not Linux: the closed stdin pipe still ends the child after its solve
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)


def main(parent_pid: int | None = None) -> None:
    """The child: answer programs until stdin closes."""
    if parent_pid is not None:
        _die_with_parent(parent_pid)
    replies = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything HiGHS prints goes to stderr, not into the protocol
    requests = sys.stdin.buffer
    while True:
        try:
            program, limit_s = _receive(requests, None)
        except EOFError:
            return
        _send(replies, solve(program, limit_s))
