"""Small hand-made scenes for exact tests (metres, +Z up)."""

from __future__ import annotations

import numpy as np

from planner.scene import Scene, build_scene


def square(centre: tuple[float, float, float], size_m: float, normal_axis: int,
           ) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles of a square facing along ``normal_axis`` (0 x, 1 y, 2 z)."""
    h = size_m / 2
    u, v = [a for a in range(3) if a != normal_axis]
    corners = np.zeros((4, 3))
    for i, (du, dv) in enumerate([(-h, -h), (h, -h), (h, h), (-h, h)]):
        corners[i] = centre
        corners[i, u] += du
        corners[i, v] += dv
    return corners, np.array([[0, 1, 2], [0, 2, 3]])


def scene_of(*parts: tuple[np.ndarray, np.ndarray], groups: list[str] | None = None) -> Scene:
    vertices, faces, labels = [], [], []
    offset = 0
    for i, (v, f) in enumerate(parts):
        vertices.append(v)
        faces.append(f + offset)
        labels.extend([i] * len(f))
        offset += len(v)
    names = tuple(groups) if groups else tuple(f"part{i}" for i in range(len(parts)))
    return build_scene(np.concatenate(vertices), np.concatenate(faces), np.array(labels), names)


def small_triangle(at: tuple[float, float, float], normal: tuple[float, float, float],
                   size_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """A tiny equilateral triangle centred on ``at`` with the given normal."""
    n = np.asarray(normal, float)
    n /= np.linalg.norm(n)
    helper = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    corners = [np.asarray(at) + size_m * (np.cos(a) * e1 + np.sin(a) * e2)
               for a in (0, 2 * np.pi / 3, 4 * np.pi / 3)]
    # counter-clockwise seen from the normal's side
    return np.array(corners), np.array([[0, 1, 2]])
