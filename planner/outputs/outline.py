"""Faces merged for drawing: the pieces of one file face that share a state drawn as few
triangles as their outline needs.

A model split for the coverage (``max_edge_m``) has millions of faces, but a drawing shows
states (a class, a colour), and the pieces of one file face with one state cover a region
of that face. A *group* here is such a set of pieces. A group that is all of its file face
is drawn as the file face itself (its three corners); a group of one face as that face;
any other as its outline (holes and all, corners on a straight run dropped) triangulated
with no new vertices (GEOS's constrained Delaunay through ``shapely``), or the pieces
themselves where that would not cover exactly their area. The outline is the pieces' edges
that no other piece of the group uses (the pieces of a file face share their vertices along
common edges, as :func:`planner.scene.remesh` splits), found for every group in one
compiled pass (:func:`_outlines`); shapely's union of the pieces only where those edges
make no closed loops. ``coverage.glb`` draws its features so
(:mod:`planner.outputs.glb`), the floors of the pictures their colours
(:mod:`planner.outputs.drawing`).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import shapely
from numpy.typing import NDArray

from planner.scene import Scene

# a merged outline drops a corner this close to the line through its neighbours (pieces
# are split at edge midpoints, which lie on the edge only to rounding)
_COLLINEAR_M = 1e-6
# a chunk of the features to outline holds about this many pieces (bounds the outlines'
# scratch arrays: 3 edges a piece)
_OUTLINE_CHUNK_PIECES = 1 << 16
# _outlines' verdict on a feature: outlined, or left to _merge (shapely's union)
_OUTLINED, _TO_MERGE = 0, 1


def group_triangles(scene: Scene, rows: NDArray[np.int32], offsets: NDArray[np.int64]
                    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Triangles covering each group of faces of a split ``scene`` (``scene.file_faces``
    set), group ``n`` being the faces ``rows[offsets[n]:offsets[n + 1]]`` (ascending, all
    from one file face).

    Returns (T, 3) int64 corners, group after group, indexing the scene's vertices
    followed by the file's (``scene.file_vertices``, for a group that is its whole file
    face), and (N,) int64 the number of triangles of each group."""
    source = scene.source_face
    first = rows[offsets[:-1]]
    file_face = source[first].astype(np.int64)
    counts = np.diff(offsets)
    whole = counts == scene.pieces_per_file_face()[file_face]
    triangle_group, triangles, to_merge = _outlined(
        scene, rows, offsets, first, np.flatnonzero(~whole & (counts > 1)))
    merged = [triangles]
    merged_group = [triangle_group]
    for group in to_merge.tolist():  # edges that make no closed loops: shapely's union
        members = rows[offsets[group]:offsets[group + 1]]
        merged.append(_merge(scene, scene.faces[members], int(first[group]),
                             float(scene.areas[members].sum())))
        merged_group.append(np.full(len(merged[-1]), group, np.int64))
    triangle_group = np.concatenate(merged_group)
    by_group = np.argsort(triangle_group, kind="stable")
    triangle_group, triangles = triangle_group[by_group], np.concatenate(merged)[by_group]
    del merged, merged_group, by_group
    made = np.ones(len(counts), np.int64)
    made[~whole & (counts > 1)] = 0
    made += np.bincount(triangle_group, minlength=len(counts))
    starts = np.concatenate([[0], np.cumsum(made)[:-1]])
    corners = np.empty((int(made.sum()), 3), np.int64)
    single = counts == 1
    corners[starts[single]] = scene.faces[first[single]]
    # a file face all of one state: the file face itself (its vertices follow the scene's)
    alone = whole & ~single
    corners[starts[alone]] = scene.file_mesh[1][file_face[alone]] + len(scene.vertices)
    # each merged group's triangles, in order, from its start
    rank = np.arange(len(triangle_group)) - np.searchsorted(triangle_group, triangle_group)
    corners[starts[triangle_group] + rank] = triangles
    return corners, made


