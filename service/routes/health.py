"""``/healthz`` (the process answers) and ``/readyz`` (database, queue, data dir, store)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from planner.version import __version__
from service.deps import ServicesDep
from service.problems import NotReadyError, problem_responses

router = APIRouter(tags=["health"], responses=problem_responses(500))


# async: answered on the event loop, without a thread-pool hop
@router.get("/healthz")
async def healthz() -> dict[str, str]:
    """Liveness: the API process answers, with scanplan's version."""
    return {"status": "ok", "version": __version__}


@router.get("/readyz", responses=problem_responses(503))
def readyz(services: ServicesDep) -> dict[str, Any]:
    """Readiness: the job table, the queue, the data directory and the store all answer."""
    checks = {
        "database": services.jobs.ping,
        "queue": services.queue.ping,
        "data_dir": services.meshes.ping,
        "store": services.store.ping,
    }
    failed = []
    for name, check in checks.items():
        try:
            check()
        except Exception as exc:
            failed.append(f"{name}: {type(exc).__name__}: {exc}")
    if failed:
        raise NotReadyError("; ".join(failed))
    return {"status": "ready", "checks": {name: "ok" for name in checks}}
