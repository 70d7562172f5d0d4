"""Where the tests' models and reference files come from, with nothing beside the checkout.

The halls and the IfcOpenHouse IFC ship in the package (``planner/example_data``), the BCF
schemas and the FZK-Haus reference triangulation live in ``tests/data``; the larger public
models are found by :mod:`planner.examples` (the ``SCANPLAN_DATA_MIRROR`` directory, the
cache, or a download checked by its sha256). :func:`scenes_layout` puts them all in one
directory laid out as the team's scenes folder, which the tests read.
"""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path

from planner.examples import FILES, MIRROR_VARIABLE, DataMissingError, find

DATA = Path(__file__).resolve().parent / "data"
BCF_XSD = DATA / "bcf-3.0"
HALL_SMALL = find("hall-small/hall.obj").parent
HALL_FULL = find("hall-full/hall.obj").parent
# the files of tests/data that sit in the scenes layout (the rest are standards)
_REFERENCE = ("AC20-FZK-Haus.obj", "AC20-FZK-Haus.ply", "AC20-FZK-Haus.elements.json",
              "AC20-FZK-Haus.spaces.ply", "IfcOpenHouse_IFC4.obj", "IfcOpenHouse_IFC4.ply",
              "IfcOpenHouse_IFC4.elements.json")


@functools.cache
def scenes_layout() -> Path:
    """A directory of links laid out as the team's scenes folder: every model the tests
    use. :class:`DataMissingError` lists what could not be found and names
    ``SCANPLAN_DATA_MIRROR``."""
    root = Path(tempfile.mkdtemp(prefix="scanplan-scenes-"))
    missing = []
    for path in FILES:
        try:
            source = find(path)
        except DataMissingError as exc:
            missing.append(str(exc))
            continue
        _link(root / path, source)
    for name in _REFERENCE:
        _link(root / name, DATA / name)
    if missing:
        raise DataMissingError(
            f"{len(missing)} test model(s) missing; set {MIRROR_VARIABLE} to a directory "
            "laid out as the scenes folder (CI: ../shared/scenes) or give this machine "
            "internet access:\n" + "\n".join(missing))
    return root


def _link(target: Path, source: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    target.symlink_to(source.resolve())
