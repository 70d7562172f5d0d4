"""coverage.glb: a valid glTF binary that trimesh loads, face colours and the property table
agree with faces.npz, stations where the plan puts them, same bytes twice; a split model is
drawn by file face and coverage state, far fewer triangles than faces, every face's state
still in its feature.

The default file is meshopt-compressed, which trimesh cannot read: it is decoded here with
the ``meshopt`` decoder and shown to hold exactly the arrays of the uncompressed variant,
which trimesh then reads."""

from __future__ import annotations

import dataclasses
import io
import itertools
import json
import math
import struct
from pathlib import Path
from typing import Any

import meshopt
import numpy as np
import pytest
import trimesh

from planner.errors import ParameterError
from planner.outputs import drawing, glb, outline
from planner.outputs.report import faces_npz
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult, plan
from planner.scene import build_scene
from tests.planner.test_drawing import decode, pixel_of, plan_hall_small


@pytest.fixture(scope="module")
def result(scenes_dir: Path) -> PlanResult:
    return plan_hall_small(scenes_dir)


@pytest.fixture(scope="module")
def data(result: PlanResult) -> bytes:
    return glb.coverage_glb(result)


@pytest.fixture(scope="module")
def plain(result: PlanResult) -> bytes:
    return glb.coverage_glb(result, compress=False)


def chunks(data: bytes) -> tuple[dict[str, Any], bytes]:
    magic, version, total = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, total) == (b"glTF", 2, len(data))
    json_len, json_type = struct.unpack_from("<I4s", data, 12)
    assert json_type == b"JSON" and json_len % 4 == 0
    document = json.loads(data[20:20 + json_len])
    bin_len, bin_type = struct.unpack_from("<I4s", data, 20 + json_len)
    assert bin_type == b"BIN\x00"
    blob = data[28 + json_len:28 + json_len + bin_len]
    assert len(blob) == document["buffers"][0]["byteLength"]
    return document, blob


def view_bytes(document: dict[str, Any], blob: bytes, index: int) -> bytes:
    """The (decompressed) bytes of buffer view ``index``."""
    view = document["bufferViews"][index]
    packed = view.get("extensions", {}).get("EXT_meshopt_compression")
    if packed is None:
        assert view["buffer"] == 0
        return blob[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]
    assert document["buffers"][view["buffer"]]["extensions"]["EXT_meshopt_compression"][
        "fallback"]
    start = packed["byteOffset"]
    rows = meshopt.decode_gltf_buffer(blob[start:start + packed["byteLength"]],
                                      packed["count"], packed["byteStride"], packed["mode"])
    data = np.asarray(rows, np.uint8).tobytes()
    assert len(data) == view["byteLength"]
    return data


def test_same_bytes_twice(result: PlanResult, data: bytes, plain: bytes) -> None:
    assert glb.coverage_glb(result) == data
    assert glb.coverage_glb(result, compress=False) == plain


def test_compressed_file_holds_the_plain_arrays(data: bytes, plain: bytes) -> None:
    packed_doc, packed_blob = chunks(data)
    plain_doc, plain_blob = chunks(plain)
    assert "EXT_meshopt_compression" in packed_doc["extensionsRequired"]
    assert "EXT_meshopt_compression" not in plain_doc["extensionsUsed"]
    for key in ("nodes", "meshes", "accessors", "scenes", "materials"):
        assert packed_doc[key] == plain_doc[key]
    assert len(packed_doc["bufferViews"]) == len(plain_doc["bufferViews"])
    for index in range(len(plain_doc["bufferViews"])):
        assert (view_bytes(packed_doc, packed_blob, index)
                == view_bytes(plain_doc, plain_blob, index))
    assert len(data) < len(plain) / 2  # the point of compressing


