"""Embree through its C API on a device pinned to one instruction set.

Embree picks its kernels at run time from the CPU's instruction sets (SSE4.2, AVX, AVX2,
AVX-512), and kernels of two sets round a ray that grazes an edge differently: an AVX2 and
an AVX-512 machine disagree on a few rays of a building. So the plan would depend on the
machine. Embree's device configuration caps the kernels it may use (``max_isa``, Embree's
API reference, ``rtcNewDevice``: "isa", "max_isa"); every machine that has the capped set
then runs the same kernels, the same instructions on the same float32 data, and decides
every ray the same way with one cast.

The cap is AVX2 (with FMA3, BMI1/2, LZCNT and MOVBE, as Embree defines it: Intel Haswell,
2013, and later; AMD Excavator, 2015, and Zen). A CPU without it runs Embree's best set
below AVX2, which :data:`KERNELS` names and every plan records; on ARM the kernels are the
NEON ones of that build.

embreex's Python wrapper makes its devices with no configuration, so this module calls
the Embree library that embreex ships (the same binary) through ctypes, and casts rays in
compiled loops that call ``rtcIntersect8`` directly, eight rays a call (the GIL released).
"""

from __future__ import annotations

import ctypes
import glob
import os
import platform
import threading
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from planner.errors import PlannerError

# Embree 4's C API (include/embree4/rtcore_*.h): the enum values this module passes
_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX, _BUFFER_TYPE_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
_SCENE_FLAG_ROBUST = 1 << 2
_BUILD_QUALITY_MEDIUM = 1  # Embree's default for static scenes
_INVALID_ID = 0xFFFFFFFF
# RTCRayHit8 (include/embree4/rtcore_ray.h): eight rays and their hits, structure of
# arrays, aligned to 32 bytes. Each field is eight 4-byte words, in this order: the ray
# (org x, y, z, tnear, dir x, y, z, time, tfar, mask, id, flags), then the hit (Ng x, y,
# z, u, v, primID, geomID, instID, instPrimID: one instance level, as this build's
# single-ray layout has it). The field index of each word the loops below write and read
_LANES = 8
_PACKET_FIELDS = 21
_ORG_X, _TNEAR, _DIR_X, _TIME, _TFAR, _MASK, _ID, _FLAGS = 0, 3, 4, 7, 8, 9, 10, 11
_PRIM_ID, _GEOM_ID, _INST_ID, _INST_PRIM_ID = 17, 18, 19, 20

# Embree's AVX2 set, in LLVM's names of the CPU features (Embree's common/sys/sysinfo.h:
# ISA_AVX2 = AVX + AVX2, FMA3, BMI1, BMI2, LZCNT, MOVBE)
_AVX2_FEATURES = ("avx", "avx2", "fma", "bmi", "bmi2", "lzcnt", "movbe", "sse4.2")


def _library_path() -> str:
    """The Embree 4 shared library that embreex's wheel bundles beside its package."""
    try:
        import embreex
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise PlannerError(
            "embreex is not installed; install the project with its dependencies "
            "(pip install -e .) to get the Embree ray caster") from exc
    package = os.path.dirname(embreex.__file__)
    site = os.path.dirname(package)
    patterns = (os.path.join(site, "embreex.libs", "libembree4*"),  # Linux (auditwheel)
                os.path.join(package, ".dylibs", "libembree4*"),  # macOS (delocate)
                os.path.join(site, "embreex.libs", "embree4*.dll"))  # Windows (delvewheel)
    for pattern in patterns:
        found = sorted(glob.glob(pattern))
        if found:
            return found[0]
    raise PlannerError(f"embreex's Embree 4 library was not found beside {package}; "
                       "reinstall embreex from its wheel (pip install --force-reinstall embreex)")


def _kernel_set() -> tuple[str, bytes]:
    """The instruction set the kernels are pinned to on this CPU, and the device config."""
    machine = platform.machine().lower()
    if machine not in ("x86_64", "amd64", "i686", "x86"):
        return f"{machine} (Embree's default kernels)", b""
    import llvmlite.binding as llvm

    features = llvm.get_host_cpu_features()
    if all(features.get(name, False) for name in _AVX2_FEATURES):
        return "avx2", b"max_isa=avx2"
    if features.get("sse4.2", False):
        return "sse4.2", b"max_isa=sse4.2"
    return "sse2", b"max_isa=sse2"


