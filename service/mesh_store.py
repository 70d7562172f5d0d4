"""Meshes as content-addressed files: ``meshes/<sha256>/mesh.<format>`` in the store (the
data directory, or an S3 bucket in scale-out: see :mod:`service.store`).

An upload is streamed to a staging file while its sha256 is computed and its size capped
(the body never lands in the store when it is too large), its format is sniffed from the
bytes, and it is parsed once so that a broken model fails at upload, not in a job. Rows in
the database record the summary and which keys uploaded it (a key sees only its meshes).
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import time
import uuid
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, bindparam, delete, func, insert, select
from sqlalchemy.exc import IntegrityError

from planner.errors import SceneError
from planner.io.readers import file_format, read_scene
from service.database import mesh_owners, meshes
from service.problems import PayloadTooLargeError
from service.store import LocalStore, ObjectStore, mesh_key, mesh_prefix

_CHUNK_BYTES = 1 << 20
# built once: every submission looks its mesh up, and building the statement per call
# (coercions, cache key) cost more than running it
_GET_FOR_OWNER = (select(meshes, mesh_owners.c.filename)
                  .join(mesh_owners, mesh_owners.c.mesh_id == meshes.c.id)
                  .where(meshes.c.id == bindparam("mesh_id"),
                         mesh_owners.c.owner == bindparam("owner")))
_SAFE_NAME = re.compile(r"[^A-Za-z0-9._-]+")


@dataclass(frozen=True)
class StagedUpload:
    """An upload written to a staging directory, not yet in the store."""

    path: Path
    sha256: str
    size_bytes: int

    def renamed(self, filename: str | None) -> StagedUpload:
        """The same upload under the user's (sanitised) file name, for messages."""
        target = self.path.with_name(safe_filename(filename))
        self.path.rename(target)
        return StagedUpload(target, self.sha256, self.size_bytes)

    def discard(self) -> None:
        shutil.rmtree(self.path.parent, ignore_errors=True)


@dataclass(frozen=True)
class MeshRecord:
    """A stored mesh as one owner sees it."""

    id: str
    format: str
    size_bytes: int
    summary: dict[str, Any]
    created: float
    filename: str | None


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while chunk := handle.read(_CHUNK_BYTES):
            digest.update(chunk)
    return digest.hexdigest()


def safe_filename(name: str | None) -> str:
    """A plain file name (no directories) for messages and downloads."""
    base = Path(name or "").name
    cleaned = _SAFE_NAME.sub("_", base).strip("._")
    return cleaned[:120] or "upload"


