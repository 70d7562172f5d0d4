"""The corpus: every real IFC building, as IFC and as a plain mesh, planned as a user would.

Plans each IFC building in ``shared/scenes/buildings/`` and the shared IFC houses in
``shared/scenes/`` twice: as IFC, and as a plain OBJ exported from it without classes or
groups (``tests.planner.buildings.export_plain_mesh``), each plan in a fresh child process
as the command line makes it (read, plan, write the outputs; ``--outputs plan`` writes
plan.json only, which is all the figures need: Lantern Hollow's plain mesh is read and
planned in 143 CPU s, its plan.pdf takes 533 more and 7.4 GB, 346 A3 sheets tiling its
storeys with the site around them). Prints per model and storey
the candidates, stations, rooms without stations (no station on their floor: one in rooms
that overlap counts in each), unreachable stations and their reasons,
and the legs through walls (:func:`planner.truth.legs.legs_through_walls`, with the IFC's
own door faces as the door mask; for the plain mesh its doors and its windows to the floor,
which a plain mesh cannot tell from glazed doors); per model the wall and CPU
seconds (reading and planning, then writing the outputs, apart) and the child's peak memory
(``ru_maxrss``). Prints figures, never passes or fails on them::

    .venv/bin/python benchmarks/buildings.py [--models renga,niedriha,...] [--skip-large]
        [--forms ifc,obj] [--outputs all|plan] [--grid-spacing-m 0.5] [--json out.json]
        [--keep DIR]

Models: renga, niedriha, jasmin, lantern, amersfoort (``shared/scenes/buildings``), fzk,
openhouse (``shared/scenes``); ``--skip-large`` leaves out lantern and amersfoort (minutes
and gigabytes each). On a shared machine compare CPU seconds and peak memory, not wall time.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT.parent / "shared" / "scenes"
BUILDINGS = SCENES / "buildings"
MODELS = {
    "renga": BUILDINGS / "Renga-House.ifc",
    "niedriha": BUILDINGS / "AC90R1-niedriha-V2-2x3.ifc",
    "jasmin": BUILDINGS / "AC90R1-Jasmin-Sun-105-2x3.ifc",
    "lantern": BUILDINGS / "Lantern_Hollow.ifc",
    "amersfoort": BUILDINGS / "Amersfoort_sports_hall.ifc",
    "fzk": SCENES / "AC20-FZK-Haus.ifc",
    "openhouse": SCENES / "IfcOpenHouse_IFC4.ifc",
}
LARGE = ("lantern", "amersfoort")
# what --without-slabs deletes: the structural model's slabs and the finishes on them
STRIPPED = ("IfcSlab", "IfcCovering")


def _strip(ifc: str, out: str) -> None:
    """Child: ``ifc`` without its IfcSlab and IfcCovering elements (with their relations),
    as an architect's discipline model arrives without the structural one."""
    import ifcopenshell
    import ifcopenshell.api.root

    model = ifcopenshell.open(ifc)
    for ifc_class in STRIPPED:
        for product in model.by_type(ifc_class):
            ifcopenshell.api.root.remove_product(model, product=product)
    model.write(out)


def _export(ifc: str, obj: str, doors: str) -> None:
    """Child: the plain OBJ of ``ifc`` and the IFC's doorways for a plain mesh (its doors
    and its windows to the floor, :func:`tests.planner.buildings.plain_mesh_doorways`, in
    the OBJ's face order) as a .npy mask."""
    import numpy as np

    from planner.io.ifc import read_ifc
    from tests.planner.buildings import export_plain_mesh, plain_mesh_doorways

    scene = read_ifc(ifc)
    export_plain_mesh(ifc, obj, scene)
    np.save(doors, scene.on_file_faces(plain_mesh_doorways(scene)))


def _storey_of(station: dict[str, Any]) -> str:
    label = station.get("label") or {}
    return str(label.get("storey") or "?")