def test_face_colours_match_faces_npz(result: PlanResult, plain: bytes) -> None:
    arrays = np.load(io.BytesIO(faces_npz(result)))
    classes = drawing.face_classes(arrays, result.limits.target)
    expected = glb.linear_bytes(drawing.face_rgb(arrays, result.limits.target,
                                                 result.limits.min_density_pts_m2))
    loaded = trimesh.load(io.BytesIO(plain), file_type="glb", process=False)
    document, _ = chunks(plain)
    assert "KHR_mesh_quantization" in document["extensionsRequired"]
    step_m = document["scenes"][0]["extras"]["scanplan"]["position_step_m"]
    root_inverse = np.diag([1.0, 1.0, 1.0, 1.0])
    root_inverse[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # glTF Y-up -> model Z-up
    seen = np.zeros(result.scene.n_faces, int)
    for k, name in enumerate(drawing.CLASS_NAMES):
        if not (classes == k).any():
            assert name not in loaded.geometry
            continue
        mesh = loaded.geometry[name]
        face_ids = mesh.vertex_attributes["_FEATURE_ID_0"].reshape(-1, 3)
        assert (face_ids == face_ids[:, :1]).all()
        ids = face_ids[:, 0].astype(int)
        assert (classes[ids] == k).all()
        colours = np.asarray(mesh.visual.vertex_attributes["color"]).reshape(-1, 3, 4)
        assert (colours[:, :, :3] == expected[ids][:, None, :]).all()
        # geometry is the scene's: uint16 grid steps that the node scales back to model
        # coordinates (under the root rotation), within half a step
        to_model = root_inverse @ loaded.graph[name][0]
        vertices = trimesh.transform_points(np.asarray(mesh.vertices, float), to_model)
        np.testing.assert_allclose(vertices.reshape(-1, 3, 3), result.scene.triangles[ids],
                                   rtol=0, atol=0.5 * step_m + 1e-9)
        seen[ids] += 1
    assert (seen == 1).all()  # every face once


_TYPES = {"UINT8": np.uint8, "INT32": np.int32, "UINT32": np.uint32, "FLOAT32": np.float32}


def property_table(document: dict[str, Any], blob: bytes
                   ) -> tuple[dict[str, np.ndarray], list[np.ndarray]]:
    """The property table's scalar columns, (N,) each, and each feature's rows of faces.npz
    (its variable-length ``faces`` array)."""
    metadata = document["extensions"]["EXT_structural_metadata"]
    table = metadata["propertyTables"][0]
    schema = metadata["schema"]["classes"][table["class"]]["properties"]
    columns = {}
    for name, column in table["properties"].items():
        assert document["bufferViews"][column["values"]]["byteOffset"] % 8 == 0
        values = np.frombuffer(view_bytes(document, blob, column["values"]),
                               _TYPES[schema[name]["componentType"]])
        if not schema[name].get("array"):
            columns[name] = values[:table["count"]]
    faces = table["properties"]["faces"]
    assert schema["faces"]["array"] and faces["arrayOffsetType"] == "UINT32"
    offsets = np.frombuffer(view_bytes(document, blob, faces["arrayOffsets"]), np.uint32,
                            count=table["count"] + 1)
    values = np.frombuffer(view_bytes(document, blob, faces["values"]), np.uint32)
    rows = [values[a:b].astype(int) for a, b in itertools.pairwise(offsets)]
    return columns, rows


def test_property_table_carries_faces_npz(result: PlanResult, data: bytes) -> None:
    """Read from the compressed file, as a BIM platform with a meshopt decoder would: a
    model that was not split has a feature a face, feature i being face i."""
    document, blob = chunks(data)
    arrays = np.load(io.BytesIO(faces_npz(result)))
    columns, rows = property_table(document, blob)
    assert len(rows) == result.scene.n_faces
    assert all(list(r) == [i] for i, r in enumerate(rows))
    for name in ("covered", "best_lpd_pts_m2", "n_stations", "first_station", "n_candidates",
                 "source_face"):
        np.testing.assert_array_equal(columns[name], arrays[name].astype(columns[name].dtype))


def test_stations_are_numbered_markers(result: PlanResult, plain: bytes) -> None:
    document, _ = chunks(plain)
    nodes = {node["name"]: node for node in document["nodes"]}
    loaded = trimesh.load(io.BytesIO(plain), file_type="glb", process=False)
    root = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float)  # model Z-up -> glTF Y-up
    for order, candidate in enumerate(result.chosen.stations):
        name = f"station {order + 1}"
        extras = nodes[name]["extras"]
        assert extras["order"] == order + 1 and extras["candidate_index"] == candidate
        assert extras["new_area_m2"] == pytest.approx(result.chosen.new_area_m2[order])
        position = result.candidates.positions[candidate]
        world = loaded.graph[name][0][:3, 3]
        np.testing.assert_allclose(world, root @ position, atol=1e-6)
        assert f"{name} number" in loaded.geometry
    assert document["scenes"][0]["extras"]["scanplan"]["stations"] == len(result.chosen.stations)


