"""HTML pages for people who open the service in a browser: the viewer (``/`` is in
:mod:`service.routes.landing`, which serves the page to plan to browsers).

The pages are static files (``service/static``); their scripts read the job id from the
address and talk to the JSON API (``GET /jobs``, ``GET /jobs/{id}``,
``GET /jobs/{id}/results/{output}``), so nothing is templated here. three.js is vendored
under ``static/vendor/three`` (from the npm registry, with its licence) and the pages load
it by relative address, so they work on a site server without internet and behind a path
prefix. The pages are left out of the OpenAPI document: they are not part of the API.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import HTMLResponse

STATIC = Path(__file__).resolve().parent.parent / "static"

router = APIRouter(tags=["pages"], include_in_schema=False)


def page(name: str) -> HTMLResponse:
    """A static page, never cached."""
    # no-cache: a new release of the page must not meet an old script in the browser
    return HTMLResponse((STATIC / name).read_text(encoding="utf-8"),
                        headers={"Cache-Control": "no-cache"})


@router.get("/jobs/{job_id}/viewer", response_class=HTMLResponse)
def viewer_page(job_id: str) -> HTMLResponse:
    """The 3D viewer of one job (polls ``GET /jobs/{job_id}`` until it has finished)."""
    return page("viewer.html")
