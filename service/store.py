"""Where meshes and results live: the data directory (embedded) or an S3 bucket (scale-out).

The API, the workers and the job table agree on keys, not on a disk. Keys are
``/``-separated paths below the store's root:

- ``meshes/<sha256>/mesh.<format>``: an uploaded model, content-addressed (a key is only ever
  written with the same bytes, so concurrent uploads and retries cannot corrupt it);
- ``jobs/<job id>/<output name>``: a successful job's files (``plan.json``, ``faces.npz``...).

Two stores behind one small interface, :class:`ObjectStore`:

- :class:`LocalStore` (the default): the data directory itself, exactly the files and the
  atomic renames the service always used; needs no client library, no server.
- :class:`S3Store` (``SCANPLAN_STORE_URL=s3://bucket/prefix``): any S3-compatible store
  through boto3, configured the standard way (``AWS_ENDPOINT_URL``, ``AWS_ACCESS_KEY_ID``,
  ``AWS_SECRET_ACCESS_KEY``, ``AWS_DEFAULT_REGION``, or an instance role). Each process then
  keeps only its own scratch in its ``--data-dir``: the API stages uploads there, a worker
  downloads the job's mesh and writes the outputs there, then uploads them.

Nothing stored is lost or corrupted on a failure: an S3 PUT shows the whole object or none;
a job's outputs are uploaded under a temporary prefix and only then copied to their final
keys (a worker that dies in between leaves the job unfinished, so nobody reads the keys,
and the re-run writes the same bytes: plans are deterministic).

Downloads are streamed through the API (see :meth:`S3Store.response`) rather than redirected
to a presigned URL: the bucket stays private (in compose, MinIO is not even reachable from
outside), the API key keeps guarding every byte, and clients get the same media types, ETag
(the sha256) and Range answers from either store. The cost is the API's bandwidth.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Protocol
from urllib.parse import quote

from starlette.responses import FileResponse, Response, StreamingResponse

from service.config import Settings, parse_store_url

if TYPE_CHECKING:  # boto3 is imported only by the scale-out store
    from mypy_boto3_s3 import S3Client
    from mypy_boto3_s3.type_defs import ObjectIdentifierTypeDef

_CHUNK_BYTES = 1 << 20
# one range as S3's GetObject takes it; several ranges are answered with the whole object
# (RFC 9110 section 14.2: a server may ignore Range)
_SINGLE_RANGE = re.compile(r"bytes=(\d+-\d*|-\d+)")


def mesh_key(mesh_id: str, fmt: str) -> str:
    """The key of an uploaded model (its sha256 and the format sniffed from its bytes)."""
    return f"meshes/{mesh_id}/mesh.{fmt}"


def mesh_prefix(mesh_id: str) -> str:
    return f"meshes/{mesh_id}/"


def result_key(job_id: str, name: str) -> str:
    """The key of one output file of a successful job."""
    return f"jobs/{job_id}/{name}"


def results_prefix(job_id: str) -> str:
    return f"jobs/{job_id}/"


class ObjectStore(Protocol):
    """What the API and the workers need from the place the files live."""

    def put_file(self, key: str, path: Path) -> None:
        """Store the file at ``path`` under ``key``, whole or not at all; ``path`` may be
        moved (do not use it afterwards)."""

    def publish_folder(self, folder: Path, prefix: str) -> None:
        """Store every file of ``folder`` under ``prefix`` (replacing what was there) only
        once all of them are stored; ``folder`` may be moved."""

    def fetch(self, key: str, scratch: Path) -> Path:
        """The object as a local file: in place when the store is a directory, else
        downloaded into the directory ``scratch``. Raises FileNotFoundError."""

    def read_bytes(self, key: str) -> bytes:
        """The whole object (a small one). Raises FileNotFoundError."""

    def response(self, key: str, *, media_type: str, etag: str, filename: str,
                 disposition: str, request_headers: dict[str, str]) -> Response | None:
        """The object as an HTTP response with ``ETag`` and Range support; None if absent."""

    def delete_prefix(self, prefix: str) -> None:
        """Delete every object whose key starts with ``prefix`` (end it with ``/``)."""

    def ping(self) -> None:
        """Raise when the store cannot be read and written."""


def content_disposition(disposition: str, filename: str) -> str:
    """``inline; filename="x"`` (RFC 6266, as Starlette's FileResponse writes it)."""
    quoted = quote(filename)
    if quoted != filename:
        return f"{disposition}; filename*=utf-8''{quoted}"
    return f'{disposition}; filename="{filename}"'


class LocalStore:
    """The store as files below ``root`` (the data directory): the embedded default."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def __repr__(self) -> str:
        return f"LocalStore({str(self.root)!r})"

    def _path(self, key: str) -> Path:
        return self.root / key

    def put_file(self, key: str, path: Path) -> None:
        target = self._path(key)
        target.parent.mkdir(parents=True, exist_ok=True)
        path.chmod(0o644)
        path.replace(target)  # atomic on one file system; the same bytes on a race

    def publish_folder(self, folder: Path, prefix: str) -> None:
        final = self._path(prefix)
        final.parent.mkdir(parents=True, exist_ok=True)
        if final.exists():  # left by an earlier attempt that could not finish
            shutil.rmtree(final)
        folder.rename(final)

    def fetch(self, key: str, scratch: Path) -> Path:
        path = self._path(key)
        if not path.is_file():
            raise FileNotFoundError(key)
        return path

    def read_bytes(self, key: str) -> bytes:
        return self._path(key).read_bytes()

    def response(self, key: str, *, media_type: str, etag: str, filename: str,
                 disposition: str, request_headers: dict[str, str]) -> Response | None:
        path = self._path(key)
        if not path.is_file():
            return None
        # Starlette serves ranges itself, with sendfile where it can
        return FileResponse(path, media_type=media_type, headers={"ETag": etag},
                            content_disposition_type=disposition, filename=filename)

    def delete_prefix(self, prefix: str) -> None:
        shutil.rmtree(self._path(prefix), ignore_errors=True)

    def ping(self) -> None:
        self.root.mkdir(parents=True, exist_ok=True)
        probe = self.root / f".probe-{uuid.uuid4().hex}"
        probe.write_bytes(b"")
        probe.unlink()


class S3Store:
    """The store as objects in ``bucket`` below ``prefix`` of an S3-compatible service."""

    def __init__(self, client: S3Client, bucket: str, prefix: str = "") -> None:
        self.client = client
        self.bucket = bucket
        self.prefix = prefix.strip("/") + "/" if prefix.strip("/") else ""

    def __repr__(self) -> str:
        return f"S3Store('s3://{self.bucket}/{self.prefix}')"

    def _key(self, key: str) -> str:
        return self.prefix + key

    def put_file(self, key: str, path: Path) -> None:
        # upload_file switches to a multipart upload for large files; S3 shows the object
        # only once the upload completed
        self.client.upload_file(str(path), self.bucket, self._key(key))

    def publish_folder(self, folder: Path, prefix: str) -> None:
        staging = f"{prefix}.tmp-{uuid.uuid4().hex}/"
        names = sorted(path.name for path in folder.iterdir())
        try:
            for name in names:
                self.put_file(staging + name, folder / name)
            for name in names:  # a server-side copy: no bytes through this process
                self.client.copy({"Bucket": self.bucket, "Key": self._key(staging + name)},
                                 self.bucket, self._key(prefix + name))
        finally:
            self.delete_prefix(staging)

    def fetch(self, key: str, scratch: Path) -> Path:
        scratch.mkdir(parents=True, exist_ok=True)
        target = scratch / key.rsplit("/", 1)[-1]
        partial = target.with_name(f".{target.name}.part")
        try:
            self.client.download_file(self.bucket, self._key(key), str(partial))
        except Exception as exc:
            partial.unlink(missing_ok=True)
            if _is_missing(exc):
                raise FileNotFoundError(key) from exc
            raise
        partial.replace(target)
        return target

    def read_bytes(self, key: str) -> bytes:
        try:
            answer = self.client.get_object(Bucket=self.bucket, Key=self._key(key))
        except Exception as exc:
            if _is_missing(exc):
                raise FileNotFoundError(key) from exc
            raise
        with contextlib.closing(answer["Body"]) as body:
            return body.read()

    def response(self, key: str, *, media_type: str, etag: str, filename: str,
                 disposition: str, request_headers: dict[str, str]) -> Response | None:
        """The object streamed from the store; one range is forwarded to the store."""
        headers = {"ETag": etag, "Accept-Ranges": "bytes",
                   "Content-Disposition": content_disposition(disposition, filename)}
        wanted = request_headers.get("range", "").replace(" ", "")
        if_range = request_headers.get("if-range")
        if not _SINGLE_RANGE.fullmatch(wanted) or (if_range is not None and if_range != etag):
            wanted = ""
        try:
            if wanted:
                answer = self.client.get_object(Bucket=self.bucket, Key=self._key(key),
                                                Range=wanted)
            else:
                answer = self.client.get_object(Bucket=self.bucket, Key=self._key(key))
        except Exception as exc:
            if _is_missing(exc):
                return None
            if _error_code(exc) == "InvalidRange":
                size = self.client.head_object(Bucket=self.bucket,
                                               Key=self._key(key))["ContentLength"]
                return Response(status_code=416, headers={"Content-Range": f"bytes */{size}"})
            raise
        headers["Content-Length"] = str(answer["ContentLength"])
        status = 200
        if wanted and answer.get("ContentRange"):
            headers["Content-Range"] = answer["ContentRange"]
            status = 206
        return StreamingResponse(_chunks(answer["Body"]), status_code=status,
                                 media_type=media_type, headers=headers)

    def delete_prefix(self, prefix: str) -> None:
        pages = self.client.get_paginator("list_objects_v2").paginate(
            Bucket=self.bucket, Prefix=self._key(prefix))
        for page in pages:  # at most 1,000 keys a page: DeleteObjects' own limit
            keys: list[ObjectIdentifierTypeDef] = [
                {"Key": item["Key"]} for item in page.get("Contents", [])]
            if keys:
                self.client.delete_objects(Bucket=self.bucket,
                                           Delete={"Objects": keys, "Quiet": True})

    def ping(self) -> None:
        self.client.head_bucket(Bucket=self.bucket)


def _chunks(body: object) -> Iterator[bytes]:
    """The body of a GetObject, a MiB at a time (Starlette iterates it in a thread)."""
    try:
        yield from body.iter_chunks(_CHUNK_BYTES)  # type: ignore[attr-defined]
    finally:
        body.close()  # type: ignore[attr-defined]


def _error_code(exc: Exception) -> str:
    """The S3 error code of a botocore ClientError ('' for anything else)."""
    answer = getattr(exc, "response", None)
    if isinstance(answer, dict):
        return str(answer.get("Error", {}).get("Code", ""))
    return ""


def _is_missing(exc: Exception) -> bool:
    return _error_code(exc) in ("NoSuchKey", "404", "NotFound")


def open_store(settings: Settings) -> ObjectStore:
    """The store the settings name: the data directory, or S3 for an ``s3://`` URL.

    ``store_addressing_style`` None: path-style requests (``endpoint/bucket/key``) when
    ``AWS_ENDPOINT_URL`` names a server of one's own (MinIO and the like answer those
    without a DNS name per bucket), boto3's choice against AWS itself.
    """
    if not settings.store_url:
        return LocalStore(settings.data_dir)
    bucket, prefix = parse_store_url(settings.store_url)
    import boto3
    from botocore.config import Config

    addressing_style = settings.store_addressing_style
    if addressing_style is None:
        custom = os.environ.get("AWS_ENDPOINT_URL_S3") or os.environ.get("AWS_ENDPOINT_URL")
        addressing_style = "path" if custom else "auto"
    config = Config(s3={"addressing_style": addressing_style},
                    retries={"mode": "standard", "max_attempts": 5})
    # endpoint, credentials and region come from the standard AWS_* variables (or a role)
    client = boto3.session.Session().client("s3", config=config)
    return S3Store(client, bucket, prefix)
