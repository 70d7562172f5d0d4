"""Which way is up: the ``up_axis`` parameter, and gravity found from the model itself.

The planner works in a *plan frame* whose +Z is up (floors are found by rays along +Z, the
blind cone points down -Z). A model whose up is another axis is rotated into that frame when
it is read (``plan = R @ model``, R a proper rotation), and every position the planner
writes (stations, candidates, the glb) is rotated back, so outputs stay in the model's own
coordinates and a BIM platform can place them without a transform.

``up_axis`` names the model's up: ``"+Z"`` ... ``"-X"``, or ``"auto"``. Unset, it follows
the format: glTF 2.0 defines +Y as up (glTF 2.0 specification, section 3.4 "Coordinate
System and Units"); IFC world coordinates from IfcOpenShell and OBJ/PLY/STL/OFF meshes are
taken as +Z.

``"auto"`` finds gravity from the dominant planes (floors, ceilings and walls of a
building are few, large and perpendicular):

1. the dominant plane orientation: the face normal whose +/-10 degree neighbourhood holds
   the most area (sampled, deterministic), refined to the area-weighted mean normal of
   neighbourhoods narrowing from 10 to 0.01 degrees (small faces slightly off the plane
   stop pulling);
2. the dominant orientation among the faces perpendicular to it (walls if 1. was the floor,
   floor or the other walls if 1. was a wall): the 4-fold circular mean of their
   directions, refined the same way, which squares the frame exactly to the walls;
3. of the three axes, up is the one with the most facing area per metre of extent
   (a storey is wider than it is high, floors and ceilings span it), weighted up by how
   much more area faces one way than the other (gravity breaks the symmetry: table tops,
   sills and stair treads face up, a scan sees more floor than ceiling);
4. its sign: the area leaning up (more than 10 degrees off vertical: floors, table tops,
   sloped roofs) exceeds the area leaning down, and the walls' area lies below mid-height
   (furniture stands on the floor); ``vote = lean asymmetry - 2 x (wall centre - middle)
   / height``. A symmetric empty box cannot be told and fails;
5. up is then made perpendicular to the walls (walls are plumb; a site or a scanned floor
   may slope);
6. of the four headings that level the model, the smallest rotation: a model that is
   already Z-up comes back unchanged (within a microradian of the axes counts as on them).

Confidence is reported per decision (0..1); below ``_MIN_CONFIDENCE`` the reader stops
with a :class:`ParameterError` naming ``up_axis``.

Array letters: F faces, N points.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.errors import ParameterError
from planner.parameters import UP_AXES

# plan = R @ model; each R a proper rotation taking the named axis to +Z (for +Y the usual
# glTF to Z-up conversion: x stays, y becomes z, z becomes -y)
_AXIS_ROTATIONS: dict[str, tuple[tuple[int, int, int], ...]] = {
    "+Z": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "-Z": ((1, 0, 0), (0, -1, 0), (0, 0, -1)),
    "+Y": ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
    "-Y": ((1, 0, 0), (0, 0, 1), (0, -1, 0)),
    "+X": ((0, 1, 0), (0, 0, 1), (1, 0, 0)),
    "-X": ((0, -1, 0), (0, 0, 1), (-1, 0, 0)),
}
_PLANE_TOLERANCE_DEG = 10.0
# refinement of the dominant directions over narrowing neighbourhoods, degrees
_REFINE_DEG = (10.0, 1.0, 0.1, 0.01)
_SNAP = 1e-6
_REFINE_COS = tuple(math.cos(math.radians(d)) for d in _REFINE_DEG)
_MIN_CONFIDENCE = 0.1
_PROBES = 512  # normals tried as the dominant orientation (half the largest faces)
_SAMPLE_FACES = 20_000  # faces that score each probe: (20 k, 512) scores, 80 MB


def default_up_axis(fmt: str) -> str:
    """The up axis a format defines: +Y for glTF/GLB, +Z for the rest."""
    return "+Y" if fmt in ("glb", "gltf") else "+Z"


def axis_rotation(up_axis: str) -> NDArray[np.float64]:
    """(3, 3) float64 rotation taking the model's ``up_axis`` to +Z (``plan = R @ model``)."""
    if up_axis not in _AXIS_ROTATIONS:
        raise ParameterError("up_axis", f"{up_axis!r} is not one of {', '.join(UP_AXES)}")
    return np.array(_AXIS_ROTATIONS[up_axis], np.float64)


