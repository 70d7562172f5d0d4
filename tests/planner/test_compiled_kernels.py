"""The instruction set the kernels are compiled for: x86-64-v3 on every CPU that runs it,
so numba's cache made on one machine serves any other such machine (the Docker image ships
one made when it is built). That ``scanplan compile-kernels`` fills the cache so that a plan
of another model compiles nothing is checked on the installed wheel (tests/test_wheel.py).
"""

from __future__ import annotations

import json
import subprocess
import sys
from importlib import resources
from pathlib import Path

import pytest

from planner.kernels import X86_64_V3, host_cpu_flags, pin_numba_target, target_for

# /proc/cpuinfo flags of an Intel Core i7-4770 (Haswell, 2013): x86-64-v3
_HASWELL = ("fpu vme de pse tsc msr pae mce cx8 apic sep mtrr pge mca cmov pat pse36 clflush "
            "dts acpi mmx fxsr sse sse2 ss ht tm pbe syscall nx pdpe1gb rdtscp lm constant_tsc "
            "arch_perfmon pebs bts rep_good nopl xtopology nonstop_tsc cpuid aperfmperf pni "
            "pclmulqdq dtes64 monitor ds_cpl vmx est tm2 ssse3 sdbg fma cx16 xtpr pdcm pcid "
            "sse4_1 sse4_2 x2apic movbe popcnt tsc_deadline_timer aes xsave avx f16c rdrand "
            "lahf_lm abm cpuid_fault epb invpcid_single pti ssbd ibrs ibpb stibp tpr_shadow "
            "vnmi flexpriority ept vpid ept_ad fsgsbase tsc_adjust bmi1 avx2 smep bmi2 erms "
            "invpcid xsaveopt dtherm ida arat pln pts md_clear flush_l1d")
HASWELL = _HASWELL.split()
# an Intel Celeron J4125 (Goldmont Plus, 2019), as in small NAS boxes: SSE4.2, no AVX
_GOLDMONT_PLUS = ("fpu vme de pse tsc msr pae mce cx8 apic sep mtrr pge mca cmov pat pse36 "
                  "clflush dts acpi mmx fxsr sse sse2 ss ht tm pbe syscall nx pdpe1gb rdtscp lm "
                  "constant_tsc art arch_perfmon pebs bts rep_good nopl xtopology nonstop_tsc "
                  "cpuid aperfmperf tsc_known_freq pni pclmulqdq dtes64 monitor ds_cpl vmx est "
                  "tm2 ssse3 sdbg cx16 xtpr pdcm sse4_1 sse4_2 x2apic movbe popcnt "
                  "tsc_deadline_timer aes xsave rdrand lahf_lm 3dnowprefetch cpuid_fault cat_l2 "
                  "pti cdp_l2 ssbd ibrs ibpb stibp ibrs_enhanced tpr_shadow vnmi flexpriority ept "
                  "vpid ept_ad fsgsbase tsc_adjust smep erms mpx rdt_a rdseed smap clflushopt "
                  "intel_pt sha_ni xsaveopt xsavec xgetbv1 xsaves dtherm ida arat pln pts umip "
                  "rdpid md_clear arch_capabilities")
GOLDMONT_PLUS = _GOLDMONT_PLUS.split()


def test_the_target_is_x86_64_v3_on_every_cpu_that_runs_it() -> None:
    assert target_for("x86_64", HASWELL) == X86_64_V3
    assert target_for("AMD64", HASWELL) == X86_64_V3  # Windows' name of the machine
    # a CPU without AVX2 keeps its own target: code for x86-64-v3 would not run on it
    assert target_for("x86_64", GOLDMONT_PLUS) is None
    assert target_for("x86_64", sorted(set(HASWELL) - {"bmi2"})) is None
    assert target_for("aarch64", HASWELL) is None


def test_the_users_own_numba_target_is_kept() -> None:
    environ = {"NUMBA_CPU_NAME": "skylake"}
    assert pin_numba_target(environ) == "skylake"
    assert environ == {"NUMBA_CPU_NAME": "skylake"}


@pytest.mark.parametrize("flags", [HASWELL, GOLDMONT_PLUS])
def test_host_flags_are_read_from_cpuinfo(tmp_path: Path, flags: list[str]) -> None:
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nvendor_id\t: GenuineIntel\n"
                       f"flags\t\t: {' '.join(flags)}\n\nprocessor\t: 1\n")
    assert host_cpu_flags(cpuinfo) == frozenset(flags)
    assert host_cpu_flags(tmp_path / "absent") == frozenset()


# a fresh process: warms up as the service's consumer does before it forks the processes
# that plan, then plans and prints what the plan compiled and loaded
_WARM_THEN_PLAN = """
import json, sys
from planner.kernels import pin_numba_target
pin_numba_target()
from planner.__main__ import kernel_counts, main, warm_up
modules, loaded = warm_up()
warm = kernel_counts()
code = main(sys.argv[1:])
print(json.dumps({"modules": modules, "loaded": loaded, "warm": warm,
                  "after_plan": kernel_counts(), "code": code}))
"""


def test_after_the_warm_up_a_plan_loads_no_kernel(tmp_path: Path) -> None:
    """The service's consumer warms up (``planner.__main__.warm_up``) before it forks the
    worker processes, so that a job's process loads nothing itself: every kernel that
    planning the hall calls is in memory before the plan starts, none compiled."""
    hall = Path(str(resources.files("planner") / "example_data" / "hall-small"))
    plan = ["plan", str(hall / "hall.obj"), "--candidates", str(hall / "candidates.csv"),
            "--quiet"]
    # numba's cache holds the hall's kernels after one plan (this one compiles what it lacks)
    subprocess.run([sys.executable, "-m", "planner", *plan, "--out", str(tmp_path / "first")],
                   check=True, timeout=600)
    run = subprocess.run([sys.executable, "-c", _WARM_THEN_PLAN, *plan,
                          "--out", str(tmp_path / "warm")],
                         check=True, timeout=600, capture_output=True, text=True)
    counts = json.loads(run.stdout.strip().splitlines()[-1])
    assert counts["code"] == 0
    assert counts["modules"] > 50  # every stage's modules, the renderers' too
    compiled, loaded = counts["warm"]
    assert compiled == 0 and loaded == counts["loaded"] > 0
    assert counts["after_plan"] == counts["warm"]  # the plan compiled and loaded nothing
    assert (tmp_path / "warm" / "plan.json").read_bytes() == (
        tmp_path / "first" / "plan.json").read_bytes()