def test_glb_compression_parameter(result: PlanResult, plain: bytes) -> None:
    """``glb_compression: none`` gives the uncompressed file; a wrong value names the fix."""
    spec = PlanSpec.from_mapping({**result.spec.to_dict(), "glb_compression": "none"})
    assert glb.coverage_glb(dataclasses.replace(result, spec=spec)) == plain
    with pytest.raises(ParameterError, match=r"glb_compression.*meshopt, none"):
        PlanSpec.from_mapping({"glb_compression": "draco"})


def class_faces(document: dict[str, Any], blob: bytes) -> dict[str, tuple[np.ndarray, ...]]:
    """Per class mesh, over all its primitives in order: (n,) face ids, (n, 4) colours and
    (n, 3, 3) grid positions of its faces, read from the (decompressed) views."""
    def attribute(accessor: int, dtype: type, width: int) -> np.ndarray:
        spec = document["accessors"][accessor]
        view = document["bufferViews"][spec["bufferView"]]
        stride = view.get("byteStride", np.dtype(dtype).itemsize * width)
        rows = np.frombuffer(view_bytes(document, blob, spec["bufferView"]), np.uint8)
        rows = rows.reshape(spec["count"], stride)[:, :np.dtype(dtype).itemsize * width]
        return np.ascontiguousarray(rows).view(dtype).reshape(spec["count"], width)

    out = {}
    for mesh in document["meshes"]:
        if mesh["name"] not in drawing.CLASS_NAMES:
            continue
        parts = [(attribute(p["attributes"]["_FEATURE_ID_0"], np.float32, 1),
                  attribute(p["attributes"]["COLOR_0"], np.uint8, 4),
                  attribute(p["attributes"]["POSITION"], np.uint16, 3))
                 for p in mesh["primitives"]]
        ids = np.concatenate([p[0] for p in parts]).reshape(-1, 3)
        assert (ids == ids[:, :1]).all()
        out[mesh["name"]] = (ids[:, 0].astype(int),
                             np.concatenate([p[1] for p in parts]).reshape(-1, 3, 4)[:, 0],
                             np.concatenate([p[2] for p in parts]).reshape(-1, 3, 3))
    return out


