"""``/jobs/{id}/callbacks``: what was POSTed to a job's subscriber, and the documents posted.

See :mod:`service.callbacks` for how deliveries are queued, signed and retried.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Header
from pydantic import BaseModel, Field

from service.callbacks import URI_FIELDS
from service.deps import OwnerDep, ServicesDep
from service.job_store import SUCCESSFUL, JobRecord
from service.problems import problem_responses
from service.routes.jobs import media_type, status_info, visible_job
from service.schemas import Link, StatusInfo

router = APIRouter(prefix="/jobs", tags=["jobs"], responses=problem_responses(401, 404, 422,
                                                                              500))


def callback_document(job: JobRecord, base_url: str) -> dict[str, Any]:
    """The body of a callback: ``job``'s status document, links absolute under
    ``base_url``; a successful job's links name every output (rel ``enclosure``)."""
    info = status_info(job)
    if job.status == SUCCESSFUL and job.outputs:
        info.links += [Link(href=f"/jobs/{job.id}/results/{name}", rel="enclosure",
                            type=media_type(name), title=name) for name in sorted(job.outputs)]
    for link in info.links:
        if link.href.startswith("/"):
            link.href = base_url + link.href
    return info.model_dump(mode="json", exclude_none=True)


class CallbackAttempt(BaseModel):
    """One POST of a delivery."""

    at: str
    status_code: int | None = Field(description="the receiver's HTTP status; null: none")
    error: str | None = Field(description="why it did not count as delivered; null: 2xx")
    address: str | None = Field(description="the IP address connected to")


class CallbackDelivery(BaseModel):
    """One callback: its event, where it goes, and how it went."""

    id: str = Field(description="X-Scanplan-Delivery of every attempt")
    event: Literal["inProgress", "success", "failed"]
    uri: str
    state: Literal["pending", "sending", "delivered", "failed", "superseded"] = Field(
        description="failed: no 2xx after SCANPLAN_CALLBACK_MAX_ATTEMPTS; superseded: a "
                    "newer callback of the job replaced this inProgress one")
    attempts: int
    created: str | None
    finished: str | None
    next_attempt: str | None = Field(description="when the next try is due (pending only)")
    last_status_code: int | None
    last_error: str | None
    history: list[CallbackAttempt] = Field(description="the last 20 attempts")


class CallbackRecord(BaseModel):
    """A job's subscriber and its deliveries, oldest first."""

    subscriber: dict[str, str] | None = Field(
        description="the URIs of the execute request; null: the job has no subscriber")
    deliveries: list[CallbackDelivery]


@router.get("/{job_id}/callbacks", response_model=CallbackRecord)
def get_callbacks(job_id: str, services: ServicesDep, owner: OwnerDep) -> CallbackRecord:
    """The job's callbacks: each POST to its subscriber, attempts, status codes, errors."""
    visible_job(services, owner, job_id)  # 404 for an unknown or dismissed job
    subscription = services.callbacks.subscription(job_id)
    subscriber = None if subscription is None else {
        URI_FIELDS[event]: uri for event, uri in subscription.uris.items() if uri is not None}
    deliveries = [CallbackDelivery.model_validate(d)
                  for d in services.callbacks.deliveries_of(job_id)]
    return CallbackRecord(subscriber=subscriber, deliveries=deliveries)


# the callbacks as OpenAPI describes them on the execute operation (never routes of the app)
callback_router = APIRouter()
_SIGNATURE_DOC = ("sha256=<hex HMAC-SHA256 of the raw body keyed with "
                  "SCANPLAN_CALLBACK_SECRET>; check it before parsing")


def _described(event: str, expression: str, summary: str) -> None:
    def receive(
        body: StatusInfo,
        x_scanplan_signature: Annotated[str, Header(description=_SIGNATURE_DOC)],
        x_scanplan_event: Annotated[Literal["inProgress", "success", "failed"],
                                    Header(description="which URI of the subscriber")],
        x_scanplan_delivery: Annotated[str, Header(
            description="the same on every retry of one callback")],
        x_scanplan_job: Annotated[str, Header(description="the job's id")],
    ) -> None:
        """Documentation only: what the receiver gets."""

    callback_router.add_api_route(
        expression, receive, methods=["POST"], name=f"{event}_callback", summary=summary,
        status_code=204, description="Any 2xx counts as delivered.",
        responses={"default": {"description": "any other answer, a redirect included (never "
                                              "followed): tried again with backoff, up to "
                                              "SCANPLAN_CALLBACK_MAX_ATTEMPTS times"}})


_described("success", "{$request.body#/subscriber/successUri}",
           "the status document of the successful job, with a link to every output")
_described("in_progress", "{$request.body#/subscriber/inProgressUri}",
           "the status document when the status or stage changed")
_described("failed", "{$request.body#/subscriber/failedUri}",
           "the status document of the failed job, with its problem")
