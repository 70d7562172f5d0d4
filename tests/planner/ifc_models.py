"""The shared IFC models as IfcOpenShell reads them, once a session for every module.

Reading FZK-Haus takes seconds; test_ifc and test_buildings both need it as read. Callers
share the returned scene: they derive new scenes from it (``dataclasses.replace``,
``remesh``) and never change it.
"""

from __future__ import annotations

import functools
from pathlib import Path

from planner.scene import Scene


@functools.cache
def read_ifc_once(path: Path) -> Scene:
    """``planner.io.ifc.read_ifc(path)``, read on the first call only."""
    from planner.io.ifc import read_ifc

    return read_ifc(path)
