"""The documentation builds with --strict and cannot drift from the code.

The site is built once into a temporary folder (about 20 s); the generated parameter page
must list every parameter of ``RANGES`` with both bounds of its range, and every public
module of ``planner`` must have its API page.
"""

from __future__ import annotations

import html
import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from planner.parameters import RANGES

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "DISABLE_MKDOCS_2_WARNING": "true"}
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{run.stdout}\n{run.stderr}"
    return out


def _rows(page: Path) -> list[str]:
    """The text of every table row of a built page, tags stripped."""
    text = page.read_text(encoding="utf-8")
    return [html.unescape(re.sub(r"<[^>]+>", " ", row))
            for row in re.findall(r"<tr>(.*?)</tr>", text, flags=re.S)]


def test_every_range_is_on_the_parameters_page(site: Path) -> None:
    rows = _rows(site / "reference" / "parameters" / "index.html")
    for name, bounds in RANGES.items():
        row = next((r for r in rows if r.split() and r.split()[0] == name), None)
        assert row is not None, f"{name} has no row on the parameters page"
        low = bounds.ge if bounds.ge is not None else bounds.gt
        high = bounds.le if bounds.le is not None else bounds.lt
        for bound in (low, high):
            if bound is not None:
                assert f"{bound:g}" in row, f"{name}: {bound:g} missing from {row!r}"


def test_every_public_module_has_an_api_page(site: Path) -> None:
    api = site / "reference" / "api"
    for path in (ROOT / "planner").rglob("*.py"):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if any(part.startswith("_") for part in parts):
            continue
        page = api.joinpath(*parts, "index.html")
        assert page.exists(), f"no API page for {'.'.join(parts)}"
        assert ".".join(parts) in page.read_text(encoding="utf-8")


def _hooks() -> ModuleType:
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs/gen/hooks.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_benchmark_matrix_table_is_tolerant(tmp_path: Path) -> None:
    hooks = _hooks()
    hooks.MATRIX = tmp_path / "matrix_baseline.json"
    assert "not been recorded yet" in hooks.benchmark_matrix()
    hooks.MATRIX.write_text(json.dumps({"machine": "2 cores", "rows": [
        {"model": "hall-full", "wall_s": 6.5, "stages": {"visibility": {"wall_s": 2.6}}},
        {"model": "office", "peak_mib": 1750}]}))
    table = hooks.benchmark_matrix()
    assert "| model | wall_s | stages | peak_mib |" in table
    assert "| hall-full | 6.5 | visibility wall_s 2.6 |  |" in table
    assert "| office |  |  | 1750 |" in table and "2 cores" in table
    hooks.MATRIX.write_text(json.dumps([1, 2, 3]))  # a shape not settled yet: no table
    assert "|" not in hooks.benchmark_matrix()
