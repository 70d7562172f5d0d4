"""``/jobs``: list, status, dismiss/delete, results (OGC API - Processes Part 1)."""

from __future__ import annotations

import json
import shutil
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response, status
from fastapi.responses import FileResponse, JSONResponse

from service.deps import OwnerDep, ServicesDep
from service.job_store import ACTIVE, FAILED, SUCCESSFUL, JobRecord
from service.problems import MEDIA_TYPE, NoSuchJobError, ResultNotReadyError, problem_responses
from service.schemas import JobList, JobResults, JobStatus, Link, OutputRef, StatusInfo
from service.timefmt import iso
from service.worker import results_dir

router = APIRouter(prefix="/jobs", tags=["jobs"],
                   responses=problem_responses(401, 404, 422, 500))

# the output id of the plan inline in the results document (the files are named outputs)
PLAN_OUTPUT = "plan"
RESULTS_REL = "http://www.opengis.net/def/rel/ogc/1.0/results"
MEDIA_TYPES = {
    ".json": "application/json", ".csv": "text/csv; charset=utf-8", ".png": "image/png",
    ".glb": "model/gltf-binary", ".npz": "application/octet-stream",
    ".npy": "application/octet-stream", ".parquet": "application/vnd.apache.parquet",
    # the plan for BIM and CAD programs: IFC (STEP physical file, ISO 10303-21), the DXF
    # drawing (IANA image/vnd.dxf), the print set; a BCF file is a zip archive that only BIM
    # tools open, served as plain bytes so browsers save it under its name
    ".ifc": "application/x-step", ".bcf": "application/octet-stream",
    ".dxf": "image/vnd.dxf", ".pdf": "application/pdf",
}


def media_type(name: str) -> str:
    """The media type served for an output file name."""
    suffix = name[name.rfind("."):].lower() if "." in name else ""
    return MEDIA_TYPES.get(suffix, "application/octet-stream")


def status_info(job: JobRecord) -> StatusInfo:
    """The status document of ``job``."""
    href = f"/jobs/{job.id}"
    links = [Link(href=href, rel="self", type="application/json", title="status"),
             Link(href=f"{href}/viewer", rel="alternate", type="text/html", title="viewer"),
             Link(href=f"/meshes/{job.mesh_id}", rel="related", type="application/json",
                  title="mesh")]
    if job.status in (SUCCESSFUL, FAILED):
        links.append(Link(href=f"{href}/results", rel=RESULTS_REL, type="application/json",
                          title="results"))
    return StatusInfo(
        jobID=job.id, status=job.status,  # type: ignore[arg-type]
        message=job.message, progress=job.progress, created=iso(job.created) or "",
        started=iso(job.started), finished=iso(job.finished), updated=iso(job.updated) or "",
        mesh=job.mesh_id, attempts=job.attempts, timings_s=job.timings, problem=job.problem,
        links=links,
    )


def _job(services: ServicesDep, owner: str, job_id: str) -> JobRecord:
    job = services.jobs.get(job_id, owner)
    if job is None:
        raise NoSuchJobError(f"no job {job_id}; GET /jobs lists yours")
    return job


@router.get("", response_model=JobList)
def list_jobs(
    request: Request, services: ServicesDep, owner: OwnerDep,
    status_: Annotated[list[JobStatus] | None, Query(alias="status",
                                                     description="only jobs in these states")]
    = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 50,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> JobList:
    """Your jobs, newest first, ``limit`` at a time."""
    wanted = list(status_ or [])
    records, total = services.jobs.page(owner, wanted, limit=limit, offset=offset)
    links = [Link(href=str(request.url), rel="self", type="application/json")]
    if offset + limit < total:
        links.append(Link(href=str(request.url.include_query_params(offset=offset + limit)),
                          rel="next", type="application/json"))
    if offset > 0:
        links.append(Link(href=str(request.url.include_query_params(
            offset=max(0, offset - limit))), rel="prev", type="application/json"))
    return JobList(jobs=[status_info(r) for r in records], numberMatched=total, links=links)


@router.get("/{job_id}", response_model=StatusInfo)
def get_job(job_id: str, services: ServicesDep, owner: OwnerDep) -> StatusInfo:
    """Status, progress 0-100, the stage in ``message``, timestamps and links."""
    return status_info(_job(services, owner, job_id))


@router.delete("/{job_id}", response_model=StatusInfo)
def delete_job(job_id: str, services: ServicesDep, owner: OwnerDep) -> StatusInfo:
    """Dismiss a queued or running job (it stops at its next chunk); delete a finished one."""
    job = _job(services, owner, job_id)
    if job.status in ACTIVE and services.jobs.dismiss(job_id):
        return status_info(_job(services, owner, job_id))
    job = _job(services, owner, job_id)  # it may have finished meanwhile
    if services.jobs.delete(job_id):
        shutil.rmtree(results_dir(services.settings, job_id), ignore_errors=True)
    document = status_info(job)
    document.status = "dismissed"
    document.message = "deleted with its results"
    return document


@router.get("/{job_id}/results", response_model=JobResults,
            responses=problem_responses(409))
def get_results(job_id: str, services: ServicesDep, owner: OwnerDep) -> JobResults | Response:
    """The plan inline and every output by href; a failed job's problem."""
    job = _job(services, owner, job_id)
    if job.status == FAILED and job.problem is not None:
        return JSONResponse(job.problem, status_code=int(job.problem.get("status", 500)),
                            media_type=MEDIA_TYPE)
    if job.status != SUCCESSFUL or job.outputs is None:
        raise ResultNotReadyError(f"job {job_id} is {job.status}; results come once it is "
                                  "successful")
    folder = results_dir(services.settings, job_id)
    document: dict[str, dict[str, Any]] = {
        PLAN_OUTPUT: json.loads((folder / "plan.json").read_text(encoding="utf-8"))}
    for name, meta in sorted(job.outputs.items()):
        document[name] = OutputRef(href=f"/jobs/{job_id}/results/{name}",
                                   type=media_type(name), bytes=meta["bytes"],
                                   sha256=meta["sha256"]).model_dump()
    return JobResults(document)


@router.get("/{job_id}/results/{output}", response_class=FileResponse,
            responses={200: {"content": {"application/octet-stream": {}}}, 304: {}})
def get_output(job_id: str, output: str, request: Request, services: ServicesDep,
               owner: OwnerDep) -> Response:
    """One output file, with ETag (its sha256) and Range support.

    Served with its media type: ``plan.json`` application/json, CSVs text/csv, PNGs
    image/png, ``coverage.glb`` model/gltf-binary, ``plan.dxf`` image/vnd.dxf, ``plan.pdf``
    application/pdf, ``plan.ifc`` application/x-step, ``plan.bcf`` (a zip) and ``faces.npz``
    application/octet-stream."""
    job = _job(services, owner, job_id)
    if job.status != SUCCESSFUL or job.outputs is None:
        raise ResultNotReadyError(f"job {job_id} is {job.status}; results come once it is "
                                  "successful")
    meta = job.outputs.get(output)
    path = results_dir(services.settings, job_id) / output
    if meta is None or not path.is_file():
        raise ResultNotReadyError(
            f"job {job_id} has no output {output!r}; it has {', '.join(sorted(job.outputs))}")
    etag = f'"{meta["sha256"]}"'
    if etag in [t.strip() for t in request.headers.get("if-none-match", "").split(",")]:
        return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers={"ETag": etag})
    return FileResponse(path, media_type=media_type(output), headers={"ETag": etag},
                        content_disposition_type="inline", filename=output)
