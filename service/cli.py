"""``scanplan serve`` (API + worker processes) and ``scanplan worker`` (scale-out consumer).

Registered through the ``scanplan.commands`` entry point. Each option is also a
``SCANPLAN_*`` environment variable (see :mod:`service.config`); the option wins.
"""

from __future__ import annotations

import argparse
import ctypes
import logging
import multiprocessing
import os
import signal
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # imported where used: pydantic-settings would slow ``scanplan --help``
    from service.config import Settings

log = logging.getLogger("scanplan.service")
_STOP_WAIT_S = 15.0


def register(subparsers: Any) -> None:
    """Add ``serve`` and ``worker`` to the ``scanplan`` command."""
    serve = subparsers.add_parser(
        "serve", help="start the HTTP API and its worker processes",
        description="Start the API and N worker processes on the embedded default "
                    "(SQLite queue and job table in the data directory).")
    serve.add_argument("--host", help="bind address (SCANPLAN_HOST, default 127.0.0.1; "
                                      "loopback only unless SCANPLAN_API_KEYS is set)")
    serve.add_argument("--port", type=int, help="TCP port (SCANPLAN_PORT, default 8000)")
    _common(serve)
    serve.set_defaults(handler=run_serve)
    worker = subparsers.add_parser(
        "worker", help="consume jobs only (scale-out: Redis queue, PostgreSQL job table)",
        description="Run N worker processes against SCANPLAN_QUEUE_URL and "
                    "SCANPLAN_DATABASE_URL; files through SCANPLAN_STORE_URL (s3://...), "
                    "else the data directory shared with the API.")
    _common(worker)
    worker.set_defaults(handler=run_worker)


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data-dir", type=Path,
                        help="meshes, results and SQLite files (SCANPLAN_DATA_DIR, "
                             "default ./data)")
    parser.add_argument("--workers", type=int,
                        help="worker processes (SCANPLAN_WORKERS, default: the cores)")


def settings_from(args: argparse.Namespace) -> Settings:
    """Settings from the environment, overridden by the options given."""
    from service.config import Settings

    overrides = {name: getattr(args, name, None) for name in ("host", "port", "data_dir",
                                                              "workers")}
    return Settings(**{k: v for k, v in overrides.items() if v is not None})


def _logging(settings: Settings) -> None:
    logging.basicConfig(level=settings.log_level.upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")


def run_serve(args: argparse.Namespace) -> int:
    """The API in this process, the huey consumer (N workers) in a forked one."""
    import uvicorn

    from service.database import make_engine
    from service.main import create_app
    settings = settings_from(args)
    _logging(settings)
    host = settings.effective_host
    if not settings.auth_enabled:
        log.warning("no API keys configured (SCANPLAN_API_KEYS): serving on loopback %s only"
                    "%s", host, "" if host == settings.host else
                    f" instead of {settings.host}")
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    make_engine(settings.job_db_url).dispose()  # create the tables before anyone forks
    consumer = None
    if settings.workers > 0:
        # fork before the server starts threads; the child runs huey's consumer
        consumer = multiprocessing.get_context("fork").Process(
            target=_consumer_main, args=(settings,), name="scanplan-consumer")
        consumer.start()
    # uvicorn re-raises the SIGTERM it caught once it has shut down; turn it into SystemExit
    # so that the consumer below is stopped too instead of being orphaned
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    log.info("scanplan %s on http://%s:%d with %d worker process(es), data in %s",
             "serve", host, settings.port, settings.workers, settings.data_dir.resolve())
    try:
        uvicorn.run(create_app(settings), host=host, port=settings.port,
                    log_level=settings.log_level.lower())
    finally:
        if consumer is not None:
            _stop(consumer)
    return 0


def _exit_on_sigterm(signum: int, frame: object) -> None:
    raise SystemExit(0)


def _consumer_main(settings: Settings) -> None:
    """The forked consumer: it gets SIGTERM when ``serve`` dies, even by SIGKILL (Linux)."""
    from service.worker import run_consumer

    _terminate_with_parent()
    run_consumer(settings, with_reaper=False)


def _terminate_with_parent() -> None:
    """Ask Linux to send SIGTERM to this process when its parent exits (prctl PDEATHSIG)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_pdeathsig = 1
        libc.prctl(pr_set_pdeathsig, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):  # not Linux: the SIGTERM path in run_serve still works
        log.debug("PR_SET_PDEATHSIG unavailable; the consumer relies on run_serve to stop it")


def _stop(process: Any) -> None:
    """Interrupt the consumer: running jobs go back to the queue (see worker.execute_job)."""
    if process.is_alive() and process.pid is not None:
        os.kill(process.pid, signal.SIGTERM)
    process.join(_STOP_WAIT_S)
    if process.is_alive():
        process.kill()
        process.join()


def run_worker(args: argparse.Namespace) -> int:
    """Consume jobs (and reap stale ones) until interrupted."""
    from service.worker import run_consumer

    settings = settings_from(args)
    _logging(settings)
    if settings.workers < 1:
        settings = settings.model_copy(update={"workers": 1})
    run_consumer(settings, with_reaper=True)
    return 0