def test_a_large_class_is_split_into_primitives(result: PlanResult, data: bytes,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """A class of more than PRIMITIVE_MAX_FACES faces takes several primitives of at most
    that many, in face order; they decode to the faces, colours and positions of the one
    primitive a larger limit gives."""
    whole_doc, whole_blob = chunks(data)
    sizes = [node["extras"]["faces"] for node in whole_doc["nodes"]
             if "face_class" in node.get("extras", {})]
    most = max(sizes) // 3 + 1  # the largest class gets three primitives
    monkeypatch.setattr(glb, "PRIMITIVE_MAX_FACES", most)
    split = glb.coverage_glb(result)
    split_doc, split_blob = chunks(split)
    counts = {mesh["name"]: [split_doc["accessors"][p["attributes"]["POSITION"]]["count"] // 3
                             for p in mesh["primitives"]] for mesh in split_doc["meshes"]}
    assert max(len(c) for c in counts.values()) == 3
    assert all(n <= most for c in counts.values() for n in c)
    assert split_doc["nodes"] == whole_doc["nodes"]
    whole, parts = class_faces(whole_doc, whole_blob), class_faces(split_doc, split_blob)
    assert whole.keys() == parts.keys()
    for name, arrays in whole.items():
        for a, b in zip(arrays, parts[name], strict=True):
            np.testing.assert_array_equal(a, b)
    # the property table is the same, wherever it lands in the file
    tables = [doc["extensions"]["EXT_structural_metadata"]["propertyTables"][0]["properties"]
              for doc in (whole_doc, split_doc)]
    for name in tables[0]:
        assert (view_bytes(whole_doc, whole_blob, tables[0][name]["values"])
                == view_bytes(split_doc, split_blob, tables[1][name]["values"]))


@pytest.fixture(scope="module")
def split_result() -> PlanResult:
    """A room of 8 x 6 x 3 m with a block in it, split at 0.25 m (about 20,000 faces from 24
    file faces), one station in a corner: walls and floor partly covered, at several LPDs,
    partly in the block's shadow."""
    room = trimesh.creation.box(extents=(8.0, 6.0, 3.0))
    room.apply_translation((4.0, 3.0, 1.5))
    room.invert()
    block = trimesh.creation.box(extents=(1.0, 2.0, 2.5))
    block.apply_translation((4.5, 3.0, 1.25))
    mesh = trimesh.util.concatenate([room, block])
    scene = dataclasses.replace(build_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
                                split_max_edge_m=0.25)
    return plan(scene, PlanSpec(candidates=((1.5, 1.5, 1.5),), max_edge_m=0.25))


def test_split_model_is_drawn_by_file_face_and_state(split_result: PlanResult) -> None:
    """Every face of faces.npz is in exactly one feature, the faces of a feature share their
    file face, class and LPD band, and the feature's triangles cover exactly their area in
    the colour of its worst face; the file holds a fraction of the faces' triangles."""
    result = split_result
    plain = glb.coverage_glb(result, compress=False)
    arrays = np.load(io.BytesIO(faces_npz(result)))
    classes = drawing.face_classes(arrays, result.limits.target)
    colours = glb.linear_bytes(drawing.face_rgb(arrays, result.limits.target,
                                                result.limits.min_density_pts_m2))
    ratio = arrays["best_lpd_pts_m2"] / result.limits.min_density_pts_m2
    bands = np.where(classes == drawing.COVERED,
                     np.clip(np.floor(np.log2(np.maximum(ratio, 1.0))), 0, glb.LPD_BANDS - 1), 0)
    document, blob = chunks(plain)
    columns, rows = property_table(document, blob)
    seen = np.zeros(result.scene.n_faces, int)
    for feature, members in enumerate(rows):
        seen[members] += 1
        for values in (arrays["source_face"], classes, bands):
            assert (values[members] == values[members[0]]).all()
        worst = members[np.argmin(ratio[members])]
        assert columns["face_class"][feature] == classes[worst]
        assert columns["source_face"][feature] == arrays["source_face"][worst]
        assert columns["best_lpd_pts_m2"][feature] == np.float32(arrays["best_lpd_pts_m2"][worst])
        assert columns["n_stations"][feature] == arrays["n_stations"][members].min()
        assert columns["n_candidates"][feature] == arrays["n_candidates"][members].min()
        assert columns["first_station"][feature] == arrays["first_station"][members].max()
    assert (seen == 1).all()  # every face in one feature
    assert len(rows) < result.scene.n_faces / 100  # one or a few features per file face
    assert len(np.unique(bands[classes == drawing.COVERED])) >= 3  # the shading is kept

    loaded = trimesh.load(io.BytesIO(plain), file_type="glb", process=False)
    step_m = document["scenes"][0]["extras"]["scanplan"]["position_step_m"]
    root_inverse = np.diag([1.0, 1.0, 1.0, 1.0])
    root_inverse[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # glTF Y-up -> model Z-up
    drawn_m2 = np.zeros(len(rows))
    triangles = 0
    for k, name in enumerate(drawing.CLASS_NAMES):
        if name not in loaded.geometry:
            assert not (classes == k).any()
            continue
        mesh = loaded.geometry[name]
        ids = mesh.vertex_attributes["_FEATURE_ID_0"].reshape(-1, 3)[:, 0].astype(int)
        assert (columns["face_class"][ids] == k).all()
        drawn = np.asarray(mesh.visual.vertex_attributes["color"]).reshape(-1, 3, 4)[:, 0, :3]
        worst = np.array([members[np.argmin(ratio[members])] for members in rows])
        assert (drawn == colours[worst[ids]]).all()
        corners = trimesh.transform_points(np.asarray(mesh.vertices, float),
                                           root_inverse @ loaded.graph[name][0]).reshape(-1, 3, 3)
        area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                             corners[:, 2] - corners[:, 0]), axis=1)
        np.add.at(drawn_m2, ids, area)
        triangles += len(ids)
    faces_m2 = np.array([result.scene.areas[members].sum() for members in rows])
    # within the positions' rounding: half a step along an outline
    outline_m = np.array([4 * math.sqrt(a) + 1.0 for a in faces_m2])
    assert (np.abs(drawn_m2 - faces_m2) <= outline_m * step_m).all()
    assert triangles < result.scene.n_faces / 5


