"""A deterministic cluttered interior: room-sized triangles beside millimetre props.

Stands in for furnished scans and CAD kitchens users send: a galley kitchen of 11 x 4 x 2.7
m whose floor, ceiling and walls are two triangles each (edges of 2.7 to 11.7 m), counters
along both long walls and wall cabinets above them as coarse boxes, and on the counters
finely tessellated props (fruit and bowls as spheres; cups, pots and bottles as cylinders)
with edges of about 2 mm, until the model holds ``--faces`` triangles (default 1.0 M:
1,057,393). The median edge is then 2.0 mm and the longest 11.7 m: room-sized faces split
into many pieces beside a million file faces that stay whole.

Binary little-endian PLY, metres, Z up. The same arguments always give the same bytes.

    .venv/bin/python benchmarks/cluttered_interior.py OUT.ply [--faces 1000000] [--seed 5]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

ROOM_M = (11.0, 4.0, 2.7)
COUNTER_DEPTH_M, COUNTER_HEIGHT_M = 0.6, 0.9
PROP_EDGE_M = 0.002

Mesh = tuple[NDArray[np.float64], NDArray[np.int64]]


def _quad(a: tuple[float, ...], b: tuple[float, ...], c: tuple[float, ...],
          d: tuple[float, ...]) -> Mesh:
    """Two triangles a-b-c, a-c-d (counter-clockwise seen from the front)."""
    return np.array([a, b, c, d], float), np.array([[0, 1, 2], [0, 2, 3]])


def _box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> Mesh:
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]])
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                  [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    return v, f


def _grid_faces(rows: int, cols: int, wrap: bool) -> NDArray[np.int64]:
    """Triangles of a (rows + 1) x cols vertex grid, columns wrapping around when ``wrap``."""
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    c1 = (c + 1) % cols if wrap else c + 1
    width = cols if wrap else cols + 1
    a, b = r * width + c, r * width + c1
    d, e = (r + 1) * width + c, (r + 1) * width + c1
    return np.concatenate([np.stack([a, b, e], -1).reshape(-1, 3),
                           np.stack([a, e, d], -1).reshape(-1, 3)])


def _sphere(centre: NDArray[np.float64], radius: float) -> Mesh:
    """A UV sphere with edges of about :data:`PROP_EDGE_M` (poles as tiny rings)."""
    segments = max(8, math.ceil(2 * math.pi * radius / PROP_EDGE_M))
    rings = max(4, segments // 2)
    polar = np.linspace(0.02, math.pi - 0.02, rings + 1)
    azimuth = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    p, a = np.meshgrid(polar, azimuth, indexing="ij")
    v = np.stack([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), -np.cos(p)], -1)
    return centre + radius * v.reshape(-1, 3), _grid_faces(rings, segments, True)


def _cylinder(base: NDArray[np.float64], radius: float, height: float) -> Mesh:
    """An open-topped upright cylinder (a cup, a pot) with edges of about
    :data:`PROP_EDGE_M`, its bottom a disc of rings of the same pitch."""
    segments = max(8, math.ceil(2 * math.pi * radius / PROP_EDGE_M))
    rows = max(1, math.ceil(height / PROP_EDGE_M))
    z = np.linspace(0.0, height, rows + 1)
    azimuth = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    zz, a = np.meshgrid(z, azimuth, indexing="ij")
    side = np.stack([radius * np.cos(a), radius * np.sin(a), zz], -1).reshape(-1, 3)
    side_faces = _grid_faces(rows, segments, True)
    rings = max(1, math.ceil(radius / PROP_EDGE_M))
    rr, a = np.meshgrid(np.linspace(radius / rings, radius, rings), azimuth, indexing="ij")
    disc = np.stack([rr * np.cos(a), rr * np.sin(a), np.zeros_like(rr)], -1).reshape(-1, 3)
    disc_faces = _grid_faces(rings - 1, segments, True)[:, ::-1] if rings > 1 else \
        np.zeros((0, 3), np.int64)
    centre_fan = np.stack([np.full(segments, len(disc)), (np.arange(segments) + 1) % segments,
                           np.arange(segments)], -1)
    v = np.concatenate([side, disc, np.zeros((1, 3))]) + base
    f = np.concatenate([side_faces, disc_faces + len(side), centre_fan + len(side)])
    return v, f


def build(faces: int = 1_000_000, seed: int = 5) -> Mesh:
    """The room, its counters and enough props for ``faces`` triangles (a few more)."""
    rng = np.random.default_rng(seed)
    lx, ly, lz = ROOM_M
    parts: list[Mesh] = [
        _quad((0, 0, 0), (lx, 0, 0), (lx, ly, 0), (0, ly, 0)),  # floor, facing up
        _quad((0, 0, lz), (0, ly, lz), (lx, ly, lz), (lx, 0, lz)),  # ceiling, facing down
        _quad((0, 0, 0), (0, 0, lz), (lx, 0, lz), (lx, 0, 0)),  # wall y = 0, facing +y
        _quad((0, ly, 0), (lx, ly, 0), (lx, ly, lz), (0, ly, lz)),  # wall y = ly
        _quad((0, 0, 0), (0, ly, 0), (0, ly, lz), (0, 0, lz)),  # wall x = 0
        _quad((lx, 0, 0), (lx, 0, lz), (lx, ly, lz), (lx, ly, 0)),  # wall x = lx
    ]
    d, h = COUNTER_DEPTH_M, COUNTER_HEIGHT_M
    # counters along the two long walls: where props stand
    surfaces = [(0.0, 0.0, lx, d), (0.0, ly - d, lx, ly)]
    for x0, y0, x1, y1 in surfaces:
        parts.append(_box((x0, y0, 0.0), (x1, y1, h)))
    # wall cabinets above the long counters
    parts.append(_box((0.0, 0.0, 1.5), (lx, 0.35, 2.3)))
    parts.append(_box((0.0, ly - 0.35, 1.5), (lx, ly, 2.3)))
    total = sum(len(f) for _, f in parts)
    while total < faces:
        x0, y0, x1, y1 = surfaces[int(rng.integers(len(surfaces)))]
        kind = rng.random()
        if kind < 0.5:  # fruit, a bowl
            radius = float(rng.uniform(0.025, 0.07))
            centre = np.array([rng.uniform(x0 + radius, x1 - radius),
                               rng.uniform(y0 + radius, y1 - radius), h + radius])
            part = _sphere(centre, radius)
        else:  # a cup, a pot, a bottle
            radius = float(rng.uniform(0.025, 0.08))
            height = float(rng.uniform(0.06, 0.3))
            base = np.array([rng.uniform(x0 + radius, x1 - radius),
                             rng.uniform(y0 + radius, y1 - radius), h])
            part = _cylinder(base, radius, height)
        parts.append(part)
        total += len(part[1])
    vertices, triangles, offset = [], [], 0
    for v, f in parts:
        vertices.append(v)
        triangles.append(f + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(triangles)


def write_ply(path: Path, vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> None:
    """Binary little-endian PLY: double x, y, z; uchar-counted int vertex lists."""
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(vertices)}\nproperty double x\nproperty double y\n"
              f"property double z\nelement face {len(faces)}\n"
              "property list uchar int vertex_indices\nend_header\n")
    face_rows = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face_rows["n"] = 3
    face_rows["v"] = faces
    with path.open("wb") as handle:
        handle.write(header.encode("ascii"))
        handle.write(np.ascontiguousarray(vertices, "<f8").tobytes())
        handle.write(face_rows.tobytes())


def edge_lengths(vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> NDArray[np.float64]:
    corner = vertices[faces]
    lengths: NDArray[np.float64] = np.linalg.norm(corner - np.roll(corner, 1, axis=1), axis=2)
    return lengths.ravel()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--faces", type=int, default=1_000_000)
    parser.add_argument("--seed", type=int, default=5)
    args = parser.parse_args()
    vertices, faces = build(args.faces, args.seed)
    write_ply(args.out, vertices, faces)
    edges = edge_lengths(vertices, faces)
    print(f"{args.out}: {len(faces):,} faces, {len(vertices):,} vertices, edge median "
          f"{np.median(edges) * 1000:.1f} mm, max {edges.max():.1f} m")


if __name__ == "__main__":
    main()
