"""Real buildings: every storey planned, a route through doors and stairs, time and memory.

Plans, with default parameters, the shared IFC houses as IFC and as plain meshes exported
from them (no IFC classes, no groups) and a generated office (``tests/planner/buildings.py``:
two units joined only outside, corridors, closed doors, a stepped and a sloped stair), each
in a fresh child process, and prints per model: seconds per stage (``Stats.seconds``), peak
memory of the child (``ru_maxrss``), candidates, stations, levels (storeys planned and
what was excluded, with the reason) and the unreachable stations with their reasons.

Prints figures, never passes or fails on them::

    .venv/bin/python benchmarks/plan_building.py [--models fzk,openhouse,office]
        [--floors 3] [--rooms 4] [--faces 0] [--grid-spacing-m 0.5] [--keep DIR]

``--faces N`` cuts the office's faces to about N (``max_edge_for_faces``; 0: coarse boxes,
remeshed by the plan's ``max_edge_m`` as any model).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT.parent / "shared" / "scenes"
HOUSES = {"fzk": SCENES / "AC20-FZK-Haus.ifc", "openhouse": SCENES / "IfcOpenHouse_IFC4.ifc"}


def _child(model: str, spec_json: str, out: str) -> None:
    """Plan ``model`` in this process and print one JSON line of figures."""
    from planner.io.readers import read_scene
    from planner.outputs.report import write_outputs
    from planner.parameters import PlanSpec
    from planner.pipeline import plan

    spec = PlanSpec(**json.loads(spec_json))
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    scene = read_scene(model, max_edge_m=spec.max_edge_m, split_faces="as_needed")
    read_s = time.perf_counter() - t0
    result = plan(scene, spec)
    t1 = time.perf_counter()
    write_outputs(result, out)
    plan_doc = json.loads((Path(out) / "plan.json").read_text(encoding="utf-8"))
    route = plan_doc.get("route", {})
    figures = {
        "faces": result.scene.n_faces,
        "seconds": {"read": read_s, **result.stats.seconds,
                    "outputs": time.perf_counter() - t1},
        "cpu_s": time.process_time() - cpu0,
        "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "candidates": len(result.candidates),
        "stations": len(result.chosen.stations),
        "levels": plan_doc["candidates"].get("levels"),
        "unreachable": route.get("unreachable", []),
        "unreachable_reasons": route.get("unreachable_reasons", {}),
    }
    print(json.dumps(figures))


def _run(label: str, model: Path, spec: dict[str, object], keep: Path | None) -> None:
    out = tempfile.mkdtemp() if keep is None else str(keep / label)
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, __file__, "--child", str(model), json.dumps(spec), out],
        capture_output=True, text=True, check=False)
    wall_s = time.perf_counter() - started
    if done.returncode != 0:
        print(f"{label}: failed\n{done.stderr.strip()[-2000:]}")
        return
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    print(f"== {label}  ({model.name}, {figures['faces']:,} faces)")
    print(f"   wall {wall_s:7.1f} s, cpu {figures['cpu_s']:7.1f} s, peak {figures['peak_mib']:,.0f}"
          f" MiB (ru_maxrss of the child)")
    for stage, seconds in figures["seconds"].items():
        print(f"   {stage:<24}{seconds:8.2f} s")
    print(f"   candidates {figures['candidates']}, stations {figures['stations']}")
    for level in figures["levels"] or []:
        what = level.get("excluded") or "storey"
        print(f"   level {level.get('floor_z_m'):+7.2f} m  {level.get('area_m2', '?')!s:>8} m²  "
              f"{level.get('candidates', 0):5d} candidates  {what}")
    reasons = figures["unreachable_reasons"]
    print(f"   unreachable stations: {len(figures['unreachable'])} {figures['unreachable']}")
    for station, reason in sorted(reasons.items(), key=lambda kv: int(kv[0])):
        print(f"     {station}: {reason}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default="fzk,openhouse,office")
    parser.add_argument("--floors", type=int, default=3)
    parser.add_argument("--rooms", type=int, default=4, help="office rooms a corridor side")
    parser.add_argument("--faces", type=int, default=0, help="office faces (0: coarse)")
    parser.add_argument("--grid-spacing-m", type=float, default=None)
    parser.add_argument("--keep", type=Path, default=None, help="keep the outputs here")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from tests.planner.buildings import export_plain_mesh, max_edge_for_faces, office_building

    spec: dict[str, object] = {}
    if args.grid_spacing_m is not None:
        spec["grid_spacing_m"] = args.grid_spacing_m
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name in args.models.split(","):
            if name in HOUSES:
                ifc = HOUSES[name]
                _run(f"{name} (IFC)", ifc, spec, args.keep)
                for ext in ("obj", "ply"):
                    plain = export_plain_mesh(ifc, work / f"{name}-plain.{ext}")
                    _run(f"{name} (plain {ext.upper()})", plain, spec, args.keep)
            elif name == "office":
                t0 = time.perf_counter()
                edge = max_edge_for_faces(args.faces, args.floors, args.rooms) if args.faces \
                    else None
                mesh = office_building(args.floors, args.rooms, edge)
                path = work / "office.ply"
                mesh.export(path)
                print(f"office: {args.floors} storeys, {args.rooms} rooms a side, "
                      f"{len(mesh.faces):,} faces, generated in {time.perf_counter() - t0:.1f} s")
                _run("office (plain PLY)", path, spec, args.keep)
            else:
                parser.error(f"unknown model {name!r}: fzk, openhouse or office")


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--child":
        _child(*sys.argv[2:])
    else:
        main()