_LIB = ctypes.CDLL(_library_path())
_VOID = ctypes.c_void_p
for _name, _args, _result in (
        ("rtcNewDevice", [ctypes.c_char_p], _VOID),
        ("rtcGetDeviceError", [_VOID], ctypes.c_int),
        ("rtcNewScene", [_VOID], _VOID),
        ("rtcSetSceneFlags", [_VOID, ctypes.c_int], None),
        ("rtcSetSceneBuildQuality", [_VOID, ctypes.c_int], None),
        ("rtcNewGeometry", [_VOID, ctypes.c_int], _VOID),
        ("rtcSetNewGeometryBuffer", [_VOID, ctypes.c_int, ctypes.c_uint, ctypes.c_int,
                                     ctypes.c_size_t, ctypes.c_size_t], _VOID),
        ("rtcCommitGeometry", [_VOID], None),
        ("rtcAttachGeometry", [_VOID, _VOID], ctypes.c_uint),
        ("rtcReleaseGeometry", [_VOID], None),
        ("rtcCommitScene", [_VOID], None),
        ("rtcReleaseScene", [_VOID], None),
        ("rtcIntersect8", [_VOID, _VOID, _VOID, _VOID], None)):
    _function = getattr(_LIB, _name)
    _function.argtypes, _function.restype = _args, _result
_intersect8 = _LIB.rtcIntersect8

#: the instruction set every ray of this process is decided with ("avx2" on any x86-64
#: CPU since 2013-2015)
KERNELS, _CONFIG = _kernel_set()
_devices: dict[bytes, int] = {}
_device_lock = threading.Lock()


def _device(config: bytes) -> int:
    """The Embree device of ``config`` in this process (thread-safe, made once)."""
    with _device_lock:
        if config not in _devices:
            device = _LIB.rtcNewDevice(config or None)
            if not device:
                raise PlannerError(f"Embree refused its device (config {config.decode()!r})")
            _devices[config] = int(device)
        return _devices[config]


def _check(device: int, what: str) -> None:
    code = _LIB.rtcGetDeviceError(device)
    if code:
        raise PlannerError(f"Embree failed to {what} (error {code}); the model may be "
                           "too large for this machine's memory")


class PinnedScene:
    """One triangle mesh in an Embree scene on the pinned device, built at once.

    ``vertices32`` (V, 3) float32 and ``faces32`` (B, 3) int32 are copied into Embree's own
    buffers (16 and 12 bytes a vertex and a triangle); ``robust``: Embree's watertight mode
    (no ray slips between two triangles that share an edge), else its fast mode.
    ``max_isa`` caps the kernels at another instruction set than the pinned one (Embree's
    names: "sse4.2", "avx", "avx2", "avx512"): only to show that the set decides rays.
    """

    def __init__(self, vertices32: NDArray[np.float32], faces32: NDArray[np.int32], *,
                 robust: bool, max_isa: str | None = None) -> None:
        device = _device(_CONFIG if max_isa is None else b"max_isa=" + max_isa.encode())
        self._scene = int(_LIB.rtcNewScene(device))
        if robust:
            _LIB.rtcSetSceneFlags(self._scene, _SCENE_FLAG_ROBUST)
        _LIB.rtcSetSceneBuildQuality(self._scene, _BUILD_QUALITY_MEDIUM)
        geometry = _LIB.rtcNewGeometry(device, _GEOMETRY_TYPE_TRIANGLE)
        vertex_buffer = _LIB.rtcSetNewGeometryBuffer(
            geometry, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3, 16, len(vertices32))
        index_buffer = _LIB.rtcSetNewGeometryBuffer(
            geometry, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3, 12, len(faces32))
        _check(device, "allocate the model's buffers")
        if len(vertices32):
            as_vertices = np.ctypeslib.as_array(
                (ctypes.c_float * (4 * len(vertices32))).from_address(vertex_buffer))
            as_vertices.reshape(-1, 4)[:, :3] = vertices32
        if len(faces32):
            as_faces = np.ctypeslib.as_array(
                (ctypes.c_uint32 * (3 * len(faces32))).from_address(index_buffer))
            as_faces.reshape(-1, 3)[:] = faces32
        _LIB.rtcCommitGeometry(geometry)
        _LIB.rtcAttachGeometry(self._scene, geometry)
        _LIB.rtcReleaseGeometry(geometry)
        _LIB.rtcCommitScene(self._scene)
        _check(device, "build its BVH")

    def __del__(self) -> None:
        scene = getattr(self, "_scene", 0)
        if scene:
            _LIB.rtcReleaseScene(scene)
            self._scene = 0

    def first_hits(self, origins32: NDArray[np.float32], directions32: NDArray[np.float32],
                   far32: NDArray[np.float32] | None = None) -> NDArray[np.int64]:
        """(R,) the triangle each (R, 3) ray hits first within ``far32`` (R,) (unbounded
        when None), -1 for none: Embree's closest hit from tnear 0."""
        prim = np.empty(len(origins32), np.int64)
        if len(origins32):
            _cast(_intersect8, self._scene, _contiguous32(origins32),
                  _contiguous32(directions32), _far(far32, len(origins32)), prim,
                  np.empty(0, np.float32))
        return prim

    def first_hits_and_distances(
            self, origins32: NDArray[np.float32], directions32: NDArray[np.float32]
    ) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
        """(R,) the first triangle each (R, 3) ray hits (-1: none) and (R,) its distance
        along the direction (Embree's tfar; the ray's far limit for a miss)."""
        prim = np.empty(len(origins32), np.int64)
        distance = _far(None, len(origins32)).copy()
        if len(origins32):
            _cast(_intersect8, self._scene, _contiguous32(origins32),
                  _contiguous32(directions32), distance, prim, distance)
        return prim, distance


