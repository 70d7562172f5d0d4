"""The tables (SQLAlchemy Core) and the engine: one code path for SQLite and PostgreSQL.

The URL picks the database. SQLite runs in WAL mode with a busy timeout so that the API and
several worker processes can write the same file.
"""

from __future__ import annotations

import contextlib
from typing import Any

from sqlalchemy import (
    BigInteger,
    Column,
    Engine,
    Float,
    Index,
    Integer,
    MetaData,
    PrimaryKeyConstraint,
    String,
    Table,
    Text,
    create_engine,
    event,
    exc,
    inspect,
    text,
)

metadata = MetaData()

meshes = Table(
    "meshes", metadata,
    Column("id", String(64), primary_key=True),  # sha256 of the bytes
    Column("format", String(8), nullable=False),
    Column("size_bytes", BigInteger, nullable=False),
    Column("summary", Text, nullable=False),  # JSON: faces, vertices, bounds, groups
    Column("created", Float, nullable=False),  # epoch seconds
)

mesh_owners = Table(
    "mesh_owners", metadata,
    Column("mesh_id", String(64), nullable=False),
    Column("owner", String(64), nullable=False),
    Column("filename", String(255), nullable=True),
    Column("created", Float, nullable=False),
    PrimaryKeyConstraint("mesh_id", "owner"),
)

jobs = Table(
    "jobs", metadata,
    Column("id", String(32), primary_key=True),
    Column("owner", String(64), nullable=False, index=True),
    Column("mesh_id", String(64), nullable=False, index=True),
    Column("parameters", Text, nullable=False),  # JSON, as submitted
    Column("status", String(16), nullable=False, index=True),
    Column("progress", Integer, nullable=False, default=0),
    Column("message", Text, nullable=False, default=""),
    Column("created", Float, nullable=False),
    Column("started", Float, nullable=True),
    Column("finished", Float, nullable=True),
    Column("updated", Float, nullable=False),
    Column("heartbeat", Float, nullable=True),
    Column("attempts", Integer, nullable=False, default=0),
    Column("worker_token", String(32), nullable=True),  # the current claim
    Column("worker", String(128), nullable=True),  # host:pid of the claimant
    Column("idempotency_key", String(255), nullable=True),
    Column("request_hash", String(64), nullable=True),
    Column("problem", Text, nullable=True),  # JSON problem document of a failed job
    Column("timings", Text, nullable=True),  # JSON seconds per stage
    Column("outputs", Text, nullable=True),  # JSON {name: {"bytes", "sha256"}}
    Column("attempt_log", Text, nullable=True),  # JSON list: one entry per ended attempt
)
Index("jobs_owner_idempotency", jobs.c.owner, jobs.c.idempotency_key, unique=True)


_SQLITE_POOL_SIZE = 40


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.execute("PRAGMA busy_timeout=30000")
    cursor.close()


def make_engine(url: str) -> Engine:
    """An engine for ``url`` with the tables created (idempotent)."""
    if url.startswith("sqlite"):
        # a pool as large as the thread pool that uses it (anyio's default: 40 threads):
        # with SQLAlchemy's default of 5 (+10 overflow), a burst of requests opened and
        # closed overflow connections, each with its PRAGMAs, on the request path
        engine = create_engine(url, connect_args={"timeout": 30, "check_same_thread": False},
                               pool_size=_SQLITE_POOL_SIZE, max_overflow=8)
        event.listen(engine, "connect", _sqlite_pragmas)
    else:
        engine = create_engine(url, pool_pre_ping=True)
    try:
        metadata.create_all(engine)
    except exc.DBAPIError:
        # another process created the tables at the same moment; theirs are the same
        metadata.create_all(engine)
    _add_missing_columns(engine)
    return engine


def _add_missing_columns(engine: Engine) -> None:
    """Add the nullable columns a table of an older version lacks (create_all adds none)."""
    for table in metadata.sorted_tables:
        present = {c["name"] for c in inspect(engine).get_columns(table.name)}
        for column in table.columns:
            if column.name in present or not column.nullable:
                continue
            kind = column.type.compile(dialect=engine.dialect)
            with contextlib.suppress(exc.DBAPIError), engine.begin() as conn:
                # another process may add it at the same moment
                conn.execute(text(f'ALTER TABLE {table.name} ADD COLUMN "{column.name}" {kind}'))
