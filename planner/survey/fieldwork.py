"""A survey a crew can run: registration overlap, walking route and field time of a plan.

:func:`survey` runs after the selection, on the chosen stations only (S of them), so with
default parameters it adds one overlap pass over S positions and the walk graph to a plan;
the constrained selection itself lives in :mod:`planner.survey.registration`. A budget of
hours times sets of stations before the survey (:class:`FieldClock`) on the walk network
the survey then walks (:class:`WalkNetwork`).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from planner.candidates.grid import CandidateSet
from planner.io.orientation import scene_rotation, to_plan
from planner.limits import FaceLimits
from planner.memory import release_freed_memory
from planner.parameters import DEFAULT_ANGULAR_STEP_RAD, PlanSpec
from planner.rays import Occlusion, RayCaster, make_ray_caster
from planner.scanners import StationScan, missing_duration_reason, station_scans, step_note
from planner.scene import Scene
from planner.survey.registration import Registration, station_registration
from planner.survey.route import (
    Places,
    Route,
    TreeCache,
    door_checks,
    parts_may_join_outside,
    plan_route,
)
from planner.visibility.bundles import forget_bundles
from planner.visibility.overlap import OverlapRows, RowsFanout, shared_faces_only
from planner.visibility.qualify import Sight
from planner.walkgraph import MeshDoors, WalkGraph, build_walk_graph, door_faces, found_doors


@dataclass(frozen=True)
class FieldTime:
    setup_s: float
    scan_s: float | None  # None: no scan duration known for this scanner and resolution
    walk_s: float
    scanner: str | None  # the preset id or the profile's name
    # with a scanner whose durations are unknown: the missing figure and the field for it
    scan_unknown_reason: str | None = None
    # with a scanner none of whose settings is as fine as the default step: why the plan's
    # step is its finest setting (planner.scanners.fallback_step)
    step_note: str | None = None

    @property
    def total_s(self) -> float | None:
        if self.scan_s is None:
            return None
        return self.setup_s + self.scan_s + self.walk_s

    def to_dict(self) -> dict[str, Any]:
        def r(v: float | None) -> float | None:
            return None if v is None else round(v, 1)

        data: dict[str, Any] = {
            "total_s": r(self.total_s), "setup_s": r(self.setup_s), "scan_s": r(self.scan_s),
            "walk_s": r(self.walk_s), "scanner": self.scanner}
        if self.scan_unknown_reason is not None:
            data["scan_unknown_reason"] = self.scan_unknown_reason
        if self.step_note is not None:
            data["step_note"] = self.step_note
        return data


@dataclass(frozen=True)
class Survey:
    registration: Registration
    route: Route
    field_time: FieldTime
    # per station in selection order, with a scanner: its setting and scan time; () without
    scans: tuple[StationScan, ...] = ()

    def visit_of(self, station_id: int) -> int | None:
        """1-based place of a station on the route; None when it is unreachable."""
        try:
            return self.route.visits.index(station_id) + 1
        except ValueError:
            return None


def field_time(spec: PlanSpec, n_stations: int, route: Route,
               scans: tuple[StationScan, ...] = ()) -> FieldTime:
    """Setup, scan and walk time; ``scans`` are the stations' (empty without a scanner)."""
    profile = spec.scanner_profile
    setup_one_s = spec.setup_per_station_s
    scan_s: float | None = None
    reason: str | None = None
    if profile is not None:
        durations = [s.scan_s for s in scans]
        if all(d is not None for d in durations):
            scan_s = float(sum(d for d in durations if d is not None))
        else:
            reason = missing_duration_reason(profile, scans)
    return FieldTime(
        setup_s=setup_one_s * n_stations,
        scan_s=scan_s,
        walk_s=route.length_m / spec.walking_speed_m_s,
        scanner=None if profile is None else
        spec.scanner if isinstance(spec.scanner, str) else profile.name,
        scan_unknown_reason=reason,
        step_note=None if profile is None else step_note(profile, spec.angular_step_rad,
                                                         DEFAULT_ANGULAR_STEP_RAD),
    )


def scans_of(spec: PlanSpec, density_margins: list[float] | None, n_stations: int
             ) -> tuple[StationScan, ...]:
    """Each station's setting and scan time (planner.scanners); () without a scanner.

    ``density_margins``: per station, the least density / requirement over the faces it is
    credited with; None: every station keeps the plan's step (margin 1).
    """
    profile = spec.scanner_profile
    if profile is None:
        return ()
    margins = [1.0] * n_stations if density_margins is None else density_margins
    return station_scans(profile, spec.angular_step_rad, spec.elevation_min_deg,
                         spec.elevation_max_deg, margins)