@numba.njit(nogil=True, cache=True)
def _outlines(faces: NDArray[np.int32], rows: NDArray[np.int32], offsets: NDArray[np.int64],
              chosen: NDArray[np.int64], vertices: NDArray[np.float64],
              axes: NDArray[np.int64], tolerance: float
              ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64],
                         NDArray[np.int64], NDArray[np.int8], NDArray[np.float64]]:
    """The outlines of the ``chosen`` features (their faces ``rows[offsets[n]:offsets[n +
    1]]``: pieces of one file face, which meet edge to edge and share the vertex indices
    along their common edges, as :func:`planner.scene.remesh` splits).

    Each feature is seen along the main axis of its normal: ``axes`` (k, 2) the other two
    axes of ``vertices`` (V, 3). An edge that no other piece of the feature uses is on its
    outline; followed from corner to corner these make closed loops, wound as the pieces
    (where the outline touches itself, each loop keeps to one side of the corner). A corner
    within ``tolerance`` of the line from the last kept corner to the next one is dropped,
    unless the outline touches itself there. Loops wound the other way than the feature's
    area are holes, each in the smallest outer loop around the middle of its first edge.

    Returns the loops' kept vertices (one after another), their (L + 1,) offsets into
    them, (L,) each loop's feature (into ``chosen``), (L,) the outer loop of each (itself
    for an outer loop), (k,) per feature ``_OUTLINED`` or ``_TO_MERGE`` (an edge used by
    more than two pieces or twice the same way, an outline that does not close, a loop of
    fewer than 3 corners, a hole in no outer loop: left to :func:`_merge`), and (k,) the
    length of each feature's outline before corners were dropped.
    """
    total = 0
    for n in chosen:
        total += offsets[n + 1] - offsets[n]
    loop_vertices = np.empty(3 * total, np.int64)
    loop_offsets = np.zeros(total + 1, np.int64)
    loop_feature = np.empty(total, np.int64)
    loop_area = np.empty(total, np.float64)
    loop_shell = np.empty(total, np.int64)
    status = np.zeros(len(chosen), np.int8)
    length = np.zeros(len(chosen), np.float64)
    n_loops = 0
    n_vertices = 0
    for f in range(len(chosen)):
        n = chosen[f]
        lo, m = offsets[n], offsets[n + 1] - offsets[n]
        keys = np.empty(3 * m, np.int64)
        start = np.empty(3 * m, np.int64)
        end = np.empty(3 * m, np.int64)
        for j in range(m):
            face = faces[rows[lo + j]]
            for e in range(3):
                a, b = np.int64(face[e]), np.int64(face[(e + 1) % 3])
                start[3 * j + e], end[3 * j + e] = a, b
                keys[3 * j + e] = (min(a, b) << 32) | max(a, b)
        order = np.argsort(keys)
        # the edges used once: the outline (directed as their piece winds)
        boundary = np.empty(3 * m, np.int64)
        nb = 0
        i = 0
        bad = False
        while i < 3 * m:
            k = i + 1
            while k < 3 * m and keys[order[k]] == keys[order[i]]:
                k += 1
            if k - i == 1:
                boundary[nb] = order[i]
                nb += 1
            elif k - i > 2 or start[order[i]] == start[order[i + 1]]:
                bad = True
                break
            i = k
        if bad or nb < 3:
            status[f] = _TO_MERGE
            continue
        ax, ay = axes[f, 0], axes[f, 1]
        # the pieces' winding as seen: +1 counter-clockwise, -1 clockwise
        wound = 0.0
        for j in range(m):
            face = faces[rows[lo + j]]
            a, b, c = face[0], face[1], face[2]
            wound += ((vertices[b, ax] - vertices[a, ax]) * (vertices[c, ay] - vertices[a, ay])
                      - (vertices[b, ay] - vertices[a, ay]) * (vertices[c, ax] - vertices[a, ax]))
        tails = start[boundary[:nb]]
        by_tail = np.argsort(tails)
        sorted_tails = tails[by_tail]
        # the edge that follows each: the one starting where it ends; where the outline
        # touches itself (several start there), the first one turning from the edge's way
        # back towards its pieces' side, so that every loop keeps to one side of the corner
        after = np.empty(nb, np.int64)
        used = np.zeros(nb, np.int64)
        pinch = np.zeros(nb, np.bool_)  # the edge starts where the outline touches itself
        for i in range(nb):
            head = end[boundary[i]]
            at = np.searchsorted(sorted_tails, head)
            if at == nb or sorted_tails[at] != head:
                bad = True
                break
            best = by_tail[at]
            if at + 1 < nb and sorted_tails[at + 1] == head:
                tail = start[boundary[i]]
                bu = vertices[tail, ax] - vertices[head, ax]
                bv = vertices[tail, ay] - vertices[head, ay]
                least = 10.0
                k = at
                while k < nb and sorted_tails[k] == head:
                    pinch[by_tail[k]] = True
                    w = end[boundary[by_tail[k]]]
                    ou = vertices[w, ax] - vertices[head, ax]
                    ov = vertices[w, ay] - vertices[head, ay]
                    # the turn from the way back to this edge, against the pieces' winding
                    turn = math.atan2(ou * bv - ov * bu, ou * bu + ov * bv)
                    if wound < 0:
                        turn = -turn
                    if turn <= 0:
                        turn += 2 * math.pi
                    if turn < least:
                        least, best = turn, by_tail[k]
                    k += 1
            after[i] = best
            used[best] += 1
        for i in range(nb):
            if used[i] != 1:
                bad = True
        if bad:
            status[f] = _TO_MERGE
            continue
        # each edge's tail as a place in sorted_tails (the first of its vertex's)
        slot = np.empty(nb, np.int64)
        for k in range(nb):
            slot[by_tail[k]] = k if k == 0 or sorted_tails[k] != sorted_tails[k - 1] else (
                slot[by_tail[k - 1]])
        first_loop, first_vertex = n_loops, n_vertices
        seen = np.zeros(nb, np.bool_)
        # the path followed so far: vertices, kept whatever the line (the outline touches
        # there), and where on it each vertex is (by slot; -1: not on it)
        path = np.empty(nb, np.int64)
        path_slot = np.empty(nb, np.int64)
        fixed = np.empty(nb, np.bool_)
        on_path = np.full(nb, -1, np.int64)
        signed = 0.0
        shells = 0
        for i0 in range(nb):
            if seen[i0] or bad:
                continue
            top = 0
            i = i0
            while True:
                # back at the start, or at a vertex of the path: the loop since then (a loop
                # that touches itself is cut there: a shell and a hole, or two shells)
                at = 0 if seen[i] else on_path[slot[i]]
                if at >= 0:
                    kept = _keep_corners(vertices, ax, ay, path[at:top], fixed[at:top],
                                         tolerance, loop_vertices, n_vertices)
                    if kept < 0:
                        bad = True
                        break
                    area = 0.0
                    for t in range(at, top):
                        on_path[path_slot[t]] = -1
                        p, q = path[t], path[t + 1 if t + 1 < top else at]
                        length[f] += math.hypot(vertices[q, ax] - vertices[p, ax],
                                                vertices[q, ay] - vertices[p, ay])
                    for t in range(n_vertices, kept):
                        p = loop_vertices[t]
                        q = loop_vertices[t + 1 if t + 1 < kept else n_vertices]
                        area += (vertices[p, ax] * vertices[q, ay]
                                 - vertices[p, ay] * vertices[q, ax])
                    n_vertices = kept
                    loop_feature[n_loops] = f
                    loop_area[n_loops] = area
                    n_loops += 1
                    loop_offsets[n_loops] = n_vertices
                    signed += area
                    top = at
                    if seen[i]:
                        break
                seen[i] = True
                on_path[slot[i]] = top
                path[top], path_slot[top], fixed[top] = start[boundary[i]], slot[i], pinch[i]
                top += 1
                i = after[i]
        if not bad:
            for i in range(first_loop, n_loops):
                loop_area[i] = loop_area[i] * signed  # > 0: an outer loop, < 0: a hole
                loop_shell[i] = i
                if loop_area[i] > 0:
                    shells += 1
            bad = shells == 0
        if not bad and shells < n_loops - first_loop:
            # each hole in the smallest outer loop around the middle of its first edge
            for h in range(first_loop, n_loops):
                if loop_area[h] > 0:
                    continue
                p, q = loop_vertices[loop_offsets[h]], loop_vertices[loop_offsets[h] + 1]
                pu = 0.5 * (vertices[p, ax] + vertices[q, ax])
                pv = 0.5 * (vertices[p, ay] + vertices[q, ay])
                least = np.inf
                for o in range(first_loop, n_loops):
                    if (loop_area[o] > 0 and loop_area[o] < least
                            and _inside(vertices, ax, ay, loop_vertices, loop_offsets[o],
                                        loop_offsets[o + 1], pu, pv)):
                        least, loop_shell[h] = loop_area[o], o
                if least == np.inf:
                    bad = True
                    break
        if bad:
            status[f] = _TO_MERGE
            n_loops, n_vertices = first_loop, first_vertex
            continue
    return (loop_vertices[:n_vertices].copy(), loop_offsets[:n_loops + 1].copy(),
            loop_feature[:n_loops].copy(), loop_shell[:n_loops].copy(), status, length)