def test_split_floor_is_drawn_by_group_in_each_piece_s_colour(
        split_result: PlanResult, monkeypatch: pytest.MonkeyPatch) -> None:
    """The pictures draw a split model's floor by group (the pieces of one file face with
    one colour): a fraction of the pieces' triangles, covering exactly each colour's
    pieces, and a preview that shows each piece's colour where the piece by piece drawing
    does, but for pixels on the edges between colours."""
    result = split_result
    (level,) = drawing.levels(result)
    below = drawing.floor_faces(result, level)
    floor = drawing.floor_of(result, level)
    assert 0 < len(floor.corners) < len(below) / 3
    rgb = drawing.face_rgb(result.faces, result.limits.target,
                           result.limits.min_density_pts_m2, below)
    assert len(np.unique(rgb, axis=0)) >= 10  # the shading is kept

    def colour_m2(corners_xy: np.ndarray, colours: np.ndarray) -> dict[bytes, float]:
        """The plan area of (t, 3, 2) triangles per colour."""
        a, b = corners_xy[:, 1] - corners_xy[:, 0], corners_xy[:, 2] - corners_xy[:, 0]
        area = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
        out: dict[bytes, float] = {}
        for colour, m2 in zip(colours, area, strict=True):
            out[colour.tobytes()] = out.get(colour.tobytes(), 0.0) + float(m2)
        return out

    drawn = colour_m2(floor.vertices[floor.corners][:, :, :2], floor.rgb)
    pieces = colour_m2(result.scene.vertices[result.scene.faces[below]][:, :, :2], rgb)
    assert drawn.keys() == pieces.keys()
    for colour, m2 in pieces.items():
        assert drawn[colour] == pytest.approx(m2, rel=1e-9)

    grouped = decode(drawing.preview_png(result))

    def piece_by_piece(scene: Any, below: np.ndarray, rgb: np.ndarray,
                       height_m: np.ndarray) -> drawing.Floor:
        return drawing.Floor(scene.vertices, scene.faces[below], rgb, height_m)

    monkeypatch.setattr(drawing, "_FLOORS", drawing._PerPlan())  # nothing made yet
    monkeypatch.setattr(drawing, "_grouped_floor", piece_by_piece)
    pieces_image = decode(drawing.preview_png(result))
    assert np.any(grouped != pieces_image, axis=2).mean() < 0.02
    (ax,) = drawing.draw_preview(result).axes
    at = np.rint(pixel_of(ax, result.scene.centroids[below, :2],
                          grouped.shape[1::-1])).astype(int)
    shown = np.all(grouped[at[:, 1], at[:, 0]] == rgb, axis=1)
    shown_before = np.all(pieces_image[at[:, 1], at[:, 0]] == rgb, axis=1)
    assert shown.mean() >= shown_before.mean() - 0.01


