"""The target of the planner's compiled kernels: one instruction set on every machine.

numba compiles each kernel the first time a process calls it, for the CPU it runs on, and
keeps the machine code in its cache (``cache=True``), keyed by that CPU's name and features.
So a cache is of use only on the machine that made it, and the first plan after an install,
or in every new container of the Docker image, compiled all kernels: on the 2-core machine
of ``docs/performance.md`` the IfcOpenHouse example took 34.3 s instead of 4.2 s and
peaked at 730 instead of 527 MB.

The ``scanplan`` command therefore compiles for one target on every CPU that can run it:
x86-64-v3 (AVX, AVX2, BMI1, BMI2, F16C, FMA, LZCNT, MOVBE and XSAVE, the x86-64 psABI's
micro-architecture level 3, Table 3.1 of the System V AMD64 ABI: Intel Haswell, 2013, and
later, AMD Excavator, 2015, and Zen), the same CPUs Embree's kernels are pinned to
(:mod:`planner.rays.pinned`). A cache compiled on one such machine, the Docker image's made
when it is built, then serves every other. Without fast-math flags LLVM neither reorders
nor fuses floating-point operations, so the pin changes no result, only where a cache is
valid (hall-full's files are byte-identical either way, and as fast: 5.25 s).

The pin is numba's own configuration (``NUMBA_CPU_NAME``, ``NUMBA_CPU_FEATURES``), read when
numba is first imported: :func:`pin_numba_target` sets it in the environment, which worker
processes inherit. Light on purpose: it runs before ``scanplan`` imports anything heavy.
"""

from __future__ import annotations

import os
import platform
import sys
from collections.abc import Iterable, MutableMapping
from pathlib import Path

# the x86-64 psABI's level 3, in the flag names of Linux's /proc/cpuinfo (abm: LZCNT)
X86_64_V3_FLAGS = frozenset(("avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe",
                             "xsave"))
# LLVM's name of that level as a CPU
X86_64_V3 = "x86-64-v3"


def target_for(machine: str, cpu_flags: Iterable[str]) -> str | None:
    """The CPU name the kernels are compiled for on a ``machine`` (``platform.machine()``)
    with ``cpu_flags`` (/proc/cpuinfo's names): x86-64-v3 where it runs, else None (the
    host's own CPU, numba's default)."""
    if machine.lower() not in ("x86_64", "amd64"):
        return None
    return X86_64_V3 if set(cpu_flags) >= X86_64_V3_FLAGS else None


def host_cpu_flags(cpuinfo: Path = Path("/proc/cpuinfo")) -> frozenset[str]:
    """The CPU's feature flags as Linux lists them (empty where there is no /proc/cpuinfo:
    macOS and Windows keep numba's default, the host's CPU)."""
    try:
        with cpuinfo.open(encoding="ascii", errors="replace") as lines:
            for line in lines:
                if line.startswith("flags"):
                    return frozenset(line.partition(":")[2].split())
    except OSError:
        pass
    return frozenset()


def pin_numba_target(environ: MutableMapping[str, str] = os.environ) -> str | None:
    """Sets numba's target to x86-64-v3 in ``environ`` where the CPU runs it and numba is
    not imported yet; returns the CPU name numba compiles for (None: the host's). A
    ``NUMBA_CPU_NAME`` already set is the user's choice and is kept."""
    if "NUMBA_CPU_NAME" in environ:
        return environ["NUMBA_CPU_NAME"]
    if "numba" in sys.modules:  # numba has read its configuration: too late to change it
        return None
    target = target_for(platform.machine(), host_cpu_flags())
    if target is not None:
        environ["NUMBA_CPU_NAME"] = target
        # the level's own features, not the host's: the cache's key names only the level
        environ["NUMBA_CPU_FEATURES"] = ""
    return target