def _contiguous32(array: NDArray[Any]) -> NDArray[np.float32]:
    return np.ascontiguousarray(array, np.float32)


def _far(far32: NDArray[np.float32] | None, n: int) -> NDArray[np.float32]:
    if far32 is None:
        return np.full(n, np.inf, np.float32)
    return np.ascontiguousarray(far32, np.float32)


@numba.njit(nogil=True, cache=True)
def _cast(intersect8: Any, scene: int, origins32: NDArray[np.float32],
          directions32: NDArray[np.float32], far32: NDArray[np.float32], prim: NDArray[np.int64],
          distance: NDArray[np.float32]) -> None:
    """Cast each (R, 3) ray with ``intersect8`` (Embree's ``rtcIntersect8``, passed as a
    first-class function so that the compiled loop is cached across processes) up to
    ``far32`` (R,); write its first triangle to ``prim`` (R,) (-1: none) and, when
    ``distance`` is not empty, its tfar.

    Eight rays go to Embree at a time, as one packet: the rays of a block start at one
    candidate and end on neighbouring pieces, so a packet's rays walk mostly the same BVH
    nodes (on the benchmark matrix the visibility takes 6 - 11 % less CPU time than with
    one ``rtcIntersect1`` a ray). Each lane finds its own closest hit with the pinned
    kernels' triangle test; ``tests/planner/test_pinned_kernels.py`` compares the packets'
    hits and distances with single rays', the rays that graze shared corners included.
    """
    # one RTCRayHit8 and its valid mask, aligned to 32 bytes inside slightly longer buffers
    buffer = np.zeros(_PACKET_FIELDS * _LANES + 8, np.float32)
    start = ((32 - buffer.ctypes.data % 32) % 32) // 4
    ray = buffer[start:start + _PACKET_FIELDS * _LANES]
    words = ray.view(np.uint32)
    valid_buffer = np.zeros(2 * _LANES, np.int32)
    valid_start = ((32 - valid_buffer.ctypes.data % 32) % 32) // 4
    valid = valid_buffer[valid_start:valid_start + _LANES]
    with_distance = distance.shape[0] > 0
    n = origins32.shape[0]
    for first in range(0, n, _LANES):
        lanes = min(_LANES, n - first)
        for i in range(_LANES):
            # a lane past the last ray is inactive (Embree skips it); it holds the
            # packet's first ray
            r = first + i if i < lanes else first
            valid[i] = -1 if i < lanes else 0
            for axis in range(3):
                ray[(_ORG_X + axis) * _LANES + i] = origins32[r, axis]
                ray[(_DIR_X + axis) * _LANES + i] = directions32[r, axis]
            ray[_TNEAR * _LANES + i] = 0.0
            ray[_TIME * _LANES + i] = 0.0
            ray[_TFAR * _LANES + i] = far32[r]
            words[_MASK * _LANES + i] = _INVALID_ID  # every geometry
            words[_ID * _LANES + i] = 0
            words[_FLAGS * _LANES + i] = 0
            words[_PRIM_ID * _LANES + i] = _INVALID_ID
            words[_GEOM_ID * _LANES + i] = _INVALID_ID
            words[_INST_ID * _LANES + i] = _INVALID_ID
            words[_INST_PRIM_ID * _LANES + i] = _INVALID_ID
        intersect8(valid.ctypes, scene, ray.ctypes, 0)
        for i in range(lanes):
            hit = words[_GEOM_ID * _LANES + i] != _INVALID_ID
            prim[first + i] = np.int64(words[_PRIM_ID * _LANES + i]) if hit else -1
            if with_distance:
                distance[first + i] = ray[_TFAR * _LANES + i]