def test_split_model_same_bytes_twice(split_result: PlanResult) -> None:
    assert glb.coverage_glb(split_result) == glb.coverage_glb(split_result)


def _outline_check(scene: Any, labels: np.ndarray) -> tuple[int, list[int]]:
    """Group ``scene``'s faces by source face and ``labels`` as coverage.glb does, outline
    the groups of several faces that are not a whole file face, and check each outlined
    group's triangles: corners among its faces' vertices, wound as its faces, covering
    exactly their area once. Returns the triangles made and the groups left to _merge."""
    import shapely

    key = scene.source_face.astype(np.int64) * 64 + labels
    rows = np.argsort(key, kind="stable").astype(np.int32)
    offsets = np.append(np.flatnonzero(np.diff(key[rows], prepend=-1)), len(key))
    first = rows[offsets[:-1]]
    counts = np.diff(offsets)
    whole = counts == np.bincount(scene.source_face)[scene.source_face[first]]
    chosen = np.flatnonzero(~whole & (counts > 1))
    features, triangles, to_merge = outline._outlined(scene, rows, offsets, first, chosen)
    assert (np.diff(features) >= 0).all() and set(features) <= set(chosen)
    axes = [0, 1]  # the test scenes lie in z = 0
    for feature in sorted(set(chosen) - set(to_merge)):
        members = rows[offsets[feature]:offsets[feature + 1]]
        mine = triangles[features == feature]
        assert np.isin(mine, scene.faces[members]).all()
        corners = scene.vertices[mine]
        normal = scene.normals[members[0]]
        assert (outline._cross(corners) @ normal > 0).all()
        flat = corners[:, :, axes]
        drawn = shapely.polygons(np.concatenate([flat, flat[:, :1]], axis=1))
        pieces = scene.vertices[scene.faces[members]][:, :, axes]
        union = shapely.union_all(shapely.polygons(np.concatenate([pieces, pieces[:, :1]],
                                                                  axis=1)))
        assert shapely.area(drawn).sum() == pytest.approx(union.area, rel=1e-9)
        assert shapely.symmetric_difference(shapely.union_all(drawn), union).area < 1e-9
    return len(triangles), sorted(int(f) for f in to_merge)


def _split_square(edge_m: float) -> Any:
    """A 4 m square of two triangles in z = 0, split into pieces of ``edge_m``."""
    from planner.scene import remesh

    vertices = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [4.0, 4.0, 0.0], [0.0, 4.0, 0.0]])
    return remesh(build_scene(vertices, np.array([[0, 1, 2], [0, 2, 3]])), edge_m)