def _walk_caster(scene: Scene, limits: FaceLimits, caster: RayCaster, file_faces: bool
                 ) -> tuple[RayCaster, MeshDoors | None]:
    """Rays for walking: every face blocks (glass too, which coverage may see through)
    except doors (IFC doors; in a plain mesh the thin fillers of wall openings that
    :func:`~planner.walkgraph.found_doors` finds with the coverage ``caster`` over the
    whole footprint, returned too; None for an IFC model); the coverage caster is reused
    when it blocks exactly those faces. ``file_faces``: cast against the file's faces, as
    the plan's rays (``occluders``)."""
    doors = None if scene.elements else found_doors(scene, caster)
    blocks = ~door_faces(scene) if doors is None else doors.face_door < 0
    if np.array_equal(blocks, limits.occludes):
        return caster, doors
    return make_ray_caster(scene, blocks, file_faces=file_faces), doors


def places_of(scene: Scene, candidates: CandidateSet | None, stations: list[int]
              ) -> Places:
    """What the route's reasons name (:class:`planner.survey.route.Places`): the storeys
    (an IFC model's, else the storeys of the ``candidates``), the room of each station
    (``stations``: candidate indices, in station order) and the IFC doors' boxes."""
    storeys = tuple((str(s["name"]), float(s["elevation_m"]))
                    for s in scene.metadata.get("storeys") or []
                    if s.get("elevation_m") is not None)
    rooms: tuple[str, ...] = ()
    if candidates is not None:
        if not storeys:
            levels = candidates.levels or []
            named = {float(str(level["floor_z_m"])): str(level["name"])
                     for level in levels if "excluded" not in level}
            # a storey's floor, and each split level or landing under its storey's name
            storeys = tuple((name, z) for z, name in named.items()) + tuple(
                (named[float(str(level["storey_floor_z_m"]))], float(str(level["floor_z_m"])))
                for level in levels
                if float(str(level.get("storey_floor_z_m", "nan"))) in named)
        if candidates.labels:
            rooms = tuple(candidates.labels[i].get("room", "") for i in stations)
    doors: list[tuple[str, tuple[float, float, float], tuple[float, float, float]]] = []
    frames: list[tuple[float, float, float, float, float, float]] = []
    if scene.elements:
        door = door_faces(scene)
        element = scene.face_element[door]
        corners = scene.vertices[scene.faces[door]]  # (D, 3, 3); not every face's corners
        for e in np.unique(element[element >= 0]).tolist():
            points = corners[element == e].reshape(-1, 3)
            lo, hi = points.min(axis=0), points.max(axis=0)
            item = scene.elements[e]
            name = item.name or item.global_id
            doors.append((f"{name} ({item.ifc_class})", (float(lo[0]), float(lo[1]),
                                                         float(lo[2])),
                          (float(hi[0]), float(hi[1]), float(hi[2]))))
            frames.append(_door_frame(points[:, :2]))
    return Places(tuple(sorted(storeys, key=lambda s: s[1])), rooms, tuple(doors),
                  tuple(frames))


def _door_frame(xy: NDArray[np.float64]) -> tuple[float, float, float, float, float, float]:
    """A door's box along its own plane from its (n, 2) corners (plan frame): centre x, y,
    the unit direction of its width (the corners' principal axis) x, y, half its width
    and half its depth, metres (:attr:`planner.survey.route.Places.door_frames`)."""
    mean = xy.mean(axis=0)
    _, axes = np.linalg.eigh(np.cov((xy - mean).T))  # ascending: the width's axis last
    width = axes[:, 1]
    depth = np.array([-width[1], width[0]])
    along, across = (xy - mean) @ width, (xy - mean) @ depth
    centre = mean + width * (along.max() + along.min()) / 2 + depth * (
        across.max() + across.min()) / 2
    return (float(centre[0]), float(centre[1]), float(width[0]), float(width[1]),
            float(np.ptp(along)) / 2, float(np.ptp(across)) / 2)


