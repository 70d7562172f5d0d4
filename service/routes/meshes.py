"""``/meshes``: upload (raw or multipart), describe, download, delete."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response, status
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from service.deps import OwnerDep, ServicesDep
from service.mesh_store import MeshRecord
from service.problems import (
    ConflictError,
    NotFoundError,
    PayloadTooLargeError,
    problem_responses,
)
from service.schemas import Link, MeshInfo
from service.store import mesh_key
from service.timefmt import iso
from service.upload import FILE_FIELD, MultipartFile, multipart_boundary

router = APIRouter(prefix="/meshes", tags=["meshes"],
                   responses=problem_responses(401, 404, 422, 500))

_UPLOAD_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "description": "the model's bytes (OBJ, PLY, STL, OFF, GLB/glTF, IFC; the format "
                       "is recognised from the bytes), raw or as the multipart field 'file'",
        "content": {
            "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
            "multipart/form-data": {"schema": {
                "type": "object", "required": [FILE_FIELD],
                "properties": {FILE_FIELD: {"type": "string", "format": "binary"}},
            }},
        },
    }
}


# OpenAPI links (https://spec.openapis.org/oas/v3.1.0#link-object): what a client does with
# a mesh it uploaded or looked up (stateful clients and Schemathesis follow them)
_BY_ID = {"mesh_id": "$response.body#/id"}
_MESH_LINKS: dict[str, dict[str, Any]] = {
    "get_mesh": {"operationId": "get_mesh", "parameters": _BY_ID,
                 "description": "faces, bounds and groups of the mesh"},
    "get_mesh_content": {"operationId": "get_mesh_content", "parameters": _BY_ID,
                         "description": "the uploaded bytes"},
    "delete_mesh": {"operationId": "delete_mesh", "parameters": _BY_ID,
                    "description": "forget the mesh"},
    "execute": {"operationId": "execute", "parameters": {"process_id": "scan-plan"},
                "requestBody": {"inputs": {"mesh": "$response.body#/id"}},
                "description": "plan on the mesh"},
}
_LOOKUP_LINKS = {name: link for name, link in _MESH_LINKS.items() if name != "get_mesh"}


def mesh_info(record: MeshRecord) -> MeshInfo:
    """The wire form of a stored mesh."""
    s = record.summary
    return MeshInfo(
        id=record.id, format=record.format, bytes=record.size_bytes, filename=record.filename,
        faces=s["faces"], vertices=s["vertices"], total_area_m2=s["total_area_m2"],
        bounds=s["bounds"], groups=s["groups"], warnings=list(s.get("warnings", [])),
        created=iso(record.created) or "",
        links=[Link(href=f"/meshes/{record.id}", rel="self", type="application/json"),
               Link(href=f"/meshes/{record.id}/content", rel="enclosure",
                    type="application/octet-stream")],
    )


def _not_found(mesh_id: str) -> NotFoundError:
    return NotFoundError(f"no mesh {mesh_id}; upload the model with POST /meshes")


@router.post("", status_code=status.HTTP_201_CREATED, response_model=MeshInfo,
             openapi_extra=_UPLOAD_BODY,
             responses={201: {"links": _MESH_LINKS},
                        200: {"model": MeshInfo, "description": "already uploaded",
                              "links": _MESH_LINKS},
                        **problem_responses(400, 413, 415)})
async def upload_mesh(
    request: Request, response: Response, services: ServicesDep, owner: OwnerDep,
    filename: Annotated[str | None, Query(description="the model's file name")] = None,
) -> MeshInfo:
    """Store a model under its sha256; 201 when new, 200 when these bytes are known."""
    store = services.meshes
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > store.max_upload_bytes:
        raise PayloadTooLargeError(store.too_large_message())
    boundary = multipart_boundary(request.headers.get("content-type", ""))
    chunks: AsyncIterator[bytes]
    if boundary is None:
        chunks = request.stream()
        staged = await store.stage(chunks)
    else:
        form = MultipartFile(request, boundary)
        staged = await store.stage(form.chunks())
        filename = filename or form.filename
    staged = staged.renamed(filename)
    record, created = await run_in_threadpool(store.ingest, staged, owner)
    response.status_code = status.HTTP_201_CREATED if created else status.HTTP_200_OK
    response.headers["Location"] = f"/meshes/{record.id}"
    response.headers["ETag"] = f'"{record.id}"'
    return mesh_info(record)


@router.get("/{mesh_id}", response_model=MeshInfo, responses={200: {"links": _LOOKUP_LINKS}})
def get_mesh(mesh_id: str, response: Response, services: ServicesDep,
             owner: OwnerDep) -> MeshInfo:
    """Faces, bounds, groups, format and size of an uploaded mesh."""
    record = services.meshes.get(mesh_id, owner)
    if record is None:
        raise _not_found(mesh_id)
    response.headers["ETag"] = f'"{record.id}"'
    return mesh_info(record)


@router.get("/{mesh_id}/content", response_class=FileResponse,
            responses={200: {"content": {"application/octet-stream": {}}}})
def get_mesh_content(mesh_id: str, request: Request, services: ServicesDep,
                     owner: OwnerDep) -> Response:
    """The uploaded bytes, unchanged."""
    record = services.meshes.get(mesh_id, owner)
    if record is None:
        raise _not_found(mesh_id)
    answer = services.store.response(
        mesh_key(record.id, record.format), media_type="application/octet-stream",
        etag=f'"{record.id}"', filename=record.filename or f"mesh.{record.format}",
        disposition="attachment", request_headers=dict(request.headers))
    if answer is None:
        raise _not_found(mesh_id)
    return answer


@router.delete("/{mesh_id}", status_code=status.HTTP_204_NO_CONTENT,
               responses=problem_responses(409))
def delete_mesh(mesh_id: str, services: ServicesDep, owner: OwnerDep) -> Response:
    """Forget the mesh; 409 while an unfinished job plans on it."""
    if services.meshes.get(mesh_id, owner) is None:
        raise _not_found(mesh_id)
    active = services.jobs.active_jobs_using(mesh_id)
    if active:
        raise ConflictError(f"{active} unfinished job(s) use mesh {mesh_id}; wait for them "
                            "or DELETE them first")
    services.meshes.remove(mesh_id, owner, files_in_use=False)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
