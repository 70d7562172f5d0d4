"""Command line: ``scanplan plan SCENE --out DIR``, ``scanplan verify PLAN_DIR --scene SCENE``
and the subcommands other packages add.

Errors print one line naming the parameter and the fix, and exit with status 2. On a
terminal a progress line shows the stage and percent; piped, the command stays quiet.
Packages add subcommands (the service adds ``serve`` and ``worker``) through the entry point
group ``scanplan.commands``: a callable that takes the argparse subparsers object.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
import time
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, NoReturn, TextIO

from planner.errors import PlannerError
from planner.kernels import pin_numba_target
from planner.parameters import PlanSpec
from planner.version import __version__

# True in the ``scanplan`` command's own process (:func:`run`), not when a program calls
# :func:`main`: ``scanplan plan`` then freezes the objects its imports made out of the
# garbage collector (:func:`gc.freeze`; some 110,000, every one of them kept to the end
# anyway), so its collections during the plan do not go over them again (hall-full, two
# sets of four runs: 5.03 -> 4.84 s and 5.07 -> 4.93 s). A program's own objects are left
# to its collector.
_COMMAND = False


class ProgressLine:
    """``stage  42 %`` rewritten in place on a terminal; silent when not a terminal."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.enabled = stream.isatty()
        self._last = ""

    def __call__(self, stage: str, fraction: float) -> bool:
        if self.enabled:
            width = 30
            filled = round(fraction * width)
            text = f"\r{stage:<11} [{'#' * filled}{'.' * (width - filled)}] {fraction * 100:5.1f} %"
            if text != self._last:
                self.stream.write(text)
                self.stream.flush()
                self._last = text
        return False

    def done(self) -> None:
        if self.enabled and self._last:
            self.stream.write("\r" + " " * len(self._last) + "\r")
            self.stream.flush()


# the stages after the selection (planner.pipeline), which start the renderers' imports
# when the selection reported no progress of its own
LATER_STAGES = ("report", "writing")


class PreloadAtSelection:
    """Passes progress on to ``progress``; once the selection has made its heuristic plans
    (its first progress past 0) or a later stage starts, starts importing the renderers'
    modules in the background (:func:`planner.outputs.report.preload_renderers`). The
    lower bound that follows runs on one thread, so the imports take an idle core instead
    of the pictures' time after the plan: on hall-full (66 k faces) some 1 CPU second of
    the 2.9 its outputs took. Not before the heuristics: greedy and weighted greedy take
    both cores (when they were Python loops, beside the imports they took 0.7 instead of
    0.18 s on hall-full)."""

    def __init__(self, progress: ProgressLine) -> None:
        self.progress = progress
        self.started = False

    def __call__(self, stage: str, fraction: float) -> bool:
        if not self.started and ((stage == "selection" and fraction > 0)
                                 or stage in LATER_STAGES):
            from planner.outputs.report import preload_renderers

            preload_renderers()
            self.started = True
        return self.progress(stage, fraction)


def load_params(path: str | None) -> dict[str, Any]:
    if path is None:
        return {}
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise PlannerError(f"--params: cannot read {path}: {exc.strerror}") from exc
    except json.JSONDecodeError as exc:
        raise PlannerError(f"--params: {path} is not valid JSON ({exc.msg} at line "
                           f"{exc.lineno}); fix the file") from exc
    if not isinstance(data, dict):
        raise PlannerError(f"--params: {path} must hold a JSON object of parameters")
    return data