@dataclass(frozen=True, eq=False)
class WalkNetwork:
    """Where a crew walks: the walk graph, the rays it is walked with (every face blocks but
    doors), the found doors of a plain mesh (None for an IFC model) and the route's start
    in the plan frame (None: the route chooses)."""

    graph: WalkGraph
    caster: RayCaster
    doors: MeshDoors | None
    start: tuple[float, float, float] | None
    # the shortest-path trees of the last route's stations, for routes over fewer of them
    trees: TreeCache = dataclasses.field(default_factory=TreeCache)

    def route(self, stations_xyz: NDArray[np.float64], places: Places | None = None) -> Route:
        """The route over the (S, 3) stations (:func:`planner.survey.route.plan_route`)."""
        return plan_route(self.graph, self.caster, stations_xyz, self.start, places,
                          self.trees)


def walk_network(scene: Scene, spec: PlanSpec, limits: FaceLimits, caster: RayCaster,
                 stations_xyz: NDArray[np.float64],
                 walk_area_xy: NDArray[np.float64] | None = None) -> WalkNetwork:
    """The :class:`WalkNetwork` for routes over the (S, 3) ``stations_xyz`` (and the
    ``route_start``): the graph of the ground in ``walk_area_xy`` ((2, 2); None: the
    model's whole footprint), or of the whole footprint when two parts that hold some of
    the stations both reach the area's edge (they may be joined outside it)."""
    start = spec.route_start
    if start is not None:  # given in model coordinates, like every position (up_axis)
        x, y, z = to_plan(scene_rotation(scene.metadata), np.asarray([start], np.float64))[0]
        start = (float(x), float(y), float(z))
        if walk_area_xy is not None:  # the crew's start is walked ground too
            walk_area_xy = np.stack([np.minimum(walk_area_xy[0], (x, y)),
                                     np.maximum(walk_area_xy[1], (x, y))])
    walk_caster, doors = _walk_caster(scene, limits, caster, spec.occluders == "file")
    if scene.metadata.get("spaces"):  # rooms are floors where the model has no slab
        from planner.survey.space_floors import with_room_floors

        walk_caster, _ = with_room_floors(scene, walk_caster)
    graph = build_walk_graph(scene, walk_caster, area_xy=walk_area_xy)
    points = stations_xyz if start is None else np.vstack([stations_xyz, [start]])
    if walk_area_xy is not None and parts_may_join_outside(graph, walk_caster, points):
        # stations on two parts that both reach the edge of the area: the whole site's
        # ground may join them (a lower lawn reached round the house's far end)
        graph = build_walk_graph(scene, walk_caster)
    return WalkNetwork(graph, walk_caster, doors, start)


class FieldClock:
    """The field time of any stations, for a budget of hours (``max_field_time_h``): each
    station's setup, its scan at the plan's step, and the walk of the route over them at
    ``walking_speed_m_s``, as :func:`field_time` counts them. A station whose faces allow a
    coarser setting scans faster (:func:`with_settings`), so the plan's own field time is at
    most this.

    The :class:`WalkNetwork` is made at the first call, for the stations asked about then
    (a budget asks about its largest set first), and every later route is walked on it; the
    plan's survey walks it too (:meth:`hand_over`), so the plan's route is the one measured.
    """

    def __init__(self, scene: Scene, spec: PlanSpec, limits: FaceLimits, caster: RayCaster,
                 positions: NDArray[np.float64], walk_area_xy: NDArray[np.float64] | None,
                 seconds: dict[str, float]) -> None:
        self._scene, self._spec, self._limits, self._caster = scene, spec, limits, caster
        self._positions = positions  # (C, 3) the candidates
        self._walk_area_xy = walk_area_xy
        self._seconds = seconds  # the plan's stages: "walk graph" gains the time spent here
        one_s = spec.station_time_s
        if one_s is None:
            raise ValueError("a field-time budget needs the scanner's scan time "
                             "(checked with the parameters)")
        self.per_station_s = one_s  # setup and scan of one
        self.network: WalkNetwork | None = None

    def hand_over(self) -> WalkNetwork | None:
        """The walk network, which the clock then no longer holds (the survey walks the
        plan's route on it and lets it go before its own peak)."""
        network, self.network = self.network, None
        return network

    def seconds(self, stations: list[int]) -> float:
        """Field time of the candidates ``stations``: setup, scan and walk, seconds."""
        t0 = time.perf_counter()
        xyz = self._positions[stations]
        if self.network is None:
            self.network = walk_network(self._scene, self._spec, self._limits, self._caster,
                                        xyz, self._walk_area_xy)
        walk_m = self.network.route(xyz).length_m if stations else 0.0
        self._seconds["walk graph"] = self._seconds.get("walk graph", 0.0) \
            + time.perf_counter() - t0
        return self.per_station_s * len(stations) + walk_m / self._spec.walking_speed_m_s


