"""``/jobs``: list, status, dismiss/delete, results (OGC API - Processes Part 1)."""

from __future__ import annotations

import json
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response, status
from fastapi.responses import FileResponse, JSONResponse

from planner.outputs.report import OUTPUTS
from service.deps import OwnerDep, ServicesDep
from service.job_store import ACTIVE, DISMISSED, FAILED, STATUSES, SUCCESSFUL, JobRecord
from service.problems import MEDIA_TYPE, NoSuchJobError, ResultNotReadyError, problem_responses
from service.schemas import (
    AttemptInfo,
    JobList,
    JobResults,
    JobStatus,
    Link,
    OutputRef,
    StatusInfo,
)
from service.store import result_key, results_prefix
from service.timefmt import iso

router = APIRouter(prefix="/jobs", tags=["jobs"],
                   responses=problem_responses(401, 404, 422, 500))

# the output id of the plan inline in the results document (the files are named outputs)
PLAN_OUTPUT = "plan"
# the largest offset of GET /jobs: far past any job table, and within every database's
# 64-bit integers (a larger one was a 500 from the database)
MAX_OFFSET = 1_000_000_000
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


# OpenAPI links (https://spec.openapis.org/oas/v3.1.0#link-object): from a response naming a
# job to what a client does next with it. Stateful clients and Schemathesis follow them; the
# parameters are runtime expressions (where the response or the request holds the job's id).
def job_links(job_id: str) -> dict[str, dict[str, Any]]:
    """Links to the job's status, results, callbacks and dismissal; ``job_id`` is the
    runtime expression of its id."""
    by_id = {"job_id": job_id}
    return {
        "get_job": {"operationId": "get_job", "parameters": by_id,
                    "description": "the job's status and progress"},
        "get_results": {"operationId": "get_results", "parameters": by_id,
                        "description": "the results document once the job has finished"},
        "get_callbacks": {"operationId": "get_callbacks", "parameters": by_id,
                          "description": "what was POSTed to the job's subscriber"},
        "delete_job": {"operationId": "delete_job", "parameters": by_id,
                       "description": "dismiss the job (cancel it, or delete its results)"},
    }


def output_links(job_id: str) -> dict[str, dict[str, Any]]:
    """A link to each output file a plan may have (the results document lists those of one
    job); ``job_id`` is the runtime expression of the job's id."""
    return {f"get_output_{name}": {
        "operationId": "get_output", "parameters": {"job_id": job_id, "output": name},
        "description": f"the output {name} once the job has succeeded"} for name in OUTPUTS}


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
    if job.status == DISMISSED:
        links = []  # gone: nothing to link to
    if job.status in (SUCCESSFUL, FAILED):
        links.append(Link(href=f"{href}/results", rel=RESULTS_REL, type="application/json",
                          title="results"))
    return StatusInfo(
        jobID=job.id, status=job.status,  # type: ignore[arg-type]
        message=job.message, progress=job.progress, created=iso(job.created) or "",
        started=iso(job.started), finished=iso(job.finished), updated=iso(job.updated) or "",
        mesh=job.mesh_id, attempts=job.attempts, timings_s=job.timings, problem=job.problem,
        attempt_log=[AttemptInfo(**{**entry, "started": iso(entry.get("started")),
                                    "finished": iso(entry.get("finished"))})
                     for entry in job.attempt_log or []],
        links=links,
    )


def visible_job(services: ServicesDep, owner: str, job_id: str) -> JobRecord:
    """The caller's job; a dismissed one is gone (OGC dismiss), as one that never was.

    Every ``/jobs/{job_id}/...`` route finds its job here, so all of them answer the same
    404 once the job is dismissed or deleted."""
    job = services.jobs.get(job_id, owner)
    if job is None:
        raise NoSuchJobError(f"no job {job_id}; GET /jobs lists yours")
    if job.status == DISMISSED:
        raise NoSuchJobError(f"job {job_id} was dismissed (DELETE); it and its results are "
                             "gone; GET /jobs lists yours")
    return job


@router.get("", response_model=JobList)
def list_jobs(
    request: Request, services: ServicesDep, owner: OwnerDep,
    status_: Annotated[list[JobStatus] | None, Query(alias="status", max_length=16,
                                                     description="only jobs in these states")]
    = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 50,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
) -> JobList:
    """Your jobs, newest first, ``limit`` at a time."""
    # dismissed jobs are gone: never listed, whatever the filter says
    wanted = [s for s in (status_ or STATUSES) if s != DISMISSED]
    records, total = (services.jobs.page(owner, wanted, limit=limit, offset=offset)
                      if wanted else ([], 0))
    links = [Link(href=str(request.url), rel="self", type="application/json")]
    if offset + limit < total:
        links.append(Link(href=str(request.url.include_query_params(offset=offset + limit)),
                          rel="next", type="application/json"))
    if offset > 0:
        links.append(Link(href=str(request.url.include_query_params(
            offset=max(0, offset - limit))), rel="prev", type="application/json"))
    return JobList(jobs=[status_info(r) for r in records], numberMatched=total, links=links)


@router.get("/{job_id}", response_model=StatusInfo, responses={200: {"links": {
    **{name: link for name, link in job_links("$request.path.job_id").items()
       if name != "get_job"},
    **output_links("$request.path.job_id"),
    "get_mesh": {"operationId": "get_mesh", "parameters": {"mesh_id": "$response.body#/mesh"},
                 "description": "the mesh the job plans on"}}}})
