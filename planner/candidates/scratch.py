"""What the candidate stage derives from the scene alone, made once and reused by its steps.

Grid candidates look at the same scene several times: the lowest floor and then every
storey, at every scanner height. Each look tests points against the winding-number cells of
the model's closed groups (:mod:`planner.candidates.winding`) and keeps the points near the
building by a tree of the building's upright samples (:func:`planner.candidates.grid.\
on_the_building`); the cells and the tree depend on the scene (and the plan's targets)
alone. Within :func:`stage_scratch` they are made at the first look and reused; the block's
end drops them, so none of it stays in memory for the stages after the candidates. Outside
such a block nothing is kept (a tripod's displaced setups, tested later, make their own).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

from planner.scene import Scene

T = TypeVar("T")

_SCRATCH: weakref.WeakKeyDictionary[Scene, dict[Hashable, Any]] = weakref.WeakKeyDictionary()


@contextmanager
def stage_scratch(scene: Scene) -> Iterator[None]:
    """Within the block, :func:`reused` keeps what it makes for ``scene``; dropped at its
    end."""
    _SCRATCH[scene] = {}
    try:
        yield
    finally:
        _SCRATCH.pop(scene, None)


def reused(scene: Scene, key: Hashable, make: Callable[[], T]) -> T:
    """``make()``, made once per ``key`` within :func:`stage_scratch` of ``scene`` (every
    call outside one). ``make`` must depend on the scene and ``key`` alone."""
    kept = _SCRATCH.get(scene)
    if kept is None:
        return make()
    if key not in kept:
        kept[key] = make()
    value: T = kept[key]
    return value


def kept_or_none(scene: Scene, key: Hashable) -> Any:
    """What :func:`reused` keeps for ``key`` (None when nothing is, or outside a block)."""
    kept = _SCRATCH.get(scene)
    return None if kept is None else kept.get(key)


def keep(scene: Scene, key: Hashable, value: Any) -> None:
    """Keep ``value`` for ``key`` within :func:`stage_scratch` of ``scene`` (outside one,
    nothing is kept)."""
    kept = _SCRATCH.get(scene)
    if kept is not None:
        kept[key] = value