def _what(scene: Any, face: int) -> str:
    """The element a face belongs to ("" in a plain mesh)."""
    element = int(scene.face_element[face])
    if element < 0 or not scene.elements:
        return ""
    item = scene.elements[element]
    return f"{item.ifc_class} {item.name}"


def _child(model: str, spec_json: str, out: str, doors: str, outputs: str) -> None:
    """Plan ``model`` in this process and print one JSON line of figures. ``doors``: a
    .npy door mask over the file's faces ("" : the model's own, by IFC class);
    ``outputs``: "all" the outputs the command line writes, "plan" plan.json only."""
    import numpy as np

    from planner.io.readers import read_scene
    from planner.outputs.report import write_outputs
    from planner.parameters import PlanSpec
    from planner.pipeline import plan
    from planner.truth.legs import legs_in_plan, legs_through_walls
    from planner.walkgraph import door_faces

    spec = PlanSpec(**json.loads(spec_json))
    t0, cpu0 = time.perf_counter(), time.process_time()
    scene = read_scene(model, max_edge_m=spec.max_edge_m, split_faces="as_needed")
    result = plan(scene, spec)
    plan_cpu_s = time.process_time() - cpu0
    write_outputs(result, out, None if outputs == "all" else ("plan.json",))
    wall_s, cpu_s = time.perf_counter() - t0, time.process_time() - cpu0
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    document = json.loads((Path(out) / "plan.json").read_text(encoding="utf-8"))
    scene = result.scene
    if doors:
        on_file = np.load(doors)
        n_file = scene.n_faces if scene.file_faces is None else len(scene.file_faces)
        if len(on_file) != n_file:
            raise SystemExit(f"door mask of {len(on_file)} faces for {n_file} file faces")
        door = scene.of_file_faces(on_file)
    else:
        door = door_faces(scene)
    t1 = time.perf_counter()
    blocked = legs_through_walls(scene, door, legs_in_plan(scene, document["route"]))
    check_s = time.perf_counter() - t1
    stations = document["stations"]
    route = document["route"]
    storeys: dict[str, dict[str, Any]] = {}

    def row(name: str) -> dict[str, Any]:
        return storeys.setdefault(name, {"stations": 0, "unreachable": {},
                                         "rooms": 0, "rooms_without_stations": [],
                                         "legs_through_walls": 0, "candidates": None,
                                         "floor_z_m": None})

    for level in document["candidates"].get("levels") or []:
        if "excluded" not in level:
            entry = row(str(level["name"]))
            entry["candidates"], entry["floor_z_m"] = level["candidates"], level["floor_z_m"]
    for room in document["candidates"].get("rooms") or []:
        entry = row(str(room["storey"]) or "no storey")
        entry["rooms"] += 1
        # a room overlapping an earlier one counts the candidates it shares with it too
        shared = int((room.get("shared") or {}).get("candidates", 0))
        entry["candidates"] = (entry["candidates"] or 0) + int(room["candidates"]) - shared
        if entry["floor_z_m"] is None and room["floor_z_m"] is not None:
            entry["floor_z_m"] = room["floor_z_m"]
        if not room.get("stations"):
            entry["rooms_without_stations"].append(
                f"{room['room']}: {room.get('reason') or 'candidates, no station chosen'}")
    for station in stations:
        row(_storey_of(station))["stations"] += 1
    reasons = route.get("unreachable_reasons", {})
    for station_id in route.get("unreachable", []):
        reason = reasons.get(str(station_id), "?")
        counts = row(_storey_of(stations[station_id - 1]))["unreachable"]
        counts[reason] = counts.get(reason, 0) + 1
    for leg in blocked:
        row(_storey_of(stations[leg.end - 1]))["legs_through_walls"] += 1
    excluded = [level for level in document["candidates"].get("levels") or []
                if "excluded" in level]
    figures = {
        "faces": scene.n_faces,
        "wall_s": wall_s, "cpu_s": cpu_s, "peak_mib": peak_mib, "check_s": check_s,
        "plan_cpu_s": plan_cpu_s, "outputs_cpu_s": cpu_s - plan_cpu_s, "outputs": outputs,
        "candidates": document["candidates"]["count"],
        "stations": len(stations),
        "unreachable": len(route.get("unreachable", [])),
        # the walk's parts the model does not join, and why (the step's note)
        "walk_parts": len(route.get("steps_between_parts", [])) + 1,
        "steps": [f"{step['from']} -> {step['to']}: {step['note']}"
                  for step in route.get("steps_between_parts", [])],
        "legs": len(route.get("legs", [])),
        "legs_through_walls": [{**leg.to_dict(), "hit": _what(scene, leg.face)}
                               for leg in blocked],
        "storeys": storeys,
        "not_storeys": Counter(str(level["excluded"]).split(":")[0] for level in excluded),
        "not_storey_heights_m": sorted({float(level["floor_z_m"]) for level in excluded}),
        "route_length_m": route.get("length_m"),
    }
    print(json.dumps(figures))


