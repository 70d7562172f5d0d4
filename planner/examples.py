"""Example models: the ones scanplan ships, and public ones fetched by hash.

Every file is named by its path in the layout of the team's scenes folder (``hall-small/
hall.obj``, ``buildings/Renga-House.ifc``) and known by its sha256. A file is found, in this
order:

1. in the package (``planner/example_data/``: the synthetic halls, ours, and the
   IfcOpenHouse IFC example);
2. in the directory ``SCANPLAN_DATA_MIRROR`` names, laid out the same way (an offline
   mirror: CI points it at the team's scenes folder);
3. in the download cache (``SCANPLAN_DATA_CACHE``, default ``scanplan`` in the user's
   cache folder);
4. downloaded from its public source at a pinned commit, with pooch, into that cache.

Every file taken from a mirror, the cache or the network is checked against its sha256.
The sources and licences are those of the scenes folder's READMEs.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from planner.errors import PlannerError

MIRROR_VARIABLE = "SCANPLAN_DATA_MIRROR"
CACHE_VARIABLE = "SCANPLAN_DATA_CACHE"

_WEB_IFC = ("https://raw.githubusercontent.com/ThatOpen/engine_web-ifc/"
            "233e3aa7118d7364606dcb171206a89b3ed62657/tests/ifcfiles/public/")
_OPEN_BIM = ("https://raw.githubusercontent.com/opensourceBIM/TestFiles/"
             "2fdf94854a7fba814a17604ed65f543f125cd265/TestData/data/")


@dataclass(frozen=True)
class DataFile:
    """One file: its path in the scenes layout, sha256, public address (None: shipped in
    the package) and who made it, under which terms."""

    path: str
    sha256: str
    url: str | None
    source: str


@dataclass(frozen=True)
class Example:
    """A model a user can plan: its name, what it is, its files (the first is the model)
    and the parameters its plan takes beyond the defaults (``--candidates``: a CSV)."""

    name: str
    about: str
    files: tuple[str, ...]
    candidates: str | None = None


_HALL = "synthetic hall made for scanplan at the scale of the paper's experiment (ours)"
# the halls' files: ours, shipped in the package
_HALL_FILES = {
    "hall-small/hall.obj":
        "8460f729c01b219962341c3a61038e4a35254038f61e3a399c34bb817a739e1b",
    "hall-small/candidates.csv":
        "b887ab3fec7621b2009731c0c1437ffa59782250badb53ecc763e39ca4eff012",
    "hall-small/expected.json":
        "415bccdf88f1f7b36a9b73358e6740fca64901839a73b36c4a65513ed710cea5",
    "hall-small/scene.json":
        "8c137e994339a7df546be4137e2d9b41f964fc6347671316d1d08a63e77e6c9e",
    "hall-full/hall.obj":
        "84b581172a19a3f63c747352a8ec4d85f7b96a4eb0743aac077007b7872983ef",
    "hall-full/candidates.csv":
        "2d0c7e317aebf6693d30606aa91d0df81b2afdebd4e4624cfb18ca16ee883070",
    "hall-full/expected.json":
        "f55469f6ee1e61bd04b551a0e53faf6fa46432b68adb3c66e82fbdd5c2318837",
    "hall-full/scene.json":
        "85f4e4d6e16e95870dd50b023e549f9a0b6bdaf31acd77d881d4fd0a0a349192",
}
FILES: dict[str, DataFile] = {f.path: f for f in (
    *(DataFile(path, sha256, None, _HALL) for path, sha256 in _HALL_FILES.items()),
    DataFile("IfcOpenHouse_IFC4.ifc",
             "71c9466bf02306be58d45b77d738541a0e7410767960b5eed1cf85737dfa34c9", None,
             "IfcOpenShell's IfcOpenHouse example (IFC4, written by IfcOpenShell 0.5.0-dev), "
             "from ThatOpen/engine_web-ifc at 233e3aa, tests/ifcfiles/public"),
    DataFile("AC20-FZK-Haus.ifc",
             "70cc8ff245fc0894201d96496c031005a5cbd7a96b22d8a1b87c5a883fb77994",
             _WEB_IFC + "AC20-FZK-Haus.ifc",
             "KIT IAI's FZK-Haus (ArchiCAD 20, IFC4), a free IFC example file; attribute "
             "Karlsruhe Institute of Technology, Institute for Automation and Applied "
             "Informatics"),
    DataFile("copyroom_scan_c2000.ply",
             "5a501296688812e27e9d1fee342ec37d6174ffbb4ec8f1bc4ad60866cad67a7e",
             "https://raw.githubusercontent.com/chaowang15/plane-opt-rgbd/"
             "5ff18eb2a44849c840942768e3f3462f69fa27cb/models/copyroom/copyroom_c2000_opt.ply",
             "a plane-simplified RGB-D scan of a copy room, (c) 2021 Chao Wang, MIT"),
    DataFile("buildings/Renga-House.ifc",
             "d62967b2620113689c84e855d1adbab6cca3243dcd43ca3f31ca325a128fa54d",
             "https://raw.githubusercontent.com/xBimTeam/XbimEssentials/"
             "e3c877712aeff39813219b9dd13383c266d07055/Tests/TestSourceFiles/House.ifc",
             "a Renga Architecture house (ASCON), from XbimEssentials' tests (CDDL)"),
    DataFile("buildings/AC90R1-niedriha-V2-2x3.ifc",
             "47eb2faed9ebdeb4caf31621bc9898442618631e71e8eb91d3056b18ca3fdac4",
             _OPEN_BIM + "AC90R1-niedriha-V2-2x3.ifc",
             "KIT's NiedriHa demo house (ArchiCAD 9), from opensourceBIM/TestFiles; attribute KIT"),
    DataFile("buildings/AC90R1-Jasmin-Sun-105-2x3.ifc",
             "b7244828bfe2360c683728e2ad446263c548c12e27526f951e87f60f68937750",
             _OPEN_BIM + "AC90R1-Jasmin-Sun-105-2x3.ifc",
             "KIT's Jasmin-Sun demo house (ArchiCAD 9), from opensourceBIM/TestFiles; "
             "attribute KIT"),
    DataFile("buildings/Lantern_Hollow.ifc",
             "b043576f533a1effa1de9d7429054f322771c66c110296f3b80d9e9e802b92e9",
             "https://raw.githubusercontent.com/OpeningDesign/IFCopenHouse_Lantern_Hollow/"
             "e1d3db03c47a8bd0d4ceaf67364e1035b155b273/Models/"
             "IFCopenHouse_Lantern_Hollow_IFC.ifc",
             "OpeningDesign's Lantern Hollow house (Revit 2014, feet), CC BY-SA 4.0; attribute "
             "OpeningDesign"),
    DataFile("buildings/Amersfoort_sports_hall.ifc",
             "e1f1e6f05973f250683c102bfabec62b89230865391e58b1a244ccc9eb25b7e2",
             "https://raw.githubusercontent.com/tudelft3d/ifcgref/"
             "3fb56960e50b0855a8a073da359474a0ae0bff77/uploads/example_project_location.ifc",
             "buildingSMART's sample 'IFC 4.0 / Example project location' (a sports hall in "
             "Amersfoort), CC BY 4.0; attribute buildingSMART and deBIMspecialist"),
)}

EXAMPLES: dict[str, Example] = {e.name: e for e in (
    Example("hall-small", "a 5 x 4 m hall with machines, 14,724 faces, 201 candidates "
            "(shipped)", ("hall-small/hall.obj", "hall-small/candidates.csv",
                          "hall-small/expected.json"), "hall-small/candidates.csv"),
    Example("hall-full", "an 11 x 9 m hall at the paper's scale, 66,562 faces, 1,358 "
            "candidates (shipped)", ("hall-full/hall.obj", "hall-full/candidates.csv",
                                     "hall-full/expected.json"), "hall-full/candidates.csv"),
    Example("ifcopenhouse", "IfcOpenShell's one-room IFC4 house, in millimetres (shipped)",
            ("IfcOpenHouse_IFC4.ifc",)),
    Example("fzk-haus", "KIT's two-storey FZK-Haus, IFC4 from ArchiCAD 20 (2.6 MB)",
            ("AC20-FZK-Haus.ifc",)),
    Example("renga-house", "a house with a lower level, IFC2X3 from Renga, mm (1.5 MB)",
            ("buildings/Renga-House.ifc",)),
    Example("niedriha", "KIT's four-storey NiedriHa house, IFC2X3 from ArchiCAD 9",
            ("buildings/AC90R1-niedriha-V2-2x3.ifc",)),
    Example("jasmin-sun", "KIT's Jasmin-Sun prefab house, IFC2X3 from ArchiCAD 9",
            ("buildings/AC90R1-Jasmin-Sun-105-2x3.ifc",)),
    Example("lantern-hollow", "a real house with its site, IFC2X3 from Revit 2014, feet",
            ("buildings/Lantern_Hollow.ifc",)),
    Example("amersfoort", "a real sports hall with 48 rooms, IFC4 from Revit 2020",
            ("buildings/Amersfoort_sports_hall.ifc",)),
    Example("copyroom-scan", "a real RGB-D scan of a copy room (no semantics, not levelled)",
            ("copyroom_scan_c2000.ply",)),
)}


class DataMissingError(PlannerError):
    """A data file is in none of the places it is looked for."""


def cache_dir() -> Path:
    """Where downloaded files are kept: ``SCANPLAN_DATA_CACHE``, else ``scanplan`` in the
    user's cache folder (``XDG_CACHE_HOME``, else ~/.cache)."""
    given = os.environ.get(CACHE_VARIABLE)
    if given:
        return Path(given)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "scanplan"