def find_up(vertices: NDArray[np.float64], faces: NDArray[np.integer[Any]]
            ) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """The rotation that levels a model, and how sure it is (see the module docstring).

    Parameters
    ----------
    vertices : (V, 3) float64, model coordinates
    faces : (F, 3) int64

    Returns
    -------
    (3, 3) float64 rotation R with ``plan = R @ model``, and a report with the model's up
    vector and the confidence of each decision

    Raises
    ------
    ParameterError
        ``up_axis``: the model has no dominant planes, or up cannot be told from a side
    """
    triangles = vertices[faces]
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    doubled = np.linalg.norm(cross, axis=1)
    keep = doubled > 0
    normals = cross[keep] / doubled[keep, None]
    areas = doubled[keep] / 2.0
    centroids = triangles[keep].mean(axis=1)
    if len(areas) == 0:
        raise ParameterError("up_axis", "auto found no faces with an area; give the axis")
    cos_tol = math.cos(math.radians(_PLANE_TOLERANCE_DEG))
    sin_tol = math.sin(math.radians(_PLANE_TOLERANCE_DEG))

    first = _dominant(normals, areas, cos_tol)
    across = np.abs(normals @ first) < sin_tol
    if areas[across].sum() <= 0:
        raise _undecided("every large plane faces one way (no walls across the floors)")
    second = _square(normals[across], areas[across], first)
    third = np.cross(first, second)
    axes = np.stack([first, second, third])

    along = normals @ axes.T  # (F, 3)
    up_area = (areas[:, None] * (along > cos_tol)).sum(axis=0)
    down_area = (areas[:, None] * (along < -cos_tol)).sum(axis=0)
    # gravity breaks a room's symmetry: table tops, sills and treads face up, a scan sees
    # floors better than ceilings; walls look the same from both sides
    asymmetry = (up_area - down_area) / np.maximum(up_area + down_area, 1e-12)
    extent = np.ptp(centroids @ axes.T, axis=0)
    score = (up_area + down_area) / np.maximum(extent, 1e-9) * (1.0 + np.abs(asymmetry))
    ranked = np.argsort(-score, kind="stable")
    axis_confidence = float(1.0 - score[ranked[1]] / score[ranked[0]])
    k = int(ranked[0])
    up = axes[k]

    # the sign: things stand on floors, so the wall area lies below mid-height, and more
    # area faces up than down (both measured along +up)
    height = centroids @ up
    wall = np.abs(along[:, k]) < sin_tol
    middle = (height.min() + height.max()) / 2.0
    wall_mean = (np.average(height[wall], weights=areas[wall]) - middle) / max(
        float(np.ptp(height)), 1e-9)
    # every face that leans up or down counts here, sloped roofs (outward normals) too
    leaning = np.abs(along[:, k]) > sin_tol
    up_lean = float(areas[leaning & (along[:, k] > 0)].sum())
    lean_asymmetry = (2.0 * up_lean - float(areas[leaning].sum())) / max(
        float(areas[leaning].sum()), 1e-12)
    vote = lean_asymmetry - 2.0 * float(wall_mean)
    sign = 1.0 if vote >= 0 else -1.0
    sign_confidence = float(min(1.0, abs(vote) * 5.0))
    up = up * sign
    if min(axis_confidence, sign_confidence) < _MIN_CONFIDENCE:
        raise _undecided(
            f"axis confidence {axis_confidence:.2f}, sign confidence {sign_confidence:.2f}")

    up = _plumb(normals[wall], areas[wall], up)
    # the heading again, now in the plane across the plumb up
    across = np.abs(normals @ up) < sin_tol
    rotation = _closest_heading(up, _square(normals[across], areas[across], up))
    # a model square to its axes to within a microradian (0.05 mm over 50 m) is square: its
    # rotation is the exact signed permutation, so that a level model stays untouched
    snapped = np.round(rotation)
    if np.abs(rotation - snapped).max() < _SNAP:
        rotation = snapped + 0.0
    report = {
        "up_in_model": [round(float(v), 6) + 0.0 for v in up],  # + 0.0: no -0.0
        "confidence": round(min(axis_confidence, sign_confidence), 3),
        "axis_confidence": round(axis_confidence, 3),
        "sign_confidence": round(sign_confidence, 3),
    }
    return rotation, report


def _undecided(why: str) -> ParameterError:
    return ParameterError(
        "up_axis", f"auto cannot tell which way is up ({why}); give the model's up axis, "
        f"one of {', '.join(UP_AXES[:-1])}")


