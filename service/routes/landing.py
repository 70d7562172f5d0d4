"""``/`` and ``/conformance``: the entry points of OGC API - Processes - Part 1: Core.

``/`` answers JSON (the landing page with the links the standard requires) to API clients
(``Accept: application/json``, ``?f=json``, or no HTML in ``Accept``) and the page to plan to
browsers (``Accept: text/html``, ``?f=html``). ``/conformance`` lists only the conformance
classes this service implements (OGC 18-062r2, section 7.4 and Annex A):

- core, ogc-process-description, json, oas30: the process list and description, async
  execution, status and results as JSON, this OpenAPI 3 document;
- job-list: ``GET /jobs``; dismiss: ``DELETE /jobs/{jobId}``;
- callback: ``subscriber`` in the execute request (:mod:`service.callbacks`), claimed when
  the operator set ``SCANPLAN_CALLBACK_SECRET`` (without it a subscriber is refused).

Not claimed: html (only the landing page has an HTML form).
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query, Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel

from service.deps import ServicesDep
from service.problems import problem_responses
from service.routes.pages import page
from service.schemas import Link

router = APIRouter(tags=["ogc"], responses=problem_responses(422, 500))

_CONF = "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/"
CONFORMANCE = [_CONF + name for name in (
    "core", "ogc-process-description", "json", "oas30", "job-list", "dismiss")]
CALLBACK = _CONF + "callback"
_REL = "http://www.opengis.net/def/rel/ogc/1.0/"


class LandingPage(BaseModel):
    """The OGC landing page (``landingPage.yaml``): title, description, links."""

    title: str
    description: str
    links: list[Link]


class ConfClasses(BaseModel):
    """The OGC conformance declaration (``confClasses.yaml``)."""

    conformsTo: list[str]  # noqa: N815 - OGC's name


def _landing(base: str) -> LandingPage:
    """The landing page with absolute links under ``base`` (clients resolve them as given)."""
    return LandingPage(
        title="scanplan",
        description="Plan terrestrial laser scanner stations on a 3D model (OGC API - "
                    "Processes): upload a model with POST /meshes, then execute scan-plan.",
        links=[
            Link(href=f"{base}/?f=json", rel="self", type="application/json",
                 title="this document"),
            Link(href=f"{base}/?f=html", rel="alternate", type="text/html",
                 title="the page to plan"),
            Link(href=f"{base}/openapi.json", rel="service-desc",
                 type="application/vnd.oai.openapi+json;version=3.0", title="the API"),
            Link(href=f"{base}/docs", rel="service-doc", type="text/html",
                 title="the API documentation"),
            Link(href=f"{base}/conformance", rel=_REL + "conformance", type="application/json",
                 title="conformance classes"),
            Link(href=f"{base}/processes", rel=_REL + "processes", type="application/json",
                 title="the processes"),
            Link(href=f"{base}/jobs", rel=_REL + "job-list", type="application/json",
                 title="the jobs"),
        ])


def _wants_html(request: Request, f: str | None) -> bool:
    if f is not None:
        return f == "html"
    return "text/html" in request.headers.get("accept", "")


@router.get("/", response_model=LandingPage,
            responses={200: {"content": {"text/html": {"schema": {"type": "string"}}},
                             "description": "JSON for API clients, HTML for browsers"}})
def landing_page(
    request: Request,
    f: Annotated[Literal["json", "html"] | None,
                 Query(description="json or html; default from the Accept header")] = None,
) -> Response:
    """The landing page: links to the API, its conformance, processes and jobs."""
    if _wants_html(request, f):
        response: Response = page("index.html")
    else:
        base = str(request.base_url).rstrip("/")
        response = JSONResponse(_landing(base).model_dump(exclude_none=True))
    response.headers["Vary"] = "Accept"
    return response


@router.get("/conformance", response_model=ConfClasses)
def conformance(services: ServicesDep) -> ConfClasses:
    """The conformance classes this service implements."""
    callback = [CALLBACK] if services.settings.callback_secret is not None else []
    return ConfClasses(conformsTo=CONFORMANCE + callback)