def run_plan(args: argparse.Namespace) -> int:
    # imported here, not at the top: they bring numpy, scipy, trimesh and numba, which
    # ``scanplan --help`` and the service's subcommands do not need
    from planner.candidates.grid import read_candidates_csv
    from planner.io.readers import read_scene
    from planner.outputs.report import absent_outputs, write_outputs
    from planner.pipeline import plan

    if _COMMAND:  # see run()
        gc.freeze()
    values = load_params(args.params)
    if args.candidates:
        values["candidates"] = read_candidates_csv(args.candidates).tolist()
    spec = PlanSpec.from_mapping(values)
    progress = ProgressLine(sys.stderr)
    started = time.perf_counter()
    progress("reading", 0.0)
    scene = read_scene(args.scene, max_edge_m=spec.max_edge_m, unit_scale=spec.unit_scale,
                       up_axis=spec.up_axis, split_faces="as_needed")
    try:
        result = plan(scene, spec, progress=PreloadAtSelection(progress),
                      dask_scheduler=args.dask_scheduler)
        progress("writing", 1.0)
        written = write_outputs(result, args.out)
        if spec.verify:  # as `scanplan verify` would, on the plan just written
            from planner.truth.verification import read_plan_dir, verify_plan_dir

            _, checked = verify_plan_dir(args.out, result.scene, read_plan_dir(args.out),
                                         progress=progress)
            written += [path for path in checked if path not in written]
    finally:
        progress.done()
    if not args.quiet:
        plan_doc = json.loads(written[0].read_text())
        totals = plan_doc["totals"]
        from planner.candidates.grid import levels_line

        for line in (levels_line(plan_doc["candidates"].get("levels")),
                     plan_doc["candidates"].get("floor_note")):
            if line:
                print(line)
        from planner.candidates.rooms import rooms_lines

        for line in rooms_lines(plan_doc["candidates"].get("rooms")):  # IFC: per storey
            print(line)
        print(
            f"{totals['stations']} stations cover {totals['covered_area_m2']:.2f} m² "
            f"of {totals['max_achievable_area_m2']:.2f} m² achievable "
            f"({totals['coverage_fraction'] * 100:.1f} %) from {totals['candidates']} "
            f"candidates in {time.perf_counter() - started:.1f} s; wrote "
            f"{', '.join(p.name for p in written)} to {args.out}"
        )
        for name, reason in absent_outputs(result).items():
            print(f"no {name}: {reason}")
        from planner.selection.budget import budget_line
        from planner.survey.route import door_checks_line, parts_line

        for line in (budget_line(plan_doc["selection"]),  # the bound beside a budget's plan
                     parts_line(plan_doc.get("route")),  # a model not joined on foot
                     door_checks_line(plan_doc.get("route"))):  # a plain mesh's glazed doors
            if line:
                print(line)
    return 0


def run_scanners(args: argparse.Namespace) -> int:
    from planner.scanners import FIGURES, presets  # lazily: only this command reads them

    if args.json:
        print(json.dumps([p.to_dict() for p in presets().values()], indent=2))
        return 0
    cited: dict[str, dict[str, Any]] = {}
    for preset in presets().values():
        print(f"{preset.id}  {preset.profile.name} ({preset.maker})")
        for name in FIGURES:
            figure = preset.figures.get(name)
            if figure is None:
                continue
            if figure["value"] is None:  # "-": no source, the plan keeps its default
                print(f"    {name:<24} {'-':>10}  no source: {figure['reason']}")
            else:
                keys = [figure["source"], *figure.get("also", ())]
                print(f"    {name:<24} {figure['value']:>10g}  {', '.join(keys)}")
        for setting in preset.profile.settings:
            print(f"    setting {setting.name:<16} {setting.point_spacing_m * 1000:>7g} mm at "
                  f"{setting.reference_distance_m:g} m  {preset.settings_note.get('source', '')}")
        if not preset.profile.settings:
            print(f"    {'settings':<24} {'-':>10}  no source: "
                  f"{preset.settings_note.get('reason', '')}")
        cited.update(preset.sources)
    print("sources")
    for key, source in sorted(cited.items()):
        where = source.get("url") or source.get("corpus_file")
        print(f"    {key:<24} {source['title']}; {where}")
    return 0


def run_verify(args: argparse.Namespace) -> int:
    from planner.io.readers import read_scene
    from planner.truth.verification import read_plan_dir, split_as_planned, verify_plan_dir

    files = read_plan_dir(args.plan_dir)
    progress = ProgressLine(sys.stderr)
    started = time.perf_counter()
    progress("reading", 0.0)
    scene = split_as_planned(read_scene(
        args.scene, max_edge_m=files.spec.max_edge_m, unit_scale=files.spec.unit_scale,
        up_axis=files.spec.up_axis, split_faces="as_needed"), files)
    try:
        result, written = verify_plan_dir(args.plan_dir, scene, files, progress=progress)
    finally:
        progress.done()
    if not args.quiet:
        totals = result.totals()
        print(
            f"{len(files.stations_xyz)} stations: promised {totals['promised_area_m2']:.2f} m², "
            f"delivered {totals['delivered_area_m2']:.2f} m², promised but not delivered "
            f"{totals['promised_not_delivered_area_m2']:.2f} m², delivered but not promised "
            f"{totals['delivered_not_promised_area_m2']:.2f} m², holes "
            f"{totals['hole_area_m2']:.2f} m² in {time.perf_counter() - started:.1f} s; "
            f"wrote {', '.join(p.name for p in written)} to {args.plan_dir}"
        )
    return 0


def run_examples(args: argparse.Namespace) -> int:
    from planner.examples import EXAMPLES, copy_example

    if args.name is None:
        width = max(len(name) for name in EXAMPLES)
        for example in EXAMPLES.values():
            print(f"{example.name:<{width}}  {example.about}")
        print("\nscanplan examples NAME copies one here (the public ones are downloaded "
              "once, checked by sha256; offline: set SCANPLAN_DATA_MIRROR)")
        return 0
    copied = copy_example(args.name, Path(args.to))
    example = EXAMPLES[args.name]
    for path in copied:
        print(f"wrote {path}")
    command = ["scanplan", "plan", str(copied[0])]
    if example.candidates is not None:
        command += ["--candidates", str(Path(args.to) / Path(example.candidates).name)]
    command += ["--out", f"{args.name}-plan"]
    print("plan it with:\n  " + " ".join(command))
    return 0


