"""scanplan's planner: ``planner.read_scene(path)``, then ``planner.plan(scene, spec)``.

The public names are loaded on first use (PEP 562 module ``__getattr__``): importing
``planner`` or one light module of it (``planner.errors``, ``planner.parameters``) does not
pull in trimesh, scipy, numba or Embree, so ``scanplan --help`` starts at once.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from planner.version import __version__

if TYPE_CHECKING:  # for type checkers and editors; at run time __getattr__ loads them
    from planner.errors import PlannerError
    from planner.io.readers import read_scene
    from planner.outputs.report import write_outputs
    from planner.parameters import PlanSpec
    from planner.pipeline import PlanResult, plan

# public name -> the module that defines it
_EXPORTS = {
    "plan": "planner.pipeline",
    "PlanResult": "planner.pipeline",
    "read_scene": "planner.io.readers",
    "PlanSpec": "planner.parameters",
    "PlannerError": "planner.errors",
    "write_outputs": "planner.outputs.report",
}

__all__ = ["PlanResult", "PlanSpec", "PlannerError", "__version__", "plan", "read_scene",
           "write_outputs"]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'planner' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