@numba.njit(nogil=True, cache=True)
def _inside(vertices: NDArray[np.float64], ax: int, ay: int, loop: NDArray[np.int64],
            start: int, stop: int, pu: float, pv: float) -> bool:
    """Whether the point (``pu``, ``pv``) is inside the loop ``loop[start:stop]`` (vertex
    indices; seen along the axis other than ``ax`` and ``ay``): even-odd crossings."""
    inside = False
    for t in range(start, stop):
        a, b = loop[t], loop[t + 1 if t + 1 < stop else start]
        au, av, bu, bv = vertices[a, ax], vertices[a, ay], vertices[b, ax], vertices[b, ay]
        if (av > pv) != (bv > pv) and pu < au + (pv - av) * (bu - au) / (bv - av):
            inside = not inside
    return inside


@numba.njit(nogil=True, cache=True)
def _keep_corners(vertices: NDArray[np.float64], ax: int, ay: int, loop: NDArray[np.int64],
                  fixed: NDArray[np.bool_], tolerance: float, out: NDArray[np.int64],
                  n_out: int) -> int:
    """Write the corners of the closed ``loop`` (vertex indices) to ``out`` from ``n_out``
    on, leaving out those within ``tolerance`` of the line from the last kept corner to the
    next one (never a ``fixed`` one); returns where they end, -1 when fewer than 3 are
    left (a loop seen along the axis other than ``ax`` and ``ay``)."""
    size = len(loop)
    s = -1  # a corner to start from: one off the line through its neighbours
    for t in range(size):
        if fixed[t] or not _on_line(vertices, ax, ay, loop[(t + size - 1) % size], loop[t],
                                    loop[(t + 1) % size], tolerance):
            s = t
            break
    if s < 0:
        return -1
    end = n_out
    out[end] = loop[s]
    end += 1
    for t in range(1, size):
        if fixed[(s + t) % size] or not _on_line(vertices, ax, ay, out[end - 1],
                                                 loop[(s + t) % size],
                                                 loop[(s + t + 1) % size], tolerance):
            out[end] = loop[(s + t) % size]
            end += 1
    return end if end - n_out >= 3 else -1