# The plans ``scanplan compile-kernels`` makes, on the examples the package ships, so that
# every kernel a plan calls is compiled once: an IFC building with its rooms and every
# output, at the default goal and at 100 % (the full cover's bound), with ``optimal`` and
# with a budget; the same building as a plain mesh (no classes: floors and doors found in
# the mesh); a hall with given candidates and with grid ones. A kernel none of them calls
# with the argument types a model gives it is compiled by the first plan that does.
# (example, form: "as shipped", "plain mesh" or "with candidates", plan parameters)
KERNEL_PLANS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("ifcopenhouse", "as shipped", {}),
    ("ifcopenhouse", "as shipped", {"coverage_goal": 1.0}),
    ("ifcopenhouse", "as shipped", {"method": "optimal"}),
    ("ifcopenhouse", "as shipped", {"max_stations": 2}),
    ("ifcopenhouse", "plain mesh", {}),
    ("hall-small", "with candidates", {}),
    ("hall-small", "as shipped", {}),
)


def _kernel_model(name: str, form: str, scratch: Path) -> list[str]:
    """The model argument (and ``--candidates``) of one of :data:`KERNEL_PLANS`."""
    from planner.examples import EXAMPLES, find

    example = EXAMPLES[name]
    model = find(example.files[0])
    if form == "plain mesh":  # its triangles only, as a BIM tool's mesh export gives
        from planner.io.readers import read_scene

        scene = read_scene(model)
        plain = scratch / f"{model.stem}.obj"
        with plain.open("w", encoding="utf-8") as out:
            out.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in scene.vertices.tolist())
            out.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in scene.faces.tolist())
        return [str(plain)]
    if form == "with candidates" and example.candidates is not None:
        return [str(model), "--candidates", str(find(example.candidates))]
    return [str(model)]


def run_compile_kernels(args: argparse.Namespace) -> int:
    """Plans :data:`KERNEL_PLANS` in a scratch folder, which compiles the planner's
    kernels into numba's cache, then says how many it compiled and where they went."""
    import tempfile

    started = time.perf_counter()
    if not args.quiet:
        print(f"compiling the planner's kernels: {len(KERNEL_PLANS)} plans of the examples "
              "(about a minute on two cores)", flush=True)
    parser = build_parser()
    with tempfile.TemporaryDirectory(prefix="scanplan-kernels-") as folder:
        scratch = Path(folder)
        for number, (name, form, params) in enumerate(KERNEL_PLANS):
            params_path = scratch / f"params-{number}.json"
            params_path.write_text(json.dumps(params), encoding="utf-8")
            run_plan(parser.parse_args(
                ["plan", *_kernel_model(name, form, scratch), "--params", str(params_path),
                 "--out", str(scratch / f"plan-{number}"), "--quiet"]))
    compiled, loaded = kernel_counts()
    if not args.quiet:
        where = os.environ.get("NUMBA_CACHE_DIR") or "__pycache__ beside the planner's modules"
        target = os.environ.get("NUMBA_CPU_NAME") or "this CPU"
        print(f"compiled {compiled} kernels for {target} into numba's cache ({where}), "
              f"{loaded} were there already, in {time.perf_counter() - started:.1f} s; "
              "plans start without compiling them")
    return 0


def _loaded_kernels() -> list[Any]:
    """Each compiled kernel (numba ``Dispatcher``) of the planner's modules imported in
    this process, once."""
    from numba.core.dispatcher import Dispatcher

    kernels: dict[int, Any] = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("planner.") or module is None:
            continue
        for value in vars(module).values():
            if isinstance(value, Dispatcher):
                kernels.setdefault(id(value), value)
    return list(kernels.values())


def kernel_counts() -> tuple[int, int]:
    """How many of the planner's compiled kernels this process compiled and how many it
    loaded from numba's cache (a kernel compiled for two argument types counts twice)."""
    compiled = loaded = 0
    for kernel in _loaded_kernels():
        compiled += sum(kernel.stats.cache_misses.values())
        loaded += sum(kernel.stats.cache_hits.values())
    return compiled, loaded


