"""FastAPI dependencies: the services of the running app and the caller's owner id."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Header, Request

from service.auth import KeyRing
from service.callbacks import CallbackStore
from service.config import Settings
from service.job_store import JobStore
from service.mesh_store import MeshStore
from service.queue import JobQueue
from service.store import ObjectStore


@dataclass
class Services:
    """What the handlers use; built in the app's lifespan."""

    settings: Settings
    jobs: JobStore
    meshes: MeshStore
    queue: JobQueue
    keys: KeyRing
    callbacks: CallbackStore

    @property
    def store(self) -> ObjectStore:
        """Where meshes and results live (the data directory, or S3 in scale-out)."""
        return self.meshes.store


# both dependencies are async although they never wait: FastAPI runs a plain ``def``
# dependency in the thread pool, a hop per dependency per request (GIL hand-overs included)
async def get_services(request: Request) -> Services:
    services: Services = request.app.state.services
    return services


async def get_owner(
    services: Annotated[Services, Depends(get_services)],
    authorization: Annotated[str | None, Header(include_in_schema=False)] = None,
) -> str:
    return services.keys.owner(authorization)


ServicesDep = Annotated[Services, Depends(get_services)]
OwnerDep = Annotated[str, Depends(get_owner)]