class MeshStore:
    """Mesh files in ``store`` (default: under ``root``) and their rows in the database.

    ``root`` is ``<data dir>/meshes``; uploads are staged beside it, in ``<data dir>/tmp``,
    whatever the store.
    """

    def __init__(self, root: Path, engine: Engine, max_upload_bytes: int,
                 store: ObjectStore | None = None) -> None:
        self.root = root
        self.engine = engine
        self.max_upload_bytes = max_upload_bytes
        self.staging = root.parent / "tmp"
        self.store: ObjectStore = store or LocalStore(root.parent)

    def key(self, mesh_id: str) -> str | None:
        """The store key of ``mesh_id`` (None when no such mesh is stored)."""
        row = self._row(mesh_id)
        return None if row is None else mesh_key(mesh_id, row.format)

    def fetch(self, mesh_id: str, scratch: Path) -> Path | None:
        """The stored model as a local file (downloaded into the new directory ``scratch``
        from a remote store: the caller removes it), its bytes checked against the id
        (their sha256); None when absent, and then ``scratch`` is gone.

        Raises SceneError when the stored bytes are not the ones uploaded.
        """
        key = self.key(mesh_id)
        try:
            path = None if key is None else self.store.fetch(key, scratch)
            if path is not None and _sha256(path) != mesh_id:
                raise SceneError(f"the stored bytes of mesh {mesh_id} do not match its sha256 "
                                 f"(in {self.store!r}); upload the model again")
        except FileNotFoundError:
            path = None
        except BaseException:
            shutil.rmtree(scratch, ignore_errors=True)
            raise
        if path is None:
            shutil.rmtree(scratch, ignore_errors=True)
        return path

    async def stage(self, chunks: AsyncIterator[bytes]) -> StagedUpload:
        """Stream ``chunks`` into a staging file, hashing; 413 past ``max_upload_bytes``."""
        folder = self.staging / f"upload-{uuid.uuid4().hex}"
        folder.mkdir(parents=True)
        path = folder / "upload"
        digest = hashlib.sha256()
        size = 0
        try:
            with path.open("wb") as handle:
                async for chunk in chunks:
                    size += len(chunk)
                    if size > self.max_upload_bytes:
                        raise PayloadTooLargeError(self.too_large_message())
                    digest.update(chunk)
                    handle.write(chunk)
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            raise
        return StagedUpload(path, digest.hexdigest(), size)

    def too_large_message(self) -> str:
        return (f"the upload is larger than the limit of {self.max_upload_bytes} bytes; "
                "simplify the model or raise SCANPLAN_MAX_UPLOAD_BYTES")

    def ingest(self, staged: StagedUpload, owner: str) -> tuple[MeshRecord, bool]:
        """Sniff, parse once and store ``staged`` (blocking: call it in a thread).

        Returns the record and whether it is new to ``owner``.
        Raises SceneError (422) or UnsupportedFormatError (415) for a bad model.
        """
        try:
            fmt = file_format(staged.path)
            if self._row(staged.sha256) is None:
                summary = read_scene(staged.path, max_edge_m=None).summary()
                self._store(staged, fmt, summary)
        finally:
            staged.discard()
        created = self._add_owner(staged.sha256, owner, staged.path.name)
        record = self.get(staged.sha256, owner)
        assert record is not None
        return record, created

    def _store(self, staged: StagedUpload, fmt: str, summary: dict[str, Any]) -> None:
        # the key is the sha256: any concurrent upload writes the same bytes (harmless race)
        self.store.put_file(mesh_key(staged.sha256, fmt), staged.path)
        try:
            with self.engine.begin() as conn:
                conn.execute(insert(meshes).values(
                    id=staged.sha256, format=fmt, size_bytes=staged.size_bytes,
                    summary=json.dumps(summary, sort_keys=True), created=time.time()))
        except IntegrityError:
            pass  # a concurrent upload of the same bytes stored it first

    def _add_owner(self, mesh_id: str, owner: str, filename: str) -> bool:
        try:
            with self.engine.begin() as conn:
                conn.execute(insert(mesh_owners).values(
                    mesh_id=mesh_id, owner=owner, filename=filename, created=time.time()))
        except IntegrityError:
            return False
        return True

    def _row(self, mesh_id: str) -> Any:
        with self.engine.connect() as conn:
            return conn.execute(select(meshes).where(meshes.c.id == mesh_id)).first()

    def get(self, mesh_id: str, owner: str) -> MeshRecord | None:
        """The mesh if ``owner`` uploaded it."""
        with self.engine.connect() as conn:
            row = conn.execute(_GET_FOR_OWNER, {"mesh_id": mesh_id, "owner": owner}).first()
        if row is None:
            return None
        data = row._mapping
        return MeshRecord(id=data["id"], format=data["format"], size_bytes=data["size_bytes"],
                          summary=json.loads(data["summary"]), created=data["created"],
                          filename=data["filename"])

    def remove(self, mesh_id: str, owner: str, *, files_in_use: bool) -> None:
        """Forget ``owner``'s copy; delete the files once nobody holds or uses them."""
        with self.engine.begin() as conn:
            conn.execute(delete(mesh_owners).where(mesh_owners.c.mesh_id == mesh_id,
                                                   mesh_owners.c.owner == owner))
            holders = conn.execute(select(func.count()).select_from(mesh_owners)
                                   .where(mesh_owners.c.mesh_id == mesh_id)).scalar_one()
            if holders or files_in_use:
                return
            conn.execute(delete(meshes).where(meshes.c.id == mesh_id))
        self.store.delete_prefix(mesh_prefix(mesh_id))

    def ping(self) -> None:
        """Raise when the data directory (the staging of uploads) is not writable."""
        self.staging.mkdir(parents=True, exist_ok=True)
        probe = self.staging / f".probe-{uuid.uuid4().hex}"
        probe.write_bytes(b"")
        probe.unlink()
