"""The generated benchmark office (benchmarks/ifc_office.py) is the building it claims to be."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from planner.io.ifc import read_ifc

ROOT = Path(__file__).resolve().parents[2]


def _office_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("ifc_office", ROOT / "benchmarks" /
                                                  "ifc_office.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_small_office_has_storeys_rooms_doors_and_a_stair(tmp_path: Path) -> None:
    office = _office_module()
    first = office.build_ifc_office(tmp_path / "a.ifc", storeys=2, width_m=12.0, depth_m=20.0)
    again = office.build_ifc_office(tmp_path / "b.ifc", storeys=2, width_m=12.0, depth_m=20.0)
    assert first.read_bytes() == again.read_bytes()  # deterministic

    scene = read_ifc(first)
    assert [s["elevation_m"] for s in scene.metadata["storeys"]] == [0.0, 3.5]
    names = [s["long_name"] for s in scene.metadata["spaces"]]
    # per storey: the corridor, two bays on each side, one of them the stair core
    assert sum(n.startswith("Corridor") for n in names) == 2
    assert sum(n.startswith("Office") for n in names) == 6
    assert sum(n.startswith("Stair core") for n in names) == 2
    classes = [e.ifc_class for e in scene.elements]
    assert classes.count("IfcDoor") == 2 * 4 + 1  # a door per room, the entrance
    assert classes.count("IfcStairFlight") == 1
    assert classes.count("IfcFurniture") > 20

    def bounds(name: str) -> np.ndarray:
        index = next(i for i, e in enumerate(scene.elements) if e.name == name)
        points = scene.vertices[scene.faces[scene.face_element == index]].reshape(-1, 3)
        return np.stack([points.min(axis=0), points.max(axis=0)])

    flight = next(e.name for e in scene.elements if e.ifc_class == "IfcStairFlight")
    low, high = bounds(flight)
    assert low[2] == pytest.approx(0.0, abs=1e-6) and high[2] == pytest.approx(3.5, abs=1e-6)
    core = next(s for s in scene.metadata["spaces"] if s["long_name"] == "Stair core L0")
    xy = np.asarray(core["polygon"])
    assert (xy.min(axis=0) <= low[:2]).all() and (high[:2] <= xy.max(axis=0)).all()
    # a door leaf is closed: it stays within its wall's thickness (0.12 m plus the lining)
    low, high = bounds("Door L1-S00")
    assert high[1] - low[1] < 0.2 and low[2] == pytest.approx(3.5, abs=1e-6)


def test_office_in_ifc2x3_reads_with_the_same_rooms(tmp_path: Path) -> None:
    path = _office_module().build_ifc_office(tmp_path / "office.ifc", storeys=2, width_m=12.0,
                                             depth_m=20.0, schema="IFC2X3")
    scene = read_ifc(path)
    assert scene.metadata["schema"] == "IFC2X3"
    assert [s["elevation_m"] for s in scene.metadata["storeys"]] == [0.0, 3.5]
    assert len(scene.metadata["spaces"]) == 10
    classes = [e.ifc_class for e in scene.elements]
    assert classes.count("IfcFurnishingElement") > 20 and "IfcStairFlight" in classes
