"""Hand-made buildings of solid boxes for the survey tests (metres, +Z up)."""

from __future__ import annotations

import numpy as np
import trimesh

from planner.scene import Scene, build_scene, remesh

Box = tuple[tuple[float, float, float], tuple[float, float, float]]


def boxes_scene(boxes: list[Box], max_edge_m: float = 0.5) -> Scene:
    """The union (not merged) of axis-aligned boxes (lowest, highest corner), remeshed."""
    vertices, faces = [], []
    offset = 0
    for lo, hi in boxes:
        box = trimesh.creation.box(bounds=np.array([lo, hi], float))
        vertices.append(np.asarray(box.vertices))
        faces.append(np.asarray(box.faces) + offset)
        offset += len(box.vertices)
    scene = build_scene(np.concatenate(vertices), np.concatenate(faces))
    return remesh(scene, max_edge_m)


def room_shell(x0: float, x1: float, y0: float, y1: float, height_m: float = 2.5,
               wall_m: float = 0.2) -> list[Box]:
    """Floor slab, ceiling slab and four closed walls around [x0, x1] x [y0, y1]."""
    t, h = wall_m, height_m
    return [((x0 - t, y0 - t, -t), (x1 + t, y1 + t, 0.0)),
            ((x0 - t, y0 - t, h), (x1 + t, y1 + t, h + t)),
            ((x0 - t, y0 - t, 0.0), (x0, y1 + t, h)),
            ((x1, y0 - t, 0.0), (x1 + t, y1 + t, h)),
            ((x0, y0 - t, 0.0), (x1, y0, h)),
            ((x0, y1, 0.0), (x1, y1 + t, h))]


# two 4 x 4 m rooms side by side, joined by a 0.9 m door in the corner of the shared wall
DOOR_Y_M = (0.3, 1.2)


def two_rooms(closet: bool = False) -> Scene:
    """Room A [0, 4] x [0, 4], room B [4.2, 8.2] x [0, 4]; ``closet``: a sealed third room
    [10, 12] x [0, 2] nobody can walk into."""
    h = 2.5
    boxes = [((-0.2, -0.2, -0.2), (8.4, 4.2, 0.0)), ((-0.2, -0.2, h), (8.4, 4.2, h + 0.2)),
             ((-0.2, -0.2, 0.0), (0.0, 4.2, h)), ((8.2, -0.2, 0.0), (8.4, 4.2, h)),
             ((0.0, -0.2, 0.0), (8.2, 0.0, h)), ((0.0, 4.0, 0.0), (8.2, 4.2, h)),
             # the shared wall, with its door
             ((4.0, 0.0, 0.0), (4.2, DOOR_Y_M[0], h)), ((4.0, DOOR_Y_M[1], 0.0), (4.2, 4.0, h)),
             ((4.0, DOOR_Y_M[0], 2.1), (4.2, DOOR_Y_M[1], h))]
    if closet:
        boxes += room_shell(10.0, 12.0, 0.0, 2.0)
    return boxes_scene(boxes)


def two_room_candidates() -> tuple[tuple[float, float, float], ...]:
    """A 1 m grid at scanner height in both rooms."""
    xs = [1.0, 2.0, 3.0, 5.2, 6.2, 7.2]
    return tuple((x, y, 1.5) for x in xs for y in (1.0, 2.0, 3.0))


STAIR_RISE_M = 0.2
STAIR_TREAD_M = 0.25
MEZZANINE_Z_M = 2.2


def staircase() -> Scene:
    """A 6 x 3 m hall with a mezzanine (x >= 2.75, top at 2.2 m) reached by an 11-step
    straight stair along +x in the strip y in [0, 1.2]."""
    boxes = room_shell(0.0, 6.0, 0.0, 3.0, height_m=5.0)
    steps = round(MEZZANINE_Z_M / STAIR_RISE_M)
    for i in range(steps):
        x0 = 2.75 - (steps - i) * STAIR_TREAD_M
        boxes.append(((x0, 0.0, 0.0), (x0 + STAIR_TREAD_M, 1.2, (i + 1) * STAIR_RISE_M)))
    boxes.append(((2.75, 0.0, MEZZANINE_Z_M - 0.2), (6.0, 3.0, MEZZANINE_Z_M)))
    return boxes_scene(boxes)
