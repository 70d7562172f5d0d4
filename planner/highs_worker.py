"""HiGHS in a child process that can be stopped: the time limit holds whatever HiGHS does.

HiGHS checks its ``time_limit`` between steps, and some steps (presolve on a large program)
run long without checking. The parent therefore sends each program to a child process and
waits only until its own deadline; a child that has not answered by then is killed and the
caller gets ``None``. One child serves many programs (imports are paid once).

Protocol on the child's stdin/stdout: 8-byte little-endian length + pickle, both ways.
The child runs :func:`main` of this module (imported, so pickled classes resolve).
"""

from __future__ import annotations

import os
import pickle
import select
import struct
import subprocess
import sys
import time
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


@dataclass(frozen=True)
class Answer:
    """What HiGHS returned: ``x`` None when it found no solution; ``dual_bound`` on the cost."""

    status: int  # scipy.optimize.milp: 0 optimal, 1 time/iteration limit, 2 infeasible, ...
    x: NDArray[np.float64] | None
    cost: float | None
    dual_bound: float | None
    message: str


def solve(program: Program, time_limit_s: float) -> Answer:
    """Run HiGHS (scipy.optimize.milp) on ``program`` in this process."""
    from scipy.optimize import Bounds, LinearConstraint, milp

    constraints = ([LinearConstraint(program.rows, program.row_lower, program.row_upper)]
                   if program.rows.shape[0] else [])
    result = milp(program.cost, integrality=program.integrality,
                  bounds=Bounds(program.lower, program.upper), constraints=constraints,
                  options={"time_limit": max(time_limit_s, 0.01), "disp": False,
                           "presolve": True})
    bound = getattr(result, "mip_dual_bound", None)
    return Answer(
        status=int(result.status),
        x=None if result.x is None else np.asarray(result.x, np.float64),
        cost=None if result.fun is None else float(result.fun),
        dual_bound=None if bound is None or not np.isfinite(bound) else float(bound),
        message=str(result.message),
    )


class HighsProcess:
    """A child process running :func:`solve`; killed when an answer is late. Use ``with``."""

    def __init__(self) -> None:
        self._child: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        """Start the child now (it imports scipy while the caller does other work)."""
        if self._child is None or self._child.poll() is not None:
            self._child = subprocess.Popen(
                [sys.executable, "-c", "from planner.highs_worker import main; main()"],
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
            reply = _receive(child.stdout, deadline)
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
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)) + data)
    stream.flush()


def _read_exactly(stream: IO[bytes], size: int, deadline: float | None) -> bytes:
    chunks: list[bytes] = []
    fd = stream.fileno()
    while size:
        if deadline is not None:
            left_s = deadline - time.monotonic()
            if left_s <= 0 or not select.select([fd], [], [], left_s)[0]:
                raise TimeoutError("HiGHS did not answer in time")
        chunk = os.read(fd, min(size, 1 << 20))
        if not chunk:
            raise EOFError("the HiGHS process ended")
        chunks.append(chunk)
        size -= len(chunk)
    return b"".join(chunks)


def _receive(stream: IO[bytes], deadline: float | None) -> Any:
    (size,) = _HEADER.unpack(_read_exactly(stream, _HEADER.size, deadline))
    return pickle.loads(_read_exactly(stream, size, deadline))  # our own child's bytes


def main() -> None:
    """The child: answer programs until stdin closes."""
    replies = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything HiGHS prints goes to stderr, not into the protocol
    requests = sys.stdin.buffer
    while True:
        try:
            program, limit_s = _receive(requests, None)
        except EOFError:
            return
        _send(replies, solve(program, limit_s))