@numba.njit(nogil=True, cache=True)
def _on_line(vertices: NDArray[np.float64], ax: int, ay: int, p: int, c: int, q: int,
             tolerance: float) -> bool:
    """Whether vertex ``c`` lies within ``tolerance`` of the line through vertices ``p`` and
    ``q`` (seen along the axis other than ``ax`` and ``ay``)."""
    du, dv = vertices[q, ax] - vertices[p, ax], vertices[q, ay] - vertices[p, ay]
    chord = math.hypot(du, dv)
    cross = du * (vertices[c, ay] - vertices[p, ay]) - dv * (vertices[c, ax] - vertices[p, ax])
    return bool(chord > 0 and abs(cross) <= tolerance * chord)


def _outlined(scene: Scene, rows: NDArray[np.int32], offsets: NDArray[np.int64],
              first: NDArray[np.int32], chosen: NDArray[np.int64]
              ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Triangles covering each of the ``chosen`` features (several faces, not their whole
    file face; ``first``: each feature's first face): its outline (:func:`_outlines`)
    triangulated by GEOS's constrained Delaunay (no new vertices), wound as its file face,
    ``_OUTLINE_CHUNK_PIECES`` faces' worth of features at a time.

    Returns (t,) the feature of each triangle (ascending), (t, 3) their vertex indices,
    and the features :func:`_outlines` left to :func:`_merge`. A feature whose triangles do
    not cover exactly its faces' area with their vertices is drawn as its faces."""
    pieces = offsets[chosen + 1] - offsets[chosen]
    cuts = np.searchsorted(np.cumsum(pieces), np.arange(
        _OUTLINE_CHUNK_PIECES, int(pieces.sum()), _OUTLINE_CHUNK_PIECES), side="right")
    main = np.argmax(np.abs(scene.normals_of(first[chosen])), axis=1)
    # the two axes other than the main axis of each feature's normal
    axes = np.stack([(main == 0).astype(np.int64), 2 - (main == 2).astype(np.int64)], axis=1)
    found: list[tuple[NDArray[np.int64], NDArray[np.int64]]] = []
    to_merge: list[NDArray[np.int64]] = []
    for part in np.split(np.arange(len(chosen)), np.unique(cuts)):
        if len(part) == 0:
            continue
        features, triangles, left = _outlined_part(scene, rows, offsets, first,
                                                   chosen[part], axes[part])
        found.append((features, triangles))
        to_merge.append(left)
    if not found:
        empty = np.zeros(0, np.int64)
        return empty, np.zeros((0, 3), np.int64), empty
    return (np.concatenate([f for f, _ in found]), np.concatenate([t for _, t in found]),
            np.concatenate(to_merge))


def _outlined_part(scene: Scene, rows: NDArray[np.int32], offsets: NDArray[np.int64],
                   first: NDArray[np.int32], chosen: NDArray[np.int64],
                   axes: NDArray[np.int64]
                   ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """:func:`_outlined` for one chunk of features (``axes``: theirs, :func:`_outlines`)."""
    vertices = scene.vertices
    loop_vertices, loop_offsets, loop_feature, loop_shell, status, length = _outlines(
        scene.faces, rows, offsets, chosen, vertices, axes, _COLLINEAR_M)
    # a polygon per outer loop, its holes after it
    hole = loop_shell != np.arange(len(loop_shell))
    shell = ~hole
    loop_polygon = (np.cumsum(shell) - 1)[loop_shell]
    polygon_feature = loop_feature[shell]
    order = np.lexsort((hole, loop_polygon))  # each polygon's shell, then its holes
    sizes = np.diff(loop_offsets)[order]
    at = np.repeat(loop_offsets[:-1][order] - np.cumsum(sizes) + sizes, sizes) + np.arange(
        int(sizes.sum()))
    ids = loop_vertices[at]
    polygon = np.repeat(loop_polygon[order], sizes)
    feature_axes = axes[polygon_feature[polygon]]
    uv = np.stack([vertices[ids, feature_axes[:, 0]], vertices[ids, feature_axes[:, 1]]], axis=1)
    del feature_axes
    bad = np.zeros(len(chosen), bool)  # drawn as their faces
    if len(polygon_feature):
        rings = shapely.linearrings(uv, indices=np.repeat(np.arange(len(sizes)), sizes))
        polygons = shapely.polygons(rings, indices=loop_polygon[order])
        try:
            triangulated = shapely.constrained_delaunay_triangles(polygons)
        except shapely.errors.GEOSException:
            triangulated = np.empty(len(polygons), object)
            for p, outline in enumerate(polygons):
                try:
                    triangulated[p] = shapely.constrained_delaunay_triangles(outline)
                except shapely.errors.GEOSException:
                    triangulated[p] = shapely.GeometryCollection()
                    bad[polygon_feature[p]] = True
        # each triangle a closed ring of 4 points, in the geometry of its polygon
        corners, polygon_of_corner = shapely.get_coordinates(triangulated, return_index=True)
        corners = corners.reshape(-1, 4, 2)[:, :3].reshape(-1, 2)
        part_polygon = polygon_of_corner[::4]
        del triangulated, polygon_of_corner
    else:
        corners, part_polygon = np.zeros((0, 2)), np.zeros(0, np.int64)
    # back to vertex indices: each corner is a corner of its polygon's loops, bit for bit;
    # sorted together with them (corners after the loops' points), a corner follows the
    # loop point it is
    n = len(ids)
    both = np.lexsort((np.concatenate([np.zeros(n, np.int8), np.ones(len(corners), np.int8)]),
                       np.concatenate([uv[:, 1], corners[:, 1]]).view(np.int64),
                       np.concatenate([uv[:, 0], corners[:, 0]]).view(np.int64),
                       np.concatenate([polygon, np.repeat(part_polygon, 3)])))
    last = np.maximum.accumulate(np.where(both < n, np.arange(len(both)), -1))
    at = np.empty(len(corners), np.int64)  # the loop point each corner follows (-1: none)
    at[both[both >= n] - n] = np.where(last >= 0, both[last], -1)[both >= n]
    triangle_feature = polygon_feature[part_polygon]
    found = np.maximum(at, 0)
    matched = ((at >= 0) & (polygon[found] == np.repeat(part_polygon, 3))
               & (uv[found].view(np.int64) == corners.view(np.int64)).all(axis=1))
    bad[triangle_feature[~matched.reshape(-1, 3).all(axis=1)]] = True
    triangles = ids[found].reshape(-1, 3).astype(np.int64)
    # the area check: within what dropping corners off the line by up to _COLLINEAR_M
    # moves (in the plane; seen along the main axis, lengths shrink by at most sqrt(3))
    cross = _cross(vertices[triangles])
    drawn = np.bincount(triangle_feature, np.sqrt((cross * cross).sum(axis=1)) * 0.5,
                        minlength=len(chosen))
    pieces = offsets[chosen + 1] - offsets[chosen]
    members = rows[np.repeat(offsets[chosen] - np.cumsum(pieces) + pieces, pieces)
                   + np.arange(int(pieces.sum()))]
    area = np.bincount(np.repeat(np.arange(len(chosen)), pieces), scene.areas[members],
                       minlength=len(chosen))
    made = np.bincount(triangle_feature, minlength=len(chosen))
    bad |= (np.abs(drawn - area) > 2.0 * _COLLINEAR_M * length + 1e-9 * area) | (made == 0)
    bad &= status == _OUTLINED
    flip = (cross * scene.normals_of(first[chosen[triangle_feature]])).sum(axis=1) < 0
    triangles[flip] = triangles[flip][:, ::-1]
    keep = ~bad[triangle_feature]
    # the features that failed: their faces
    faulty = np.repeat(bad, pieces)
    features = np.concatenate([triangle_feature[keep],
                               np.repeat(np.arange(len(chosen)), pieces)[faulty]])
    triangles = np.concatenate([triangles[keep], scene.faces[members[faulty]]])
    order = np.argsort(features, kind="stable")
    return (chosen[features[order]], triangles[order],
            chosen[status == _TO_MERGE])


def _merge(scene: Scene, pieces: NDArray[np.int32], first: int, area: float
           ) -> NDArray[np.int64]:
    """(t, 3) vertex indices of triangles covering the (m, 3) ``pieces`` of one file face
    (that of face ``first``; ``area`` theirs, m^2): their outline (holes and all: the
    pieces of a file face meet edge to edge), corners on a straight run dropped,
    triangulated (GEOS's constrained Delaunay, no new vertices), wound as the file face.
    The pieces themselves when that fails to cover exactly their area with their
    vertices."""
    vertices, normal = scene.vertices, scene.normals_of(first)
    axes = [a for a in range(3) if a != int(np.argmax(np.abs(normal)))]
    flat = vertices[pieces][:, :, axes]  # (m, 3, 2): the plane seen along its main axis
    try:
        outline = shapely.coverage_union_all(
            shapely.polygons(np.concatenate([flat, flat[:, :1]], axis=1)))
        # dropping corners off the line by up to _COLLINEAR_M moves at most this much area
        # (in the plane; seen along the main axis, lengths shrink by at most sqrt(3))
        slack = 2.0 * _COLLINEAR_M * float(shapely.length(outline))
        outline = shapely.simplify(outline, _COLLINEAR_M)
        parts = shapely.get_parts(shapely.constrained_delaunay_triangles(outline))
    except shapely.errors.GEOSException:
        return pieces.astype(np.int64)
    found = shapely.get_coordinates(parts).reshape(-1, 4, 2)[:, :3]  # (t, 3, 2)
    # back to vertex indices: each corner is a corner of a piece, bit for bit
    ids = np.unique(pieces)
    points = np.ascontiguousarray(vertices[ids][:, axes])
    order = np.lexsort((points[:, 1], points[:, 0]))
    keyed = points[order].view([("u", np.float64), ("v", np.float64)]).ravel()
    wanted = np.ascontiguousarray(found.reshape(-1, 2)).view(
        [("u", np.float64), ("v", np.float64)]).ravel()
    at = np.minimum(np.searchsorted(keyed, wanted), len(keyed) - 1)
    if len(found) == 0 or not (keyed[at] == wanted).all():
        return pieces.astype(np.int64)
    triangles = ids[order[at]].reshape(-1, 3).astype(np.int64)
    cross = _cross(vertices[triangles])
    if abs(0.5 * float(np.sqrt((cross * cross).sum(axis=1)).sum()) - area) > slack + 1e-9 * area:
        return pieces.astype(np.int64)
    flip = cross @ normal < 0
    triangles[flip] = triangles[flip][:, ::-1]
    return triangles


def _cross(corners: NDArray[np.float64]) -> NDArray[np.float64]:
    """(t, 3) the cross product of the edges from the first corner of (t, 3, 3) triangles
    (twice the area, along the normal); written out, np.cross is slow on small arrays."""
    a = corners[:, 1] - corners[:, 0]
    b = corners[:, 2] - corners[:, 0]
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)