def _dominant(normals: NDArray[np.float64], areas: NDArray[np.float64], cos_tol: float
              ) -> NDArray[np.float64]:
    """(3,) the plane orientation (up to sign) holding the most area, refined."""
    # a fixed, spread sample: the result must not depend on anything but the model
    step_probe = max(1, len(normals) // (_PROBES // 2))
    step_sample = max(1, len(normals) // _SAMPLE_FACES)
    by_area = np.argsort(-areas, kind="stable")
    probes = normals[np.unique(np.r_[by_area[:_PROBES // 2],
                                     np.arange(0, len(normals), step_probe)[:_PROBES // 2]])]
    sample, weight = normals[::step_sample], areas[::step_sample]
    held = (np.abs(sample @ probes.T) > cos_tol).T @ weight
    best = probes[int(np.argmax(held))]
    for tolerance in _REFINE_COS:
        # refine on every face: the mean of the flipped neighbourhood, narrower each time so
        # that small faces slightly off the plane (railings, mouldings) stop pulling
        along = normals @ best
        near = np.abs(along) > tolerance
        if not near.any():
            break
        mean = (normals[near] * (areas[near] * np.sign(along[near]))[:, None]).sum(axis=0)
        best = mean / np.linalg.norm(mean)
    return np.asarray(best)


def _square(normals: NDArray[np.float64], areas: NDArray[np.float64],
            axis: NDArray[np.float64]) -> NDArray[np.float64]:
    """(3,) a unit vector perpendicular to ``axis`` along the dominant orthogonal walls."""
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    angle = np.arctan2(normals @ v, normals @ u)
    # 4-fold circular mean: walls at 0, 90, 180, 270 degrees all pull the same way; then
    # again over the faces within a narrowing angle of it (exact for exactly square walls)
    phase = float(np.angle(np.sum(areas * np.exp(4j * angle)))) / 4.0
    for tolerance_deg in _REFINE_DEG:
        off = np.angle(np.exp(4j * (angle - phase))) / 4.0  # to the nearest wall direction
        near = np.abs(off) < math.radians(tolerance_deg)
        if not near.any():
            break
        phase += float(np.angle(np.sum(areas[near] * np.exp(4j * off[near])))) / 4.0
    direction = math.cos(phase) * u + math.sin(phase) * v
    return np.asarray(direction / np.linalg.norm(direction))


def _plumb(normals: NDArray[np.float64], areas: NDArray[np.float64],
           up: NDArray[np.float64]) -> NDArray[np.float64]:
    """(3,) ``up`` made perpendicular to the walls: walls are plumb, floors and sites may slope.

    The direction least along the walls' normals (smallest eigenvector of their
    area-weighted scatter); ``up`` unchanged when the walls run one way only.
    """
    for tolerance_deg in _REFINE_DEG:  # narrowing, so that faces off the walls stop pulling
        near = np.abs(normals @ up) < math.sin(math.radians(tolerance_deg))
        if not near.any():
            break
        scatter = (normals[near] * areas[near, None]).T @ normals[near]
        values, vectors = np.linalg.eigh(scatter)  # ascending
        if values[1] < 0.1 * values[2]:  # walls in one direction: they do not fix up
            break
        plumb = vectors[:, 0] * (1.0 if vectors[:, 0] @ up >= 0 else -1.0)
        up = plumb / np.linalg.norm(plumb)
    return np.asarray(up)


def _closest_heading(up: NDArray[np.float64], wall: NDArray[np.float64]
                     ) -> NDArray[np.float64]:
    """(3, 3) the rotation with third row ``up`` and walls on the axes, nearest identity."""
    wall = wall - (wall @ up) * up
    wall /= np.linalg.norm(wall)
    best, best_trace = np.eye(3), -math.inf
    for k in range(4):
        x_axis = wall if k == 0 else np.cross(up, wall) if k == 1 else (
            -wall if k == 2 else -np.cross(up, wall))
        rotation = np.stack([x_axis, np.cross(up, x_axis), up])
        trace = float(np.trace(rotation))
        if trace > best_trace + 1e-12:
            best, best_trace = rotation, trace
    return best


def to_model(rotation: NDArray[np.float64] | None, points: NDArray[np.float64]
             ) -> NDArray[np.float64]:
    """(N, 3) plan-frame points back in model coordinates (unchanged without a rotation)."""
    if rotation is None:
        return points
    return np.asarray(np.asarray(points, np.float64) @ rotation)


def to_plan(rotation: NDArray[np.float64] | None, points: NDArray[np.float64]
            ) -> NDArray[np.float64]:
    """(N, 3) model-coordinate points in the plan frame (unchanged without a rotation)."""
    if rotation is None:
        return points
    return np.asarray(np.asarray(points, np.float64) @ rotation.T)


def scene_rotation(metadata: dict[str, Any]) -> NDArray[np.float64] | None:
    """The (3, 3) model-to-plan rotation a reader applied, None when it applied none."""
    orientation = metadata.get("orientation") or {}
    rows = orientation.get("rotation")
    return None if rows is None else np.asarray(rows, np.float64)


def glb_root_rotation(metadata: dict[str, Any]) -> list[float] | None:
    """Quaternion (x, y, z, w) that puts plan-frame geometry back in the model's glTF frame.

    None when no rotation was applied (the glb's own Z-up to Y-up root stays). For a glTF
    input the root undoes the rotation exactly (the output lines up with the input); for
    other formats it undoes it and then turns Z-up into glTF's Y-up, as for any Z-up model.
    """
    rotation = scene_rotation(metadata)
    if rotation is None:
        return None
    from scipy.spatial.transform import Rotation

    to_model_frame = rotation.T
    if metadata.get("format") not in ("glb", "gltf"):
        to_model_frame = axis_rotation("+Y").T @ to_model_frame
    quaternion = Rotation.from_matrix(to_model_frame).as_quat()
    return [round(float(v), 9) for v in quaternion]
