"""``create_app(settings)``: routers, problem handlers and the lifespan that opens the stores.

Nothing is created at import time: the database, the queue and the reaper start in the
lifespan of the app that :func:`create_app` returns.
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from http import HTTPStatus
from pathlib import Path
from typing import Any

from fastapi import Depends, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import compile_path
from starlette.types import ASGIApp, Receive, Scope, Send

from planner.errors import ParameterError, PlannerError
from planner.parameters import (
    GROUP_RANGES,
    RANGES,
    SCANNER_RANGES,
    SETTING_RANGES,
    check_range,
)
from planner.version import __version__
from service.auth import KeyRing
from service.callbacks import CallbackDispatcher, CallbackStore
from service.config import Settings
from service.database import make_engine
from service.deps import Services
from service.job_store import JobStore
from service.mesh_store import MeshStore
from service.problems import (
    MEDIA_TYPE,
    PROBLEM_SCHEMA,
    ServiceError,
    UnauthorizedError,
    http_problem,
    problem_for,
)
from service.queue import HueyQueue, JobQueue, make_huey
from service.routes import callbacks, health, jobs, landing, meshes, processes
from service.routes.callbacks import callback_document
from service.schemas import OBJECT_TAG, PRESET_TAG
from service.store import open_store
from service.worker import Reaper

log = logging.getLogger("scanplan.service")
DESCRIPTION = """Plan terrestrial laser scanner stations on a 3D model.

Upload a model with `POST /meshes`, start a plan with `POST /processes/scan-plan/execution`,
poll `GET /jobs/{id}` and fetch `GET /jobs/{id}/results`. Errors are RFC 9457
`application/problem+json`. With API keys configured, send `Authorization: Bearer <key>`.
"""


def create_app(settings: Settings | None = None, *, queue: JobQueue | None = None,
               reaper: bool = True) -> FastAPI:
    """The service for ``settings`` (default: from the environment).

    Parameters
    ----------
    queue : where jobs go (default: huey as the settings say); tests pass an inline runner
    reaper : run the reaper (stale jobs re-queued) and re-enqueue accepted jobs at startup
    """
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        services = open_services(settings, queue)
        app.state.services = services
        keeper = Reaper(services.jobs, services.queue, settings) if reaper else None
        if keeper is not None:
            requeued = keeper.requeue_accepted()
            if requeued:
                log.info("re-enqueued %d accepted job(s) from before the start", requeued)
            keeper.start()
        dispatcher = CallbackDispatcher(services.callbacks, settings, callback_document)
        dispatcher.start()
        try:
            yield
        finally:
            dispatcher.stop()
            if keeper is not None:
                keeper.stop()
            services.jobs.engine.dispose()

    # operation ids are the handlers' names: what a generated client calls its functions
    app = FastAPI(title="scanplan", version=__version__, description=DESCRIPTION,
                  lifespan=lifespan, generate_unique_id_function=lambda route: route.name,
                  dependencies=[Depends(_single_query_values)])
    _add_problem_component(app)
    app.add_middleware(RequestSizeLimit, max_bytes=settings.max_request_bytes)
    _add_problem_handlers(app)
    for module in (landing, meshes, processes, jobs, callbacks, health):
        app.include_router(module.router)
    _add_pages(app)
    return app


async def _single_query_values(request: Request) -> None:
    """422 for a query parameter given twice that takes one value (FastAPI keeps the last)."""
    route = request.scope.get("route")
    repeated = [key for key in request.query_params
                if len(request.query_params.getlist(key)) > 1]
    if not repeated or route is None:
        return
    operation = request.app.openapi()["paths"].get(getattr(route, "path_format", ""), {}).get(
        request.method.lower(), {})
    lists = {p["name"] for p in operation.get("parameters", [])
             if p.get("in") == "query" and _is_array(p.get("schema", {}))}
    errors = [{"type": "repeated", "loc": ("query", key),
               "msg": "given more than once; it takes one value", "input": key}
              for key in repeated if key not in lists]
    if errors:
        raise RequestValidationError(errors)


def _is_array(schema: dict[str, Any]) -> bool:
    return schema.get("type") == "array" or any(_is_array(s) for s in schema.get("anyOf", []))


class RequestSizeLimit:
    """413 for a request body over ``max_bytes`` except uploads (``/meshes`` has its cap).

    A pure ASGI middleware: it looks at the ``Content-Length`` header only, so it adds no
    latency; 1e6 candidates (some 30 MB of JSON) are refused before anything parses them.
    """

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and not scope["path"].startswith("/meshes"):
            declared = dict(scope["headers"]).get(b"content-length", b"")
            if declared.isdigit() and int(declared) > self.max_bytes:
                detail = (f"the request body has {int(declared)} bytes, more than "
                          f"{self.max_bytes} (SCANPLAN_MAX_REQUEST_BYTES); for many "
                          "candidates use a larger grid_spacing_m or an area_of_interest")
                response = _problem_response(http_problem(
                    413, "Request body too large", detail, instance=scope["path"]))
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _add_problem_component(app: FastAPI) -> None:
    """Put the problem document's schema into the OpenAPI components (routes refer to it)."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        document = generate()
        document.setdefault("components", {}).setdefault("schemas", {})["Problem"] = \
            PROBLEM_SCHEMA
        return document

    app.openapi = openapi  # type: ignore[method-assign]