def _run(label: str, model: Path, spec: dict[str, object], doors: Path | None,
         keep: Path | None, outputs: str) -> dict[str, Any] | None:
    out = tempfile.mkdtemp() if keep is None else str(keep / label.replace(" ", "-"))
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, __file__, "--child", str(model), json.dumps(spec), out,
         "" if doors is None else str(doors), outputs],
        capture_output=True, text=True, check=False, cwd=ROOT)
    if done.returncode != 0:
        print(f"== {label}: failed after {time.perf_counter() - started:.0f} s\n"
              f"{done.stderr.strip()[-1500:]}", flush=True)
        return {"label": label, "failed": done.stderr.strip()[-1500:]}
    figures: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    figures["label"] = label
    print(f"== {label}  ({model.name}, {figures['faces']:,} faces): "
          f"wall {figures['wall_s']:.1f} s, CPU {figures['cpu_s']:.1f} s "
          f"(read and plan {figures['plan_cpu_s']:.1f}, {figures['outputs']} outputs "
          f"{figures['outputs_cpu_s']:.1f}), "
          f"peak {figures['peak_mib']:,.0f} MiB; {figures['candidates']} candidates, "
          f"{figures['stations']} stations, {figures['unreachable']} unreachable, "
          f"{figures['walk_parts']} walk part{'s' if figures['walk_parts'] > 1 else ''}, "
          f"{len(figures['legs_through_walls'])} of {figures['legs']} legs through walls "
          f"(checked in {figures['check_s']:.1f} s)")
    if figures["not_storeys"]:
        print("   not storeys: " + ", ".join(f"{n} {k}" for k, n in
                                             figures["not_storeys"].items()))
    print(f"   {'storey':<34}{'floor m':>8}{'cand.':>7}{'stat.':>6}{'unreach.':>9}"
          f"{'rooms':>6}{'no stat.':>9}{'thru wall':>10}")
    for name, entry in figures["storeys"].items():
        z = entry["floor_z_m"]
        print(f"   {name[:33]:<34}{'' if z is None else f'{z:+.2f}':>8}"
              f"{'' if entry['candidates'] is None else entry['candidates']:>7}"
              f"{entry['stations']:>6}{sum(entry['unreachable'].values()):>9}"
              f"{entry['rooms']:>6}{len(entry['rooms_without_stations']):>9}"
              f"{entry['legs_through_walls']:>10}")
        for reason, count in entry["unreachable"].items():
            print(f"      {count} unreachable: {reason}")
        for room in entry["rooms_without_stations"]:
            print(f"      no station: {room}")
    for step in figures["steps"]:
        print(f"      step between parts {step}")
    for leg in figures["legs_through_walls"][:5]:
        print(f"      through a wall: leg {leg['from']} -> {leg['to']} at {leg['at']} "
              f"({leg['height_m']} m above its floor) {leg['hit']}")
    sys.stdout.flush()
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default=",".join(MODELS),
                        help=f"comma-separated, of {', '.join(MODELS)}")
    parser.add_argument("--skip-large", action="store_true",
                        help=f"leave out {' and '.join(LARGE)}")
    parser.add_argument("--forms", default="ifc,obj",
                        help="comma-separated, of ifc and obj (default: both)")
    parser.add_argument("--outputs", choices=("all", "plan"), default="all",
                        help="write every output (as the command line) or plan.json only")
    parser.add_argument("--grid-spacing-m", type=float, default=None)
    parser.add_argument("--slabs", choices=("with", "without", "both"), default="with",
                        help="plan each model as it is, without its IfcSlab and IfcCovering "
                             "elements (an architect's model without the structural one; "
                             "its plain mesh too), or both")
    parser.add_argument("--json", type=Path, default=None, help="write the figures here")
    parser.add_argument("--keep", type=Path, default=None, help="keep the outputs here")
    args = parser.parse_args()
    names = [n for n in args.models.split(",") if n]
    for name in names:
        if name not in MODELS:
            parser.error(f"unknown model {name!r}: {', '.join(MODELS)}")
    if args.skip_large:
        names = [n for n in names if n not in LARGE]
    forms = args.forms.split(",")
    for form in forms:
        if form not in ("ifc", "obj"):
            parser.error(f"unknown form {form!r}: ifc, obj or ifc,obj")
    spec: dict[str, object] = {}
    if args.grid_spacing_m is not None:
        spec["grid_spacing_m"] = args.grid_spacing_m
    results: list[dict[str, Any] | None] = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name in names:
            variants = [] if args.slabs == "without" else [(name, MODELS[name])]
            if args.slabs != "with":
                bare = work / f"{name}-without-slabs.ifc"
                subprocess.run([sys.executable, __file__, "--strip", str(MODELS[name]),
                                str(bare)], check=True, cwd=ROOT)
                variants.append((f"{name} without slabs", bare))
            for label, ifc in variants:
                if "ifc" in forms:
                    results.append(_run(f"{label} IFC", ifc, spec, None, args.keep,
                                        args.outputs))
                if "obj" in forms:
                    stem = label.replace(" ", "-")
                    obj, doors = work / f"{stem}.obj", work / f"{stem}.doors.npy"
                    subprocess.run([sys.executable, __file__, "--export", str(ifc),
                                    str(obj), str(doors)], check=True, cwd=ROOT)
                    results.append(_run(f"{label} OBJ", obj, spec, doors, args.keep,
                                        args.outputs))
    print("\n| model | storeys | candidates | stations | unreachable | walk parts "
          "| rooms w/o station | legs through walls | not storeys | wall s | CPU s "
          "| outputs CPU s | peak MiB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for figures in results:
        if figures is None or "failed" in figures:
            label = "?" if figures is None else figures["label"]
            print(f"| {label} | failed | | | | | | | | | | | |")
            continue
        storeys = [s for s in figures["storeys"].values() if s["stations"]]
        print(f"| {figures['label']} | {len(storeys)} | {figures['candidates']} "
              f"| {figures['stations']} | {figures['unreachable']} | {figures['walk_parts']} "
              f"| {sum(len(s['rooms_without_stations']) for s in figures['storeys'].values())}"
              f" | {len(figures['legs_through_walls'])} of {figures['legs']} "
              f"| {', '.join(f'{n} {k}' for k, n in figures['not_storeys'].items()) or '-'} "
              f"| {figures['wall_s']:.0f} | {figures['cpu_s']:.0f} "
              f"| {figures['outputs_cpu_s']:.0f} ({figures['outputs']}) "
              f"| {figures['peak_mib']:,.0f} |")
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    if len(sys.argv) == 7 and sys.argv[1] == "--child":
        _child(*sys.argv[2:])
    elif len(sys.argv) == 4 and sys.argv[1] == "--strip":
        _strip(*sys.argv[2:])
    elif len(sys.argv) == 5 and sys.argv[1] == "--export":
        _export(*sys.argv[2:])
    else:
        main()
