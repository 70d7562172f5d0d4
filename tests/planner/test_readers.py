"""Reading models: formats sniffed from bytes, face order kept, groups kept, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from planner.errors import SceneError, UnsupportedFormatError
from planner.io.readers import read_scene, sniff_format
from planner.scene import remesh

OBJ = """# two groups
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
g floor
f 1 2 3 4
g wall
f 1 2 5
"""


def write(tmp_path: Path, name: str, data: bytes | str) -> Path:
    path = tmp_path / name
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


def test_obj_groups_and_face_order(tmp_path: Path) -> None:
    scene = read_scene(write(tmp_path, "m.obj", OBJ), max_edge_m=None)
    assert scene.n_faces == 3  # the quad becomes two triangles
    assert scene.groups == ("floor", "wall")
    assert scene.face_group.tolist() == [0, 0, 1]
    assert scene.areas.sum() == pytest.approx(1.5)


def test_format_comes_from_the_bytes_not_the_name(tmp_path: Path) -> None:
    scene = read_scene(write(tmp_path, "model.bin", OBJ), max_edge_m=None)
    assert scene.metadata["format"] == "obj"


@pytest.mark.parametrize("file_type", ["stl", "ply", "off", "glb"])
def test_other_formats_load_with_the_same_geometry(tmp_path: Path, file_type: str) -> None:
    mesh = trimesh.creation.box(extents=(2.0, 3.0, 4.0))
    path = tmp_path / f"box.{file_type}"
    mesh.export(path)
    scene = read_scene(path, max_edge_m=None)
    assert scene.metadata["format"] == file_type
    assert scene.n_faces == 12
    assert scene.areas.sum() == pytest.approx(mesh.area)


def test_glb_node_names_become_groups(tmp_path: Path) -> None:
    world = trimesh.Scene()
    world.add_geometry(trimesh.creation.box(extents=(1, 1, 1)), node_name="column")
    world.add_geometry(trimesh.creation.icosphere(), node_name="tank",
                       transform=trimesh.transformations.translation_matrix([3, 0, 0]))
    path = tmp_path / "plant.glb"
    world.export(path)
    scene = read_scene(path, max_edge_m=None)
    assert set(scene.groups) == {"column", "tank"}
    tank = scene.face_group == scene.groups.index("tank")
    assert scene.centroids[tank, 0].mean() == pytest.approx(3.0, abs=0.05)


def test_ply_class_ids_are_groups_named_from_the_elements_table(scenes_dir: Path) -> None:
    scene = read_scene(scenes_dir / "AC20-FZK-Haus.ply", max_edge_m=None)
    assert scene.n_faces == 21_668
    counts = dict(zip(scene.groups, np.bincount(scene.face_group), strict=True))
    assert counts["IfcRailing"] == 7_776
    assert counts["IfcSite"] == 48


def test_unit_scale_turns_millimetres_into_metres(tmp_path: Path) -> None:
    in_mm = "\n".join(
        "v " + " ".join(str(float(c) * 1000) for c in line.split()[1:])
        if line.startswith("v ") else line
        for line in OBJ.splitlines()
    )
    path = write(tmp_path, "mm.obj", in_mm)
    scene = read_scene(path, max_edge_m=None, unit_scale=0.001)
    assert scene.bounds[1].tolist() == pytest.approx([1.0, 1.0, 1.0])


def test_remeshing_keeps_a_map_to_the_source_faces(tmp_path: Path) -> None:
    scene = read_scene(write(tmp_path, "m.obj", OBJ), max_edge_m=0.2)
    edges = scene.triangles - np.roll(scene.triangles, 1, axis=1)
    assert np.linalg.norm(edges, axis=2).max() <= 0.2 + 1e-9
    # every source face's area is preserved by its pieces
    source_area = np.bincount(scene.source_face, weights=scene.areas)
    assert source_area == pytest.approx([0.5, 0.5, 0.5])
    assert (np.diff(scene.source_face) >= 0).all()  # pieces stay in the file's order
    assert scene.groups[scene.face_group[-1]] == "wall"
    assert remesh(scene, 10.0) is scene


def test_a_scene_read_to_be_split_as_needed_is_the_file_with_the_split_still_to_do(
        tmp_path: Path) -> None:
    """The faces, their centroids, normals and areas are the file's, as read whole."""
    path = write(tmp_path, "m.obj", OBJ)
    whole = read_scene(path, max_edge_m=None)
    later = read_scene(path, max_edge_m=0.2, split_faces="as_needed")
    assert later.split_max_edge_m == 0.2 and whole.split_max_edge_m is None
    for name in ("vertices", "faces", "centroids", "normals", "areas", "source_face"):
        assert np.array_equal(getattr(later, name), getattr(whole, name)), name
    assert remesh(later, 10.0).split_max_edge_m is None  # nothing longer: the faces are final
    with pytest.raises(ValueError, match="vertices and faces"):
        later.replaced(faces=later.faces[:1])


@pytest.mark.parametrize(
    ("name", "data", "error", "words"),
    [
        ("empty.obj", b"", SceneError, "empty"),
        ("noise.bin", bytes(range(256)) * 8, UnsupportedFormatError, "not a model format"),
        ("notes.txt", "meeting notes\nnothing here\n", UnsupportedFormatError, "obj, ply"),
        ("nan.obj", "v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", SceneError, "non-finite"),
        ("nofaces.obj", "v 0 0 0\nv 1 0 0\n", SceneError, "no triangles"),
        ("cut.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n", SceneError, "vertex"),
    ],
)
def test_broken_files_raise_clear_errors(tmp_path: Path, name: str, data: bytes | str,
                                         error: type[Exception], words: str) -> None:
    with pytest.raises(error, match=words):
        read_scene(write(tmp_path, name, data), max_edge_m=None)


def test_sniffing() -> None:
    assert sniff_format(b"ISO-10303-21;\nHEADER;") == "ifc"
    assert sniff_format(b"ply\nformat binary_little_endian 1.0\n") == "ply"
    assert sniff_format(b"glTF\x02\x00\x00\x00") == "glb"
    assert sniff_format(b"OFF\n3 1 0\n") == "off"
    assert sniff_format(b"solid x\n facet normal 0 0 1\n") == "stl"
    assert sniff_format(b"\x89PNG\r\n\x1a\n") is None
