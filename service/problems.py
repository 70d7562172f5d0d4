"""RFC 9457 problem details: the one table from exception class to HTTP status.

Planner errors pass their message on unchanged as ``detail`` (it names the parameter, the
value and the fix). Service errors are the few exceptions below. A failed job stores the
problem document of its error, and its results endpoint returns it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from planner.errors import (
    CancelledError,
    NoCandidatesError,
    NothingVisibleError,
    ParameterError,
    PlannerError,
    SceneError,
    UnsupportedFormatError,
)

MEDIA_TYPE = "application/problem+json"
_OGC = "http://www.opengis.net/def/exceptions/ogcapi-processes-1/1.0/"


class ServiceError(Exception):
    """Root of the service's own errors; the message becomes the problem ``detail``."""


class NotFoundError(ServiceError):
    """The resource does not exist, or belongs to another key."""


class NoSuchJobError(NotFoundError):
    """No job with this id (OGC ``no-such-job``)."""


class NoSuchProcessError(NotFoundError):
    """No process with this id (OGC ``no-such-process``)."""


class ResultNotReadyError(NotFoundError):
    """The job has not finished successfully yet (OGC ``result-not-ready``)."""


class ConflictError(ServiceError):
    """The request conflicts with the resource's state (a mesh still in use)."""


class IdempotencyKeyReusedError(ServiceError):
    """The Idempotency-Key was used before with a different request body."""


class PayloadTooLargeError(ServiceError):
    """The upload is larger than ``max_upload_bytes``."""


class BadRequestError(ServiceError):
    """The request itself is malformed (not JSON, no file part, ...)."""


class UnauthorizedError(ServiceError):
    """No or an unknown bearer key."""


class NotReadyError(ServiceError):
    """A dependency (database, queue, data directory) is unreachable."""


@dataclass(frozen=True)
class ProblemKind:
    """How one exception class looks on the wire."""

    status: int
    type: str
    title: str


# The one table. Order does not matter: the most specific class in the MRO wins.
PROBLEMS: dict[type[BaseException], ProblemKind] = {
    UnsupportedFormatError: ProblemKind(415, "urn:scanplan:problem:unsupported-format",
                                        "Unsupported model format"),
    SceneError: ProblemKind(422, "urn:scanplan:problem:invalid-scene",
                            "The model cannot be used"),
    ParameterError: ProblemKind(422, "urn:scanplan:problem:invalid-parameter",
                                "Invalid parameter"),
    NoCandidatesError: ProblemKind(422, "urn:scanplan:problem:no-candidates",
                                   "No scanner position to consider"),
    NothingVisibleError: ProblemKind(422, "urn:scanplan:problem:nothing-visible",
                                     "No face qualifies from any candidate"),
    CancelledError: ProblemKind(409, "urn:scanplan:problem:cancelled", "The job was dismissed"),
    PlannerError: ProblemKind(422, "urn:scanplan:problem:planning-failed", "Planning failed"),
    NoSuchJobError: ProblemKind(404, _OGC + "no-such-job", "No such job"),
    NoSuchProcessError: ProblemKind(404, _OGC + "no-such-process", "No such process"),
    ResultNotReadyError: ProblemKind(404, _OGC + "result-not-ready", "Result not ready"),
    NotFoundError: ProblemKind(404, "urn:scanplan:problem:not-found", "Not found"),
    ConflictError: ProblemKind(409, "urn:scanplan:problem:conflict", "Conflict"),
    IdempotencyKeyReusedError: ProblemKind(422, "urn:scanplan:problem:idempotency-key-reused",
                                           "Idempotency-Key reused with another request"),
    PayloadTooLargeError: ProblemKind(413, "urn:scanplan:problem:too-large",
                                      "Upload too large"),
    BadRequestError: ProblemKind(400, "urn:scanplan:problem:bad-request", "Bad request"),
    UnauthorizedError: ProblemKind(401, "urn:scanplan:problem:unauthorized",
                                   "Missing or unknown API key"),
    NotReadyError: ProblemKind(503, "urn:scanplan:problem:not-ready", "Not ready"),
}
INTERNAL = ProblemKind(500, "urn:scanplan:problem:internal", "Internal error")


