"""``/processes``: the one process, ``scan-plan``, and its execution (OGC API - Processes)."""

from __future__ import annotations

import hashlib
import json
from typing import Annotated, Any

from fastapi import APIRouter, Header, Path, Request, Response, status
from starlette.concurrency import run_in_threadpool

from planner.io.readers import unit_warning
from planner.outputs.report import OUTPUTS
from planner.parameters import PlanSpec
from planner.scanners import presets
from service import guards, tenants
from service.callbacks import check_subscriber
from service.deps import OwnerDep, ServicesDep
from service.problems import (
    IdempotencyKeyReusedError,
    JobTooLargeError,
    NoSuchProcessError,
    NotFoundError,
    problem_responses,
)
from service.routes.callbacks import callback_router
from service.routes.jobs import PLAN_OUTPUT, job_links, media_type, status_info
from service.schemas import ExecuteRequest, PlanParameters, StatusInfo

router = APIRouter(prefix="/processes", tags=["processes"],
                   responses=problem_responses(401, 404, 422, 500))

PROCESS_ID = "scan-plan"
_SUMMARY: dict[str, Any] = {
    "id": PROCESS_ID,
    "title": "Plan laser scanner stations",
    "description": "Fewest scanner stations on a mesh for the required coverage and point "
                   "density (greedy, weighted greedy or optimal MILP).",
    "version": "1.0.0",
    "jobControlOptions": ["async-execute", "dismiss"],
    "outputTransmission": ["reference"],
    "links": [{"href": f"/processes/{PROCESS_ID}", "rel": "self", "type": "application/json"},
              {"href": f"/processes/{PROCESS_ID}/execution",
               "rel": "http://www.opengis.net/def/rel/ogc/1.0/execute",
               "type": "application/json"}],
}


# OpenAPI links from a new job to what a client does next (Schemathesis follows them)
_JOB_LINKS = job_links("$response.body#/jobID")


# past the key's cap of jobs queued or running (service.tenants)
_BUSY = {**problem_responses(429)[429], "headers": {"Retry-After": {
    "description": "seconds to wait before submitting again", "schema": {"type": "integer"}}}}


# the schema lists the one process; another id is still a 404 no-such-process (OGC), not a 422
ProcessIdPath = Annotated[str, Path(json_schema_extra={"enum": [PROCESS_ID]})]


class MeshNotFoundError(NotFoundError):
    """The execution names a mesh this key did not upload."""


def _description() -> dict[str, Any]:
    return {
        **_SUMMARY,
        "inputs": {
            "mesh": {"title": "mesh id", "description": "the id POST /meshes returned",
                     "schema": {"type": "string", "pattern": "^[0-9a-f]{64}$"},
                     "minOccurs": 1, "maxOccurs": 1},
            "parameters": {"title": "plan parameters",
                           "description": "names, units and defaults as in the planner",
                           "schema": PlanParameters.model_json_schema(),
                           "minOccurs": 0, "maxOccurs": 1},
        },
        "scanners": [preset.to_dict() for preset in presets().values()],
        "outputs": {
            PLAN_OUTPUT: {"title": "the plan inline", "description": "the content of plan.json",
                          "schema": {"type": "object"}},
            **{name: {"title": name,
                      "schema": {"type": "string", "contentMediaType": media_type(name)}}
               for name in OUTPUTS},
        },
    }


@router.get("")
def list_processes() -> dict[str, Any]:
    """The processes this service offers (one)."""
    return {"processes": [_SUMMARY],
            "links": [{"href": "/processes", "rel": "self", "type": "application/json"}]}


@router.get("/{process_id}")
def describe_process(process_id: ProcessIdPath) -> dict[str, Any]:
    """Inputs (JSON Schema with the real defaults) and outputs of the process."""
    _check_process(process_id)
    return _description()


def _check_process(process_id: str) -> None:
    if process_id != PROCESS_ID:
        raise NoSuchProcessError(f"no process {process_id!r}; the one process is {PROCESS_ID}")