def open_services(settings: Settings, queue: JobQueue | None = None) -> Services:
    """Open the database, the stores and the queue of ``settings``."""
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    engine = make_engine(settings.job_db_url)
    return Services(
        settings=settings,
        jobs=JobStore(engine),
        meshes=MeshStore(settings.data_dir / "meshes", engine, settings.max_upload_bytes,
                         open_store(settings)),
        queue=queue or HueyQueue(make_huey(settings)),
        keys=KeyRing.from_settings(settings.api_keys),
        callbacks=CallbackStore(engine),
    )


def _problem_response(document: dict[str, Any], headers: dict[str, str] | None = None
                      ) -> JSONResponse:
    return JSONResponse(document, status_code=document["status"], media_type=MEDIA_TYPE,
                        headers=headers)


def _add_problem_handlers(app: FastAPI) -> None:
    async def domain_error(request: Request, exc: Exception) -> JSONResponse:
        headers = ({"WWW-Authenticate": "Bearer"} if isinstance(exc, UnauthorizedError)
                   else getattr(exc, "headers", None))  # Retry-After of a 429
        return _problem_response(problem_for(exc, instance=request.url.path), headers)

    async def validation_error(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        errors = exc.errors()
        details = [_describe_validation(e) for e in errors]
        document = http_problem(422, "Invalid request", "; ".join(details),
                                instance=request.url.path)
        document["type"] = "urn:scanplan:problem:invalid-request"
        if errors:
            parameter = _parameter_of(errors[0])
            if parameter:
                document["parameter"] = parameter
        return _problem_response(document)

    async def http_error(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, StarletteHTTPException)
        title = HTTPStatus(exc.status_code).phrase
        detail = str(exc.detail)
        headers = dict(exc.headers or {})
        if exc.status_code == 404:
            detail = f"no resource at {request.url.path}; see /docs for the API"
        if exc.status_code == 405:
            # Starlette names the methods of the first route that matched the path only
            allowed = _allowed_methods(request.app, request.url.path)
            if allowed:  # else a page outside the API: Starlette's own Allow stands
                headers["Allow"] = ", ".join(allowed)
            detail = f"{request.method} is not allowed on {request.url.path}; use " \
                     f"{', '.join(allowed)}"
        return _problem_response(http_problem(exc.status_code, title, detail,
                                              instance=request.url.path), headers)

    async def unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unexpected error on %s", request.url.path, exc_info=exc)
        return _problem_response(problem_for(exc, instance=request.url.path))

    app.add_exception_handler(ServiceError, domain_error)
    app.add_exception_handler(PlannerError, domain_error)
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(Exception, unexpected)


_RANGE_ERRORS = {"greater_than", "greater_than_equal", "less_than", "less_than_equal"}
# parts of a validation error's location that name no field: the body, a union's form
_NOT_NAMES = {"body", PRESET_TAG, OBJECT_TAG}


def _allowed_methods(app: Any, path: str) -> list[str]:
    """Every method the OpenAPI document declares at ``path`` (GET brings HEAD along)."""
    methods: set[str] = set()
    for template, operations in app.openapi()["paths"].items():
        if compile_path(template)[0].match(path):
            methods |= {method.upper() for method in operations}
    if "GET" in methods:
        methods.add("HEAD")
    return sorted(methods)


def _describe_validation(error: Any) -> str:
    range_message = _range_message(error)
    if range_message is not None:
        return range_message
    where = ".".join(str(p) for p in error.get("loc", ()) if p not in _NOT_NAMES)
    message = error.get("msg", "invalid")
    if "input" in error and error.get("type") != "missing":
        value = repr(error["input"])
        message += f" (got {value[:60]})"
    return f"{where}: {message}" if where else message


def _range_message(error: Any) -> str | None:
    """The planner's own words for a parameter out of its range (the fix included)."""
    parameter = _parameter_of(error)
    if error.get("type") not in _RANGE_ERRORS or parameter is None:
        return None
    name = parameter.rsplit(".", 1)[-1]
    table = (GROUP_RANGES if parameter.startswith("group_requirements.")
             else SETTING_RANGES if parameter.startswith("scanner.settings.")
             else SCANNER_RANGES if parameter.startswith("scanner.") else RANGES)
    bounds = table.get(name)
    if bounds is None or not isinstance(error.get("input"), int | float):
        return None
    try:
        check_range(parameter, float(error["input"]), bounds)
    except ParameterError as exc:
        return str(exc)
    return None


def _parameter_of(error: Any) -> str | None:
    loc = [str(p) for p in error.get("loc", ()) if p not in _NOT_NAMES]
    if "parameters" in loc:
        rest = loc[loc.index("parameters") + 1:]
        return ".".join(rest) or None
    return None


def _add_pages(app: FastAPI) -> None:
    """The HTML pages (viewer, job list) when their module is installed."""
    if importlib.util.find_spec("service.routes.pages") is None:
        return
    pages = importlib.import_module("service.routes.pages")
    app.include_router(pages.router)
    static = Path(__file__).parent / "static"
    if static.is_dir() and not any(getattr(r, "path", "") == "/static" for r in app.routes):
        app.mount("/static", StaticFiles(directory=static), name="static")
