"""Settings: the one place that reads the environment (prefix ``SCANPLAN_``).

Every knob of ``scanplan serve`` and ``scanplan worker`` is a field here; the command line
overrides the environment, which overrides the defaults.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

LOOPBACK_HOSTS = ("127.0.0.1", "::1", "localhost")


def _cores() -> int:
    return os.cpu_count() or 1


class Settings(BaseSettings):
    """Service configuration; ``SCANPLAN_<FIELD>`` sets each field."""

    model_config = SettingsConfigDict(env_prefix="SCANPLAN_", extra="ignore")

    host: str = Field(default="127.0.0.1", description="address the API binds to")
    port: int = Field(default=8000, ge=0, le=65535, description="TCP port of the API")
    data_dir: Path = Field(default=Path("data"), description="meshes, results, SQLite files")
    workers: int = Field(default_factory=_cores, ge=0,
                         description="worker processes (default: the number of cores)")
    database_url: str | None = Field(
        default=None, description="SQLAlchemy URL of the job table; default SQLite in data_dir")
    queue_url: str | None = Field(
        default=None, description="redis://host:port/db for scale-out; default SQLite in data_dir")
    api_keys: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="comma-separated bearer keys, or sha256:<hex> of a key; empty = no auth")
    max_upload_bytes: int = Field(default=512 * 1024 * 1024, gt=0,
                                  description="largest accepted mesh upload")
    heartbeat_interval_s: float = Field(default=2.0, gt=0, description="worker heartbeat period")
    stale_after_s: float = Field(
        default=30.0, gt=0, description="a running job without heartbeat this long is reaped")
    reaper_interval_s: float = Field(default=5.0, gt=0, description="how often the reaper looks")
    max_attempts: int = Field(default=3, ge=1, description="runs of a job before it fails as lost")
    progress_interval_s: float = Field(
        default=0.5, gt=0, description="least time between progress writes (and cancel checks)")
    plan_threads: int | None = Field(
        default=None, ge=1, description="visibility threads per job (default: cores / workers)")
    worker_health_interval_s: float = Field(
        default=2.0, gt=0, description="how often a dead worker process is replaced")
    log_level: str = Field(default="info", description="debug, info, warning or error")

    @field_validator("api_keys", mode="before")
    @classmethod
    def _split_keys(cls, value: object) -> object:
        if isinstance(value, str):
            return [key.strip() for key in value.split(",") if key.strip()]
        return value

    @property
    def auth_enabled(self) -> bool:
        """Whether bearer keys are required."""
        return bool(self.api_keys)

    @property
    def effective_host(self) -> str:
        """The bind address: loopback whenever no API key is configured."""
        if not self.auth_enabled and self.host not in LOOPBACK_HOSTS:
            return "127.0.0.1"
        return self.host

    @property
    def job_db_url(self) -> str:
        """The job table's URL: ``database_url`` or SQLite in the data directory."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'jobs.db').resolve()}"

    @property
    def threads_per_job(self) -> int:
        """Visibility threads per job, so that N workers do not oversubscribe the cores."""
        if self.plan_threads is not None:
            return self.plan_threads
        return max(1, _cores() // max(1, self.workers))