def _packaged(path: str) -> Path | None:
    candidate = Path(str(resources.files("planner") / "example_data" / path))
    return candidate if candidate.is_file() else None


def sha256_of(path: Path) -> str:
    """The sha256 of the file at ``path``, hex."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _verified(path: Path, data: DataFile) -> Path:
    actual = sha256_of(path)
    if actual != data.sha256:
        raise DataMissingError(
            f"{path} is not {data.path} (sha256 {actual[:12]}..., expected "
            f"{data.sha256[:12]}...); replace it with the file from {data.url or 'scanplan'}")
    return path


def find(path: str, *, download: bool = True) -> Path:
    """The local file of ``path`` (a key of :data:`FILES`), looked for as the module
    docstring says; :class:`DataMissingError` names what to set when it is nowhere."""
    data = FILES.get(path)
    if data is None:
        raise DataMissingError(f"{path!r} is no example file; known ones: "
                               f"{', '.join(sorted(FILES))}")
    if data.url is None:
        packaged = _packaged(path)
        if packaged is None:
            raise DataMissingError(f"{path} is missing from the installed package; "
                                   "reinstall scanplan")
        return packaged
    mirror = os.environ.get(MIRROR_VARIABLE)
    if mirror and (Path(mirror) / path).is_file():
        return _verified(Path(mirror) / path, data)
    cached = cache_dir() / path
    if cached.is_file():
        return _verified(cached, data)
    if not download:
        raise DataMissingError(_missing(data, mirror))
    try:
        import pooch

        fetched = pooch.retrieve(data.url, known_hash=f"sha256:{data.sha256}",
                                 fname=Path(path).name, path=cached.parent, progressbar=False)
    except Exception as exc:  # no network, a proxy, a moved file: say what to do instead
        reason = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        raise DataMissingError(f"{_missing(data, mirror)}; the download failed: {reason}"
                               ) from exc
    return Path(fetched)


def _missing(data: DataFile, mirror: str | None) -> str:
    where = (f"{MIRROR_VARIABLE}={mirror} has no {data.path}" if mirror
             else f"{MIRROR_VARIABLE} is not set")
    return (f"{data.path} is not here: {where}, and it is not in the cache {cache_dir()}. "
            f"Set {MIRROR_VARIABLE} to an offline copy that holds it at that path, or let "
            f"scanplan download it from {data.url}")


def copy_example(name: str, to: Path) -> list[Path]:
    """Copy the files of example ``name`` into the directory ``to`` (flat: the model, then
    the rest); the copied paths, the model first."""
    example = EXAMPLES.get(name)
    if example is None:
        raise DataMissingError(f"no example {name!r}; known ones: {', '.join(EXAMPLES)}")
    to.mkdir(parents=True, exist_ok=True)
    copied = []
    for path in example.files:
        target = to / Path(path).name
        shutil.copyfile(find(path), target)
        copied.append(target)
    return copied
