"""Settings: the one place that reads the environment (prefix ``SCANPLAN_``).

Every knob of ``scanplan serve`` and ``scanplan worker`` is a field here; the command line
overrides the environment, which overrides the defaults.
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
from pathlib import Path
from typing import Annotated, Literal
from urllib.parse import urlsplit

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

LOOPBACK_HOSTS = ("127.0.0.1", "::1", "localhost")


def _cores() -> int:
    return os.cpu_count() or 1


def _memory_bytes() -> int | None:
    """Memory this service may use: the machine's, or its container's cgroup limit if lower
    (None when the platform says neither)."""
    sizes = []
    with contextlib.suppress(ValueError, OSError, AttributeError):
        sizes.append(int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES")))
    try:  # cgroup v2 (Docker, systemd): "max" or a number of bytes
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit.isdigit():
            sizes.append(int(limit))
    except OSError:
        pass
    return min(sizes) if sizes else None


def parse_store_url(url: str) -> tuple[str, str]:
    """``s3://bucket/prefix`` -> (bucket, prefix). Raises ValueError with the fix.

    Here, not in :mod:`service.store`, so that the settings check the URL without importing
    the store, and the store imports the settings, never the other way round."""
    parts = urlsplit(url)
    if parts.scheme != "s3" or not parts.netloc or parts.query or parts.fragment:
        raise ValueError(f"SCANPLAN_STORE_URL must look like s3://bucket/prefix (got {url!r}); "
                         "leave it unset to keep files in the data directory")
    return parts.netloc, parts.path.strip("/")


class Settings(BaseSettings):
    """Service configuration; ``SCANPLAN_<FIELD>`` sets each field."""

    model_config = SettingsConfigDict(env_prefix="SCANPLAN_", extra="ignore")

    host: str = Field(default="127.0.0.1", description="address the API binds to")
    port: int = Field(default=8000, ge=0, le=65535, description="TCP port of the API")
    data_dir: Path = Field(default=Path("data"),
                           description="meshes, results, SQLite files (scratch only with "
                                       "store_url)")
    workers: int = Field(default_factory=_cores, ge=0,
                         description="worker processes (default: the number of cores)")
    database_url: str | None = Field(
        default=None, description="SQLAlchemy URL of the job table; default SQLite in data_dir")
    queue_url: str | None = Field(
        default=None, description="redis://host:port/db for scale-out; default SQLite in data_dir")
    store_url: str | None = Field(
        default=None, description="s3://bucket/prefix: meshes and results in an S3-compatible "
                                  "store (AWS_ENDPOINT_URL, AWS_ACCESS_KEY_ID...); default: "
                                  "files in data_dir")
    store_addressing_style: Literal["auto", "path", "virtual"] | None = Field(
        default=None, description="S3 addressing; default: path with AWS_ENDPOINT_URL, else auto")
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
    dask_scheduler: str | None = Field(
        default=None,
        description="address of a Dask scheduler (tcp://host:8786): each plan's visibility "
                    "and overlap rows run on its workers, the plan's bytes the same; a "
                    "scheduler that cannot be reached fails the job naming it")
    plan_threads: int | None = Field(
        default=None, ge=1, description="visibility threads per job (default: cores / workers)")
    warm_up: bool = Field(
        default=True,
        description="load the planner's modules and its compiled kernels once in the "
                    "consumer, before it forks the worker processes: each job then starts "
                    "with them in memory, shared, instead of loading them itself")
    worker_health_interval_s: float = Field(
        default=2.0, gt=0, description="how often a dead worker process is replaced")
    log_level: str = Field(default="info", description="debug, info, warning or error")
    # guards: what one job may cost (see service/guards.py and service/plan_process.py)
    job_memory_limit_mb: int | None = Field(
        default=None, ge=0,
        description="address-space limit of each job's planning process, MiB (RLIMIT_AS); "
                    "default: 80 % of the machine's memory shared by the workers; 0: none")
    worker_nice: int = Field(
        default=10, ge=0, le=19,
        description="CPU niceness of each job's planning process: it yields the cores to "
                    "the API and to the workers' heartbeats and shutdown")
    cancel_poll_interval_s: float = Field(
        default=0.25, gt=0, description="how often a worker checks that its job still stands")
    max_faces: int = Field(default=20_000_000, ge=1,
                           description="refuse plans estimated above this many faces after "
                                       "remeshing")
    max_grid_points: int = Field(default=2_000_000, ge=1,
                                 description="refuse generated grids above this many points")
    max_candidates: int = Field(default=100_000, ge=1,
                                description="refuse more explicit candidates than this")
    max_candidate_face_pairs: float = Field(
        default=2e11, gt=0, description="refuse plans above this many candidate x face pairs")
    max_request_bytes: int = Field(default=8 * 1024 * 1024, gt=0,
                                   description="largest JSON request body (not uploads)")
    # callbacks (service/callbacks.py)
    callback_secret: SecretStr | None = Field(
        default=None, description="HMAC-SHA256 key of X-Scanplan-Signature; unset: execute "
                                  "requests with a subscriber are refused")
    callback_allow: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="comma-separated CIDRs callbacks may reach besides "
                                          "public addresses (e.g. 10.0.0.0/8)")
    callback_progress_interval_s: float = Field(
        default=5.0, ge=0, description="least time between two inProgress callbacks of a job")
    callback_timeout_s: float = Field(default=10.0, gt=0, description="timeout of one POST")
    callback_max_attempts: int = Field(default=8, ge=1,
                                       description="POSTs of one callback before giving up")
    callback_retry_base_s: float = Field(
        default=5.0, gt=0, description="wait after the first failed POST; doubles each time, "
                                       "at most 300 s")
    callback_poll_interval_s: float = Field(
        default=1.0, gt=0, description="how often the API looks for job changes to announce")
    # fair tenants (service/tenants.py)
    max_active_jobs_per_key: int = Field(
        default=100, ge=0, description="jobs one API key may have queued or running; a "
        "submission past it answers 429 with Retry-After; 0: no limit")
    busy_retry_after_s: int = Field(default=30, ge=1,
                                    description="Retry-After of that 429, seconds")

    @field_validator("api_keys", "callback_allow", mode="before")
    @classmethod
    def _split_keys(cls, value: object) -> object:
        if isinstance(value, str):
            return [key.strip() for key in value.split(",") if key.strip()]
        return value

    @field_validator("store_url")
    @classmethod
    def _check_store_url(cls, value: str | None) -> str | None:
        if value:
            parse_store_url(value)  # ValueError naming the expected form
        return value or None

    @field_validator("callback_allow")
    @classmethod
    def _check_networks(cls, value: list[str]) -> list[str]:
        for cidr in value:
            try:
                ipaddress.ip_network(cidr, strict=False)
            except ValueError as exc:
                raise ValueError(f"SCANPLAN_CALLBACK_ALLOW: {cidr!r} is not a network "
                                 "(write 10.0.0.0/8 or 127.0.0.1)") from exc
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
    def job_memory_limit_bytes(self) -> int | None:
        """RLIMIT_AS of a job's planning process in bytes; None: unlimited."""
        if self.job_memory_limit_mb == 0:
            return None
        if self.job_memory_limit_mb is not None:
            return self.job_memory_limit_mb * 2**20
        total = _memory_bytes()
        if total is None:
            return None
        # at least 2 GiB: below that the imported libraries alone leave too little room
        return max(2 * 2**30, int(total * 0.8) // max(1, self.workers))

    @property
    def threads_per_job(self) -> int:
        """Visibility threads per job, so that N workers do not oversubscribe the cores."""
        if self.plan_threads is not None:
            return self.plan_threads
        return max(1, _cores() // max(1, self.workers))