def kind_of(exc: BaseException) -> ProblemKind:
    """The table entry of the most specific class of ``exc`` (500 for the unexpected)."""
    for cls in type(exc).__mro__:
        if cls in PROBLEMS:
            return PROBLEMS[cls]
    return INTERNAL


def problem_for(exc: BaseException, *, instance: str | None = None) -> dict[str, Any]:
    """The problem document of ``exc``; an error that names a parameter adds ``parameter``."""
    kind = kind_of(exc)
    detail = str(exc) if kind is not INTERNAL else "an unexpected error; see the server log"
    document: dict[str, Any] = {
        "type": kind.type, "title": kind.title, "status": kind.status, "detail": detail,
    }
    parameter = getattr(exc, "parameter", None)  # ParameterError, JobTooLargeError
    if isinstance(parameter, str):
        document["parameter"] = parameter
    if instance is not None:
        document["instance"] = instance
    return document


# JSON Schema of a problem document (RFC 9457), a component of the OpenAPI document
PROBLEM_SCHEMA: dict[str, Any] = {
    "title": "Problem",
    "description": "RFC 9457 problem details",
    "type": "object",
    "required": ["type", "title", "status"],
    "properties": {
        "type": {"type": "string", "description": "URI of the problem type"},
        "title": {"type": "string"},
        "status": {"type": "integer", "minimum": 400, "maximum": 599},
        "detail": {"type": "string", "description": "what went wrong and how to fix it"},
        "instance": {"type": "string"},
        "parameter": {"type": "string", "description": "the parameter to change"},
    },
}
PROBLEM_REF = "#/components/schemas/Problem"
_WHEN = {
    400: "malformed request (body not JSON, broken multipart)",
    401: "missing or unknown API key (only when keys are configured)",
    404: "no such resource for this key",
    409: "conflicts with the resource's state",
    413: "request body over the configured cap",
    415: "not a model format the planner reads",
    422: "invalid input, named in `parameter`",
    429: "this API key has as many jobs queued or running as it may; retry after "
         "`Retry-After` seconds",
    500: "unexpected error",
    503: "a dependency is unreachable",
}


def problem_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` entries: each status answered with a problem document."""
    return {status: {"description": _WHEN.get(status, "problem"),
                     "content": {MEDIA_TYPE: {"schema": {"$ref": PROBLEM_REF}}}}
            for status in statuses}


def http_problem(status: int, title: str, detail: str, **extra: Any) -> dict[str, Any]:
    """A problem for a plain HTTP error (unknown route, wrong method, ...)."""
    return {"type": "about:blank", "title": title, "status": status, "detail": detail, **extra}


class WorkerLostError(ServiceError):
    """The job's worker stopped heartbeating on its last allowed attempt."""


PROBLEMS[WorkerLostError] = ProblemKind(500, "urn:scanplan:problem:worker-lost", "Worker lost")


class OutOfMemoryError(ServiceError):
    """The job's planning process went past the worker's memory limit."""


class JobTooLargeError(ServiceError):
    """The estimated work of a plan exceeds a configured cap; names the parameter."""

    def __init__(self, parameter: str, message: str) -> None:
        super().__init__(message)
        self.parameter = parameter


PROBLEMS[OutOfMemoryError] = ProblemKind(422, "urn:scanplan:problem:out-of-memory",
                                         "Out of memory")
PROBLEMS[JobTooLargeError] = ProblemKind(422, "urn:scanplan:problem:job-too-large",
                                         "The plan would be too large for this service")


class PlanKilledError(ServiceError):
    """The planning process was ended by a signal from outside on the job's last attempt."""


PROBLEMS[PlanKilledError] = ProblemKind(500, "urn:scanplan:problem:plan-killed",
                                        "The planning process was killed")


class TooManyJobsError(ServiceError):
    """The API key has as many jobs queued or running as it may (service.tenants)."""

    def __init__(self, message: str, *, retry_after_s: int) -> None:
        super().__init__(message)
        self.headers = {"Retry-After": str(retry_after_s)}


PROBLEMS[TooManyJobsError] = ProblemKind(429, "urn:scanplan:problem:too-many-jobs",
                                         "Too many jobs queued or running for this key")
