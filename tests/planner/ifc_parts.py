"""Building IFC test models with ifcopenshell.api: one placed product at a time."""

from __future__ import annotations

from typing import Any

import numpy as np


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