@router.post("/{process_id}/execution", status_code=status.HTTP_201_CREATED,
             response_model=StatusInfo,
             responses={201: {"links": _JOB_LINKS},
                        200: {"model": StatusInfo, "description": "Idempotency-Key replay",
                              "links": _JOB_LINKS},
                        **problem_responses(400, 413), 429: _BUSY},
             callbacks=callback_router.routes)
async def execute(
    process_id: ProcessIdPath, body: ExecuteRequest, request: Request, response: Response,
    services: ServicesDep, owner: OwnerDep,
    idempotency_key: Annotated[str | None, Header(max_length=255)] = None,
    prefer: Annotated[str | None, Header(
        description="OGC: respond-async (every execution is asynchronous)")] = None,
) -> StatusInfo:
    """Queue a plan of ``inputs.mesh`` with ``inputs.parameters``; 201 and Location.

    Execution is always asynchronous (``jobControlOptions``: async-execute); a
    ``Prefer: respond-async`` is answered with ``Preference-Applied: respond-async``.
    """
    _check_process(process_id)
    if prefer is not None and "respond-async" in prefer:
        response.headers["Preference-Applied"] = "respond-async"
    parameters = body.inputs.parameters.model_dump(exclude_unset=True)
    spec = PlanSpec.from_mapping(parameters)  # ranges and consistency: 422 naming it
    subscriber = body.subscriber.model_dump(exclude_none=True) if body.subscriber else None
    return await run_in_threadpool(_submit, services, owner, body.inputs.mesh, parameters,
                                   spec, idempotency_key, response, subscriber,
                                   str(request.base_url))


def _submit(services: ServicesDep, owner: str, mesh_id: str, parameters: dict[str, Any],
            spec: PlanSpec, idempotency_key: str | None, response: Response,
            subscriber: dict[str, str] | None = None, base_url: str = "") -> StatusInfo:
    mesh = services.meshes.get(mesh_id, owner)
    if mesh is None:
        raise MeshNotFoundError(f"inputs.mesh: no mesh {mesh_id}; upload the model with "
                                "POST /meshes and use the id it returns")
    # resolves the hosts: here, in the thread pool, not on the event loop
    callback_uris = None if subscriber is None else check_subscriber(services.settings,
                                                                     subscriber)
    # the mesh's bounds are in file units: scaled by this job's unit_scale they say whether
    # the model is plausibly in metres, before a worker spends any time on it
    low, high = mesh.summary["bounds"]
    extent_m = max(h - lo for lo, h in zip(low, high, strict=True)) * spec.unit_scale
    warning = unit_warning(extent_m, spec.unit_scale)
    try:
        guards.check(mesh.summary, spec, services.settings)  # 422 naming the parameter
    except JobTooLargeError as exc:
        if warning is None:
            raise
        # a model in millimetres is a thousand times too large: say so, not just "too large"
        raise JobTooLargeError("unit_scale", f"{warning}. Refused as it is: {exc}") from exc
    hashed: dict[str, Any] = {"mesh": mesh_id, "parameters": parameters}
    if subscriber is not None:
        hashed["subscriber"] = subscriber
    request_hash = hashlib.sha256(json.dumps(hashed, sort_keys=True).encode()).hexdigest()
    job, created = tenants.create_admitted(  # 429 past the key's cap
        services.jobs, services.settings, owner, mesh_id, parameters,
        idempotency_key=idempotency_key, request_hash=request_hash)
    if created:
        if callback_uris is not None:
            services.callbacks.subscribe(job.id, base_url, callback_uris)
        services.queue.enqueue(job.id)
    elif job.request_hash != request_hash:
        raise IdempotencyKeyReusedError(
            f"Idempotency-Key {idempotency_key!r} was used for job {job.id} with another "
            "body; use a new key for a new request")
    else:
        response.status_code = status.HTTP_200_OK
    response.headers["Location"] = f"/jobs/{job.id}"
    info = status_info(job)
    if warning:
        info.warnings = [warning]
    return info