def survey(scene: Scene, spec: PlanSpec, stations_xyz: np.ndarray, limits: FaceLimits,
           occlusion: Occlusion, caster: RayCaster, seconds: dict[str, float],
           station_overlap: sp.csr_matrix | None = None,
           threads: int | None = None,
           fanout: RowsFanout | None = None, places: Places | None = None,
           walk_area_xy: NDArray[np.float64] | None = None,
           overlap: Sight | None = None, network: WalkNetwork | None = None) -> Survey:
    """Registration, route and field time of the (S, 3) stations, in selection order, each
    station scanned at the plan's step (:func:`with_settings` chooses a scanner's settings).

    ``station_overlap``: the stations' (S, F) overlap rows when the selection already made
    them (else made here, by ``fanout`` when given); ``seconds`` gains the stages "overlap"
    and "walk graph";
    ``places``: what the reasons of unreachable stations name (:func:`places_of`);
    ``walk_area_xy``: (2, 2), the ground the route walks (:func:`planner.walkgraph.walk_area`
    of the plan's candidates; None: the model's whole footprint); ``overlap``: the pieces
    the overlap rows are of (:meth:`planner.visibility.qualify.Sight.overlap_sight`; None:
    ``scene`` with ``limits`` and ``occlusion``, the coverage's); ``network``: where the
    crew walks when a field-time budget already made it (:meth:`FieldClock.hand_over`: its
    route is walked first and the network let go before the overlap rows; None: made here
    for these stations in ``walk_area_xy``, after the overlap rows).
    """
    t0 = time.perf_counter()
    route = None
    if network is not None:  # the route first: the graph then leaves before the overlap rows
        route = _walk(scene, network, stations_xyz, places)
        network = None
        seconds["walk graph"] = seconds.get("walk graph", 0.0) + time.perf_counter() - t0
        t0 = time.perf_counter()
    # only what two stations share counts: the rows are cut to it before the registration's
    # sums and the walk graph (10.7 M faces, 496 stations: 240 MB), and the rows the
    # survey computes itself are cut as they are, never made into one whole matrix
    pieces, pieces_limits, pieces_occlusion = (scene, limits, occlusion) if overlap is None \
        else (overlap.scene, overlap.limits, overlap.occlusion)
    if station_overlap is None:
        shared = OverlapRows(pieces, stations_xyz, pieces_limits, pieces_occlusion,
                             spec.overlap_density_pts_m2, threads=threads,
                             file_faces=spec.occluders == "file", fanout=fanout
                             ).shared_matrix(range(len(stations_xyz)))
    else:
        shared = shared_faces_only(station_overlap)
    del station_overlap
    if overlap is not None:
        forget_bundles(overlap.scene)  # the overlap rows' own: nothing else reads them
    release_freed_memory()  # the whole rows: hundreds of mid-sized arrays, freed in the heap
    registration = station_registration(pieces, shared, spec.min_overlap_m2,
                                        spec.overlap_density_pts_m2)
    del shared
    t1 = time.perf_counter()
    seconds["overlap"] = seconds.get("overlap", 0.0) + t1 - t0
    if route is None:
        route = _walk(scene, walk_network(scene, spec, limits, caster, stations_xyz,
                                          walk_area_xy), stations_xyz, places)
        seconds["walk graph"] = seconds.get("walk graph", 0.0) + time.perf_counter() - t1
    scans = scans_of(spec, None, len(stations_xyz))
    return Survey(registration, route, field_time(spec, len(stations_xyz), route, scans), scans)


def _walk(scene: Scene, network: WalkNetwork, stations_xyz: NDArray[np.float64],
          places: Places | None) -> Route:
    """The route over the (S, 3) stations on ``network``, with a plain mesh's door checks
    (the legs through found doors that may be fixed windows)."""
    route = network.route(stations_xyz, places)
    if network.doors is not None:
        route = dataclasses.replace(route, door_checks=door_checks(scene, route,
                                                                   network.doors))
    return route


def with_settings(found: Survey, spec: PlanSpec, density_margins: list[float]) -> Survey:
    """``found`` with each station's scanner setting, scan time and the field time chosen
    by its ``density_margins`` (:func:`scans_of`; :func:`survey` gives every station the
    plan's step). The margins come from the per-face results, made after the survey."""
    n_stations = len(density_margins)
    scans = scans_of(spec, density_margins, n_stations)
    return dataclasses.replace(found, scans=scans,
                               field_time=field_time(spec, n_stations, found.route, scans))
