"""Building IFC test models with ifcopenshell.api: one placed product at a time."""

from __future__ import annotations

from typing import Any

import numpy as np


def body_and_building(model: Any, ifc_project: Any) -> tuple[Any, Any]:
    """The body context of ``model`` and its building, in a site under ``ifc_project``."""
    from ifcopenshell.api import aggregate, context, root

    body = context.add_context(
        model, context_type="Model", context_identifier="Body", target_view="MODEL_VIEW",
        parent=context.add_context(model, context_type="Model"))
    site = root.create_entity(model, ifc_class="IfcSite", name="Site")
    building = root.create_entity(model, ifc_class="IfcBuilding", name="Building")
    aggregate.assign_object(model, relating_object=ifc_project, products=[site])
    aggregate.assign_object(model, relating_object=site, products=[building])
    return body, building


def placed(model: Any, ifc_class: str, name: str, representation: Any,
           xyz: tuple[float, float, float], turn: float = 0.0) -> Any:
    """A new ``ifc_class`` product of ``model`` at ``xyz`` (metres), turned by ``turn``
    radians about +Z, with ``representation``."""
    from ifcopenshell.api import geometry, root

    product = root.create_entity(model, ifc_class=ifc_class, name=name)
    matrix = np.eye(4)
    matrix[:2, :2] = [[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]]
    matrix[:3, 3] = xyz
    geometry.edit_object_placement(model, product=product, matrix=matrix, is_si=True)
    geometry.assign_representation(model, product=product, representation=representation)
    return product


def room_shell(model: Any, body: Any, storey: Any, width_m: float, depth_m: float,
               floor_m: float, height_m: float) -> None:
    """A ``width_m`` x ``depth_m`` room from the origin in ``storey``: floor and ceiling
    slabs 0.2 m thick (the floor's top at ``floor_m``, the ceiling's underside
    ``height_m`` above it) and four 0.2 m walls ``height_m`` high."""
    from ifcopenshell.api import geometry, spatial

    outline = [(0.0, 0.0), (width_m, 0.0), (width_m, depth_m), (0.0, depth_m)]
    parts = [
        placed(model, "IfcSlab", "Floor", geometry.add_slab_representation(
            model, body, depth=0.2, polyline=outline), (0, 0, floor_m - 0.2)),
        placed(model, "IfcSlab", "Ceiling", geometry.add_slab_representation(
            model, body, depth=0.2, polyline=outline), (0, 0, floor_m + height_m)),
    ]
    for name, length, x, y, turn in [
            ("South", width_m, 0.0, 0.0, 0.0), ("East", depth_m, width_m, 0.0, 0.5),
            ("North", width_m, width_m, depth_m, 1.0), ("West", depth_m, 0.0, depth_m, 1.5)]:
        parts.append(placed(model, "IfcWall", name, geometry.add_wall_representation(
            model, body, length=length, height=height_m, thickness=0.2), (x, y, floor_m),
            turn * np.pi))
    spatial.assign_container(model, relating_structure=storey, products=parts)
