"""Write one Python API page per module of ``planner/`` and their navigation, at build time.

Run by the mkdocs-gen-files plugin (mkdocs.yml). It walks the package on disk, so the pages
follow whatever layout the package has: a package gets ``reference/api/<path>/index.md``, a
module ``reference/api/<path>.md``, each holding one mkdocstrings directive. Private modules
(a leading underscore) and ``planner.__main__`` (the command line, see reference/cli.md) are
left out. ``reference/api/SUMMARY.md`` is the section's navigation (mkdocs-literate-nav).
"""

from __future__ import annotations

from pathlib import Path

import mkdocs_gen_files

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "planner"
OUT = Path("reference", "api")


def public_modules(package_dir: Path) -> list[tuple[str, ...]]:
    """Dotted parts of every public module and package under ``package_dir``, sorted."""
    found: list[tuple[str, ...]] = []
    for path in sorted(package_dir.rglob("*.py")):
        relative = path.relative_to(package_dir.parent).with_suffix("")
        parts = tuple(relative.parts)
        # a package's pages come from its __init__; skip folders that are not packages
        if any(not (package_dir.parent.joinpath(*parts[:i]) / "__init__.py").exists()
               for i in range(1, len(parts))):
            continue
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if any(part.startswith("_") for part in parts):  # private, __main__, __pycache__
            continue
        found.append(parts)
    return sorted(set(found))


nav = mkdocs_gen_files.Nav()
for parts in public_modules(ROOT / PACKAGE):
    is_package = (ROOT.joinpath(*parts) / "__init__.py").exists()
    doc_path = Path(*parts, "index.md") if is_package else Path(*parts).with_suffix(".md")
    nav[parts] = doc_path.as_posix()
    with mkdocs_gen_files.open(OUT / doc_path, "w") as page:
        page.write(f"::: {'.'.join(parts)}\n")

with mkdocs_gen_files.open(OUT / "SUMMARY.md", "w") as summary:
    summary.writelines(nav.build_literate_nav())