def get_job(job_id: str, services: ServicesDep, owner: OwnerDep) -> StatusInfo:
    """Status, progress 0-100, the stage in ``message``, timestamps and links."""
    return status_info(visible_job(services, owner, job_id))


@router.delete("/{job_id}", response_model=StatusInfo)
def delete_job(job_id: str, services: ServicesDep, owner: OwnerDep) -> StatusInfo:
    """Dismiss the job (OGC dismiss): a queued or running one is cancelled (a running plan
    stops within a second or two), a finished one is deleted with its results. Either way
    the answer is its last status document, ``dismissed``, and from then on every
    ``/jobs/{id}`` request answers 404."""
    job = visible_job(services, owner, job_id)
    if job.status in ACTIVE and services.jobs.dismiss(job_id):
        dismissed = services.jobs.get(job_id, owner)
        assert dismissed is not None  # the row stays: the worker learns of the dismissal
        return status_info(dismissed)
    job = visible_job(services, owner, job_id)  # it may have finished meanwhile
    if services.jobs.delete(job_id):
        services.store.delete_prefix(results_prefix(job_id))
    document = status_info(job)
    document.status, document.links = "dismissed", []
    document.message = "dismissed: deleted with its results"
    return document


def failed_job_problem(stored: dict[str, Any]) -> dict[str, Any]:
    """The answer of ``GET /jobs/{id}/results`` for a failed job: its stored problem.

    A problem of the input (415, 422) is answered with its own status. A failure of the
    service while it planned (a worker lost, a planning process killed, an unexpected error:
    the stored status is 5xx) is no error of this request, which asked for the results of a
    job that exists and has failed: it is answered 409 (the job's state conflicts with
    results), with the stored type, title and detail, and the stored status as
    ``job_status``. No request is answered 5xx for a job's failure."""
    status_code = stored.get("status")
    if isinstance(status_code, int) and 400 <= status_code < 500:
        return stored
    return {**stored, "status": status.HTTP_409_CONFLICT, "job_status": status_code}


@router.get("/{job_id}/results", response_model=JobResults,
            responses={200: {"links": output_links("$request.path.job_id")},
                       **problem_responses(409, 422)})
def get_results(job_id: str, services: ServicesDep, owner: OwnerDep) -> JobResults | Response:
    """The plan inline and every output by href; a failed job's problem
    (:func:`failed_job_problem`: 4xx, never 5xx)."""
    job = visible_job(services, owner, job_id)
    if job.status == FAILED and job.problem is not None:
        problem = failed_job_problem(job.problem)
        return JSONResponse(problem, status_code=problem["status"], media_type=MEDIA_TYPE)
    if job.status != SUCCESSFUL or job.outputs is None:
        raise ResultNotReadyError(f"job {job_id} is {job.status}; results come once it is "
                                  "successful")
    try:
        plan = services.store.read_bytes(result_key(job_id, "plan.json"))
    except FileNotFoundError:  # deleted (DELETE /jobs/{id}) while this request ran
        raise NoSuchJobError(f"job {job_id} was dismissed (DELETE); it and its results are "
                             "gone; GET /jobs lists yours") from None
    document: dict[str, dict[str, Any]] = {PLAN_OUTPUT: json.loads(plan.decode("utf-8"))}
    for name, meta in sorted(job.outputs.items()):
        document[name] = OutputRef(href=f"/jobs/{job_id}/results/{name}",
                                   type=media_type(name), bytes=meta["bytes"],
                                   sha256=meta["sha256"]).model_dump()
    return JobResults(document)


# every media type an output is served with (parameters such as charset aside), for OpenAPI
OUTPUT_MEDIA_TYPES = sorted({media.split(";")[0] for media in MEDIA_TYPES.values()})


@router.get("/{job_id}/results/{output}", response_class=FileResponse,
            responses={200: {"content": {media: {} for media in OUTPUT_MEDIA_TYPES}}, 304: {}})
def get_output(job_id: str, output: str, request: Request, services: ServicesDep,
               owner: OwnerDep) -> Response:
    """One output file, with ETag (its sha256) and Range support.

    Served with its media type: ``plan.json`` application/json, CSVs text/csv, PNGs
    image/png, ``coverage.glb`` model/gltf-binary, ``plan.dxf`` image/vnd.dxf, ``plan.pdf``
    application/pdf, ``plan.ifc`` application/x-step, ``plan.bcf`` (a zip) and ``faces.npz``
    application/octet-stream."""
    job = visible_job(services, owner, job_id)
    if job.status != SUCCESSFUL or job.outputs is None:
        raise ResultNotReadyError(f"job {job_id} is {job.status}; results come once it is "
                                  "successful")
    meta = job.outputs.get(output)
    if meta is None:
        raise _no_output(job, output)
    etag = f'"{meta["sha256"]}"'
    if etag in [t.strip() for t in request.headers.get("if-none-match", "").split(",")]:
        return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers={"ETag": etag})
    answer = services.store.response(
        result_key(job_id, output), media_type=media_type(output), etag=etag, filename=output,
        disposition="inline", request_headers=dict(request.headers))
    if answer is None:
        raise _no_output(job, output)
    return answer


def _no_output(job: JobRecord, output: str) -> ResultNotReadyError:
    return ResultNotReadyError(f"job {job.id} has no output {output!r}; it has "
                               f"{', '.join(sorted(job.outputs or {}))}")