def _loops(scene: Any, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per group of faces of one label (of several faces): its outer loops and its holes."""
    rows = np.argsort(labels, kind="stable").astype(np.int32)
    offsets = np.append(np.flatnonzero(np.diff(labels[rows], prepend=-1)), len(labels))
    chosen = np.flatnonzero(np.diff(offsets) > 1)
    axes = np.tile(np.array([0, 1], np.int64), (len(chosen), 1))
    _, _, feature, shell, status, _ = outline._outlines(scene.faces, rows, offsets, chosen,
                                                        scene.vertices, axes,
                                                        outline._COLLINEAR_M)
    assert (status == 0).all()
    hole = shell != np.arange(len(shell))
    return (np.bincount(feature[~hole], minlength=len(chosen)),
            np.bincount(feature[hole], minlength=len(chosen)))


@pytest.mark.parametrize("pattern", ["checkerboard", "blobs", "random"])
def test_outlines_of_pieces(pattern: str) -> None:
    """Outlines that touch themselves at corners (a checkerboard), outer loops with holes
    and islands in them (blobs), ragged groups: every group is outlined, none left to
    shapely's union, its triangles cover exactly its faces, fewer of them than faces."""
    scene = _split_square(0.3)
    centre = scene.centroids
    if pattern == "checkerboard":
        cells = np.floor(centre[:, :2] / 0.5).astype(np.int64)
        labels = (cells.sum(axis=1) % 2).astype(np.int64)
    elif pattern == "blobs":
        r = np.hypot(centre[:, 0] - 2.0, centre[:, 1] - 2.0)
        labels = ((np.sin(r * 4.0) > 0) ^ (np.sin(centre[:, 0] * 5) * np.sin(centre[:, 1] * 5)
                                            > 0.6)).astype(np.int64)
    else:
        labels = np.random.default_rng(0).integers(0, 3, scene.n_faces)
    made, left = _outline_check(scene, labels)
    assert left == []
    assert made < scene.n_faces / (2 if pattern == "blobs" else 3 if pattern == "checkerboard"
                                   else 1)
    shells, holes = _loops(scene, scene.source_face.astype(np.int64) * 64 + labels)
    if pattern == "checkerboard":  # squares that touch at their corners: one loop each
        assert shells.max() >= 16 and holes.sum() == 0
    if pattern == "blobs":  # several outer loops and holes in one group
        assert ((shells > 1) & (holes > 0)).any()


def test_outline_with_a_t_junction() -> None:
    """Pieces that meet a neighbour's edge in its middle (remesh does not split so) still
    give triangles that cover exactly their area."""
    vertices = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 2.0, 0.0], [0.0, 2.0, 0.0],
                         [1.0, 1.0, 0.0], [3.0, 0.0, 0.0]])
    faces = np.array([[0, 1, 3], [1, 2, 4], [4, 2, 3], [1, 5, 2]])
    scene = dataclasses.replace(build_scene(vertices, faces),
                                source_face=np.zeros(4, np.int32),
                                file_vertices=vertices, file_faces=np.array([[0, 5, 3]]),
                                file_face_group=np.zeros(1, np.int32),
                                file_face_element=np.full(1, -1, np.int32))
    assert _outline_check(scene, np.array([0, 0, 0, 1])) == (2, [])  # the square


def test_features_sorted_a_file_face_at_a_time_are_those_of_the_sort_of_every_face() -> None:
    """A split scene keeps each file face's pieces together, so its features (the faces by
    file face, then state, stably) are sorted one file face's run at a time: the same rows
    and feature starts as a stable sort of every face's key; a scene whose file faces are
    not in order is told apart and sorted whole."""
    from planner.outputs.glb import _features_by_face

    rng = np.random.default_rng(2)
    source = np.sort(rng.integers(0, 400, 20_000)).astype(np.int32)
    state = rng.integers(0, 16, len(source)).astype(np.uint8)
    state[source % 7 == 0] = 3  # file faces of one state: one feature each
    rows = np.empty(len(source), np.int32)
    n_features = _features_by_face(source, state, 16, rows, np.zeros(0, np.int64), False)
    offsets = np.empty(n_features + 1, np.int64)
    _features_by_face(source, state, 16, rows, offsets, True)
    key = source.astype(np.int64) * 16 + state
    order = np.argsort(key, kind="stable")
    assert np.array_equal(rows, order)
    starts = np.flatnonzero(np.diff(key[order], prepend=-1))
    assert np.array_equal(offsets, np.append(starts, len(source)))
    shuffled = source.copy()
    shuffled[[10, 15_000]] = shuffled[[15_000, 10]]
    assert _features_by_face(shuffled, state, 16, rows, offsets, False) == -1