def warm_up() -> tuple[int, int]:
    """Imports every module of the planner (the renderers' libraries with them) and loads
    every kernel numba's cache holds for this target, compiling none; returns how many
    modules were imported and how many kernels loaded.

    For a process that forks the processes that plan (the service's consumer): each fork
    then starts with all of it in memory, shared with the others, instead of importing the
    renderers and loading the kernels it calls one by one (numba loads a kernel from its
    cache when a process first calls it, after it has set up its compiler's context once).
    A module that needs an optional dependency not installed (Dask) is left out.

    numba keeps no public list of what its cache holds, so each kernel's index is read
    the way numba reads it on a kernel's first call (its cache's ``_load_index`` and
    ``_index_key``, as numba 0.68 has them); where those are not there, the warm-up loads
    no kernel and plans load them as they call them, as before.
    """
    import importlib
    import pkgutil

    import planner

    imported = 0
    for found in pkgutil.walk_packages(planner.__path__, "planner."):
        if found.name == __name__ or found.name.endswith(".__main__"):
            continue
        try:
            importlib.import_module(found.name)
        except ImportError:  # an optional dependency (dask for planner.scaleout)
            continue
        imported += 1

    loaded = 0
    for kernel in _loaded_kernels():
        signatures = _cached_signatures(kernel)
        if signatures is None:  # another numba's internals
            return imported, loaded
        for signature in signatures:
            kernel.compile(signature)
            loaded += 1
    return imported, loaded


def _cached_signatures(kernel: Any) -> list[Any] | None:
    """The argument types numba's cache holds ``kernel`` (a numba ``Dispatcher``) compiled
    for, on this target and of this source: what numba would load for them on a first call
    rather than compile. None where numba's cache is not what :func:`warm_up` knows."""
    try:
        cache = kernel._cache
        codegen = kernel.targetctx.codegen()
        index = cache._cache_file._load_index()  # {} when the source changed since
        return [key[0] for key in index if key == cache._index_key(key[0], codegen)]
    except AttributeError:
        return None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="scanplan", description="Plan terrestrial laser scanner stations on a 3D model."
    )
    parser.add_argument("--version", action="version", version=f"scanplan {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("plan", help="plan stations for a model and write the results")
    p.add_argument("scene", help="model file: OBJ, PLY, STL, OFF, GLB/glTF or IFC")
    p.add_argument("--candidates", help="CSV of scanner positions with header x,y,z")
    p.add_argument("--params", help="JSON object of parameters (names as in the API)")
    p.add_argument("--out", required=True, help="directory for plan.json, faces.npz, ...")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.add_argument("--dask-scheduler", metavar="ADDRESS",
                   default=os.environ.get("SCANPLAN_DASK_SCHEDULER") or None,
                   help="run the visibility and the overlap rows on the workers of the Dask "
                        "scheduler at ADDRESS (tcp://host:8786; default: "
                        "$SCANPLAN_DASK_SCHEDULER); the plan's files are the same")
    p.set_defaults(handler=run_plan)
    s = sub.add_parser("scanners", help="list the scanner presets (the scanner parameter)")
    s.add_argument("--json", action="store_true", help="print the presets with their sources")
    s.set_defaults(handler=run_scanners)
    v = sub.add_parser("verify", help="check a plan by a simulated scan of its stations")
    v.add_argument("plan_dir", help="the --out directory of 'scanplan plan'")
    v.add_argument("--scene", required=True,
                   help="the model the plan was made from (read with the plan's max_edge_m "
                        "and unit_scale)")
    v.add_argument("--quiet", action="store_true", help="print nothing on success")
    v.set_defaults(handler=run_verify)
    e = sub.add_parser("examples", help="list the example models, or fetch one to plan")
    e.add_argument("name", nargs="?", help="the example to fetch (none: list them)")
    e.add_argument("--to", default=".", help="the directory to copy it into (default: here)")
    e.set_defaults(handler=run_examples)
    k = sub.add_parser("compile-kernels",
                       help="compile the planner's kernels now (once after installing), so "
                            "that the first plan does not")
    k.add_argument("--quiet", action="store_true", help="print nothing on success")
    k.set_defaults(handler=run_compile_kernels)
    for entry in entry_points(group="scanplan.commands"):
        entry.load()(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    # before anything imports numba: its kernels compiled for one instruction set on every
    # machine that runs it, so one machine's cache serves another (planner.kernels)
    pin_numba_target()
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code: int = args.handler(args)
    except PlannerError as exc:
        print(f"scanplan: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("scanplan: interrupted", file=sys.stderr)
        return 130
    return code


def run() -> NoReturn:
    """The ``scanplan`` command: :func:`main`, then exit without the interpreter's last
    collections. At exit CPython collects every object the run made, over and over as it
    tears the modules down (hall-full: about 1 s of an 11 s plan, the office more); the
    process is ending, so every object is frozen out of those collections
    (:func:`gc.freeze`) and its memory goes back with the process. Files are closed and
    atexit handlers run as before."""
    global _COMMAND
    _COMMAND = True
    code = main()
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":
    run()
