"""Callbacks (OGC API - Processes Part 1, conformance class ``callback``).

An execute request may name a ``subscriber``: ``successUri``, ``inProgressUri``,
``failedUri``. The service POSTs the job's status document to ``inProgressUri`` when the
job's status or stage changes (at most one every ``SCANPLAN_CALLBACK_PROGRESS_INTERVAL_S``),
to ``successUri`` once it succeeded (the document then links every output) and to
``failedUri`` once it failed (the document carries the problem). A dismissed or deleted job
is not announced: its owner did that.

How it runs. Two tables beside the job table: ``callback_subscriptions`` (a job's URIs and
the last state announced) and ``callback_deliveries`` (one row per POST to make: body,
state, attempts, status codes, last error). A :class:`CallbackDispatcher` thread in the API
process polls both: it compares each subscribed job's row with the last state announced and
queues a delivery when they differ, then sends the due deliveries from a small thread pool,
retrying with exponential backoff. The workers are not involved at all, so a slow or dead
receiver can never hold up a plan, and a job failed by the reaper ("worker lost") is
announced like any other. The tables live in the job database, so the same code runs in
the embedded mode (SQLite) and in scale-out (PostgreSQL, every API replica running a
dispatcher: each transition and each claim is a conditional UPDATE, so a delivery is made
once). A huey task was the other choice: it would run on the plan workers' process slots
(a receiver timing out would hold a core's worth of planning), and its retry delays need
the consumer's scheduler; the delivery rows also are the record ``GET /jobs/{id}/callbacks``
shows.

Safety. A callback must not become a way into the operator's network: only http(s) URIs,
and every address the host resolves to must be global (:attr:`ipaddress.IPv4Address.
is_global`) or inside a network of ``SCANPLAN_CALLBACK_ALLOW``. The check runs at
submission (422 naming the field) and again before every attempt, and the POST connects to
the address just checked (the TLS name and ``Host`` stay the URI's), so a DNS answer that
changes in between cannot redirect it. Redirects are not followed and proxies from the
environment are ignored. Every body is signed: ``X-Scanplan-Signature: sha256=<hex
HMAC-SHA256 of the body keyed with SCANPLAN_CALLBACK_SECRET>``.
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import json
import logging
import socket
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

import httpx
from sqlalchemy import (
    Boolean,
    Column,
    Engine,
    Float,
    Integer,
    MetaData,
    String,
    Table,
    Text,
    and_,
    delete,
    exists,
    insert,
    or_,
    select,
    update,
)

from service.config import Settings
from service.database import jobs
from service.job_store import ACCEPTED, DISMISSED, FAILED, RUNNING, SUCCESSFUL, JobRecord
from service.problems import PROBLEMS, ProblemKind, ServiceError
from service.timefmt import iso

log = logging.getLogger("scanplan.callbacks")

SIGNATURE_HEADER = "X-Scanplan-Signature"
IN_PROGRESS, SUCCESS, FAILURE = "inProgress", "success", "failed"
URI_FIELDS = {IN_PROGRESS: "inProgressUri", SUCCESS: "successUri", FAILURE: "failedUri"}
PENDING, SENDING, DELIVERED, GAVE_UP, SUPERSEDED = (
    "pending", "sending", "delivered", "failed", "superseded")
HISTORY_KEPT = 20  # attempts remembered per delivery (the count is kept in full)
RETRY_CAP_S = 300.0  # longest wait between two attempts
ERROR_BYTES = 200  # of a failed answer's body, kept as its error
PURGE_INTERVAL_S = 60.0  # how often the rows of deleted jobs are dropped

Address = ipaddress.IPv4Address | ipaddress.IPv6Address
Network = ipaddress.IPv4Network | ipaddress.IPv6Network


class CallbackRefusedError(ServiceError):
    """A subscriber URI the service will not call; names the field."""

    def __init__(self, parameter: str, message: str) -> None:
        super().__init__(f"{parameter}: {message}")
        self.parameter = parameter


PROBLEMS[CallbackRefusedError] = ProblemKind(422, "urn:scanplan:problem:callback-refused",
                                             "Callback URI refused")


# --- where a callback may go -------------------------------------------------------------

def parse_networks(cidrs: Sequence[str]) -> tuple[Network, ...]:
    """``SCANPLAN_CALLBACK_ALLOW`` as networks (``10.0.0.0/8``; a bare address is a /32)."""
    return tuple(ipaddress.ip_network(cidr.strip(), strict=False) for cidr in cidrs)


def _kind(ip: Address) -> str | None:
    """Why ``ip`` is not a public address (None: it is)."""
    for name, flag in (("loopback", ip.is_loopback), ("link-local", ip.is_link_local),
                       ("unspecified", ip.is_unspecified), ("multicast", ip.is_multicast),
                       ("private", ip.is_private), ("reserved", ip.is_reserved)):
        if flag:
            return name
    return None if ip.is_global else "non-global"


def _plain(ip: Address) -> Address:
    """An IPv4-mapped IPv6 address (``::ffff:10.0.0.1``) as the IPv4 address it is."""
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped
    return ip


def refusal(ip: Address, allowed: Sequence[Network]) -> str | None:
    """Why a callback may not connect to ``ip`` (None: it may)."""
    ip = _plain(ip)
    if any(ip.version == net.version and ip in net for net in allowed):
        return None
    kind = _kind(ip)
    if kind is None:
        return None
    return (f"{ip} is a {kind} address; callbacks go only to public addresses unless the "
            "operator lists the network in SCANPLAN_CALLBACK_ALLOW")


@dataclass(frozen=True)
class Target:
    """A checked callback URI and the addresses it may connect to, in resolver order."""

    uri: str
    host: str
    port: int
    addresses: tuple[Address, ...]


def _resolve(host: str, port: int) -> tuple[Address, ...]:
    try:
        return (ipaddress.ip_address(host),)
    except ValueError:
        pass
    infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    found: dict[Address, None] = {}
    for *_, sockaddr in infos:
        found[ipaddress.ip_address(str(sockaddr[0]).split("%", 1)[0])] = None
    return tuple(found)


def check_uri(uri: str, parameter: str, allowed: Sequence[Network]) -> Target:
    """The target of ``uri`` when every address it resolves to may be called.

    Raises :class:`CallbackRefusedError` naming ``parameter`` otherwise: not http(s), no
    host, user info, a host that does not resolve, or any address not public and not in
    ``allowed`` (one bad answer is enough: a resolver may hand out either).
    """
    try:
        parts = urlsplit(uri)
        port = parts.port or (443 if parts.scheme == "https" else 80)
    except ValueError as exc:
        raise CallbackRefusedError(parameter, f"{uri!r} is not a valid URI ({exc})") from exc
    if parts.scheme not in ("http", "https"):
        raise CallbackRefusedError(parameter, f"{uri!r}: only http and https callbacks are "
                                   "made")
    if not parts.hostname:
        raise CallbackRefusedError(parameter, f"{uri!r} names no host")
    if parts.username is not None or parts.password is not None:
        raise CallbackRefusedError(parameter, f"{uri!r} carries user info; the signature "
                                   "authenticates the service, put a token in the path if "
                                   "the receiver needs one")
    try:
        addresses = _resolve(parts.hostname, port)
    except (OSError, UnicodeError) as exc:
        raise CallbackRefusedError(parameter, f"the host of {uri!r} does not resolve "
                                   f"({exc})") from exc
    if not addresses:
        raise CallbackRefusedError(parameter, f"the host of {uri!r} does not resolve")
    for ip in addresses:
        reason = refusal(ip, allowed)
        if reason is not None:
            raise CallbackRefusedError(parameter, f"{uri!r} resolves to {reason}")
    return Target(uri, parts.hostname, port, addresses)


def sign(secret: str, body: bytes) -> str:
    """The ``X-Scanplan-Signature`` value of ``body``."""
    digest = hmac.new(secret.encode(), body, hashlib.sha256).hexdigest()
    return f"sha256={digest}"


# --- the tables --------------------------------------------------------------------------

metadata = MetaData()

subscriptions = Table(
    "callback_subscriptions", metadata,
    Column("job_id", String(32), primary_key=True),
    Column("base_url", Text, nullable=False),  # the API's URL as the submitter saw it
    Column("success_uri", Text, nullable=False),
    Column("in_progress_uri", Text, nullable=True),
    Column("failed_uri", Text, nullable=True),
    Column("seen", String(64), nullable=False),  # last state announced: "running:visibility"
    Column("seen_at", Float, nullable=False),  # when an inProgress delivery was last queued
    Column("closed", Boolean, nullable=False, default=False, index=True),
    Column("created", Float, nullable=False),
)

deliveries = Table(
    "callback_deliveries", metadata,
    Column("id", String(32), primary_key=True),  # X-Scanplan-Delivery: same on every retry
    Column("job_id", String(32), nullable=False, index=True),
    Column("event", String(16), nullable=False),  # inProgress, success, failed
    Column("uri", Text, nullable=False),
    Column("body", Text, nullable=False),  # the exact bytes signed and sent (UTF-8 JSON)
    Column("state", String(16), nullable=False, index=True),
    Column("attempts", Integer, nullable=False, default=0),
    Column("next_attempt", Float, nullable=False),
    Column("lease_until", Float, nullable=True),  # a sender's claim while it posts
    Column("last_status_code", Integer, nullable=True),
    Column("last_error", Text, nullable=True),
    Column("history", Text, nullable=False),  # JSON [{at, status_code, error, address}]
    Column("created", Float, nullable=False),
    Column("finished", Float, nullable=True),
)


def _signature_of(job: JobRecord) -> str:
    """What an inProgress callback announces: the status, and the stage while running."""
    if job.status == RUNNING:
        return f"{RUNNING}:{job.message.split(':', 1)[0]}"[:64]
    return job.status


@dataclass(frozen=True)
class Subscription:
    """One row of ``callback_subscriptions``."""

    job_id: str
    base_url: str
    uris: dict[str, str | None]  # event -> URI
    seen: str
    seen_at: float


@dataclass(frozen=True)
class Delivery:
    """A delivery a sender claimed."""

    id: str
    job_id: str
    event: str
    uri: str
    body: bytes
    attempts: int
    history: list[dict[str, Any]]


class CallbackStore:
    """Reads and conditional writes of the two callback tables (created if missing)."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        metadata.create_all(engine)

    def subscribe(self, job_id: str, base_url: str, uris: dict[str, str | None]) -> None:
        """Remember the subscriber of a new job (``uris``: event -> URI)."""
        success = uris.get(SUCCESS)
        assert success is not None, "successUri is required"
        with self.engine.begin() as conn:
            conn.execute(insert(subscriptions).values(
                job_id=job_id, base_url=base_url.rstrip("/"), success_uri=success,
                in_progress_uri=uris.get(IN_PROGRESS), failed_uri=uris.get(FAILURE),
                seen=ACCEPTED, seen_at=0.0, closed=False, created=time.time()))

    def subscription(self, job_id: str) -> Subscription | None:
        with self.engine.connect() as conn:
            row = conn.execute(select(subscriptions).where(
                subscriptions.c.job_id == job_id)).first()
        return None if row is None else _subscription(row._mapping)

    def open_subscriptions(self) -> list[Subscription]:
        with self.engine.connect() as conn:
            rows = conn.execute(select(subscriptions).where(
                subscriptions.c.closed.is_(False))).all()
        return [_subscription(r._mapping) for r in rows]

    def transition(self, sub: Subscription, seen: str, *, now: float, close: bool,
                   event: str | None = None, body: bytes = b"") -> bool:
        """Move ``sub`` from the state it was read in to ``seen``, queueing a delivery of
        ``body`` for ``event``; False when another dispatcher did it first."""
        values: dict[str, Any] = {"seen": seen, "closed": close}
        if event == IN_PROGRESS:
            values["seen_at"] = now
        with self.engine.begin() as conn:
            moved = conn.execute(update(subscriptions).where(
                subscriptions.c.job_id == sub.job_id, subscriptions.c.seen == sub.seen,
                subscriptions.c.seen_at == sub.seen_at, subscriptions.c.closed.is_(False),
            ).values(**values)).rowcount == 1
            if not moved or event is None:
                return moved
            uri = sub.uris[event]
            assert uri is not None
            # only the newest progress matters, and none once the job has ended
            conn.execute(update(deliveries).where(
                deliveries.c.job_id == sub.job_id, deliveries.c.event == IN_PROGRESS,
                deliveries.c.state == PENDING).values(state=SUPERSEDED, finished=now))
            conn.execute(insert(deliveries).values(
                id=uuid.uuid4().hex, job_id=sub.job_id, event=event, uri=uri,
                body=body.decode(), state=PENDING, attempts=0, next_attempt=now,
                history="[]", created=now))
        return True

    def forget(self, job_id: str) -> None:
        """The job was deleted: drop its subscription and the deliveries not being sent."""
        with self.engine.begin() as conn:
            conn.execute(delete(subscriptions).where(subscriptions.c.job_id == job_id))
            conn.execute(delete(deliveries).where(deliveries.c.job_id == job_id,
                                                  deliveries.c.state != SENDING))

    def purge_deleted(self) -> None:
        """Drop the rows of jobs no longer in the job table (deleted once finished)."""
        with self.engine.begin() as conn:
            for table in (subscriptions, deliveries):
                gone = ~exists(select(jobs.c.id).where(jobs.c.id == table.c.job_id))
                where = [gone, deliveries.c.state != SENDING] if table is deliveries else [gone]
                conn.execute(delete(table).where(*where))

    def claim_due(self, now: float, limit: int, lease_s: float) -> list[Delivery]:
        """Up to ``limit`` deliveries due now (or whose sender died), claimed for
        ``lease_s`` seconds."""
        due = or_(and_(deliveries.c.state == PENDING, deliveries.c.next_attempt <= now),
                  and_(deliveries.c.state == SENDING, deliveries.c.lease_until < now))
        with self.engine.connect() as conn:
            rows = conn.execute(select(deliveries).where(due)
                                .order_by(deliveries.c.next_attempt).limit(limit)).all()
        claimed = []
        for row in rows:
            with self.engine.begin() as conn:
                won = conn.execute(update(deliveries).where(deliveries.c.id == row.id, due)
                                   .values(state=SENDING, lease_until=now + lease_s)
                                   ).rowcount == 1
            if won:
                claimed.append(Delivery(row.id, row.job_id, row.event, row.uri,
                                        row.body.encode(), row.attempts,
                                        json.loads(row.history)))
        return claimed

    def record(self, delivery: Delivery, attempt: dict[str, Any], *, state: str,
               next_attempt: float) -> None:
        """Write the outcome of one attempt (``state``: delivered, pending again, failed)."""
        history = [*delivery.history, attempt][-HISTORY_KEPT:]
        values: dict[str, Any] = {
            "state": state, "attempts": delivery.attempts + 1, "next_attempt": next_attempt,
            "lease_until": None, "last_status_code": attempt["status_code"],
            "last_error": attempt["error"], "history": json.dumps(history)}
        if state != PENDING:
            values["finished"] = time.time()
        with self.engine.begin() as conn:
            conn.execute(update(deliveries).where(deliveries.c.id == delivery.id,
                                                  deliveries.c.state == SENDING)
                         .values(**values))

    def deliveries_of(self, job_id: str) -> list[dict[str, Any]]:
        """Every delivery of ``job_id``, oldest first, as ``GET /jobs/{id}/callbacks``
        shows them."""
        with self.engine.connect() as conn:
            rows = conn.execute(select(deliveries).where(deliveries.c.job_id == job_id)
                                .order_by(deliveries.c.created)).all()
        return [{
            "id": r.id, "event": r.event, "uri": r.uri, "state": r.state,
            "attempts": r.attempts, "created": iso(r.created), "finished": iso(r.finished),
            "next_attempt": iso(r.next_attempt) if r.state == PENDING else None,
            "last_status_code": r.last_status_code, "last_error": r.last_error,
            "history": json.loads(r.history),
        } for r in rows]


def _subscription(row: Any) -> Subscription:
    return Subscription(
        job_id=row["job_id"], base_url=row["base_url"],
        uris={SUCCESS: row["success_uri"], IN_PROGRESS: row["in_progress_uri"],
              FAILURE: row["failed_uri"]},
        seen=row["seen"], seen_at=row["seen_at"])


# --- the dispatcher ----------------------------------------------------------------------

# the document a callback carries: the job's status document with absolute links
Render = Callable[[JobRecord, str], dict[str, Any]]


def encode(document: dict[str, Any]) -> bytes:
    """The body of a callback: compact UTF-8 JSON, keys sorted (what is signed)."""
    return json.dumps(document, sort_keys=True, separators=(",", ":"),
                      ensure_ascii=False).encode()


def retry_delay_s(attempts: int, base_s: float) -> float:
    """Wait after the ``attempts``-th failed attempt: base, 2 x base, 4 x base, ... <= 300 s."""
    return float(min(RETRY_CAP_S, base_s * 2 ** (attempts - 1)))


class CallbackDispatcher:
    """Turns job state changes into deliveries and sends them (one thread plus a pool)."""

    def __init__(self, store: CallbackStore, settings: Settings, render: Render,
                 senders: int = 4) -> None:
        self.store = store
        self.settings = settings
        self.render = render
        self.senders = senders
        self.allowed = parse_networks(settings.callback_allow)
        self._pool = ThreadPoolExecutor(senders, thread_name_prefix="callback")
        self._in_flight = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._client = httpx.Client(
            follow_redirects=False, trust_env=False,  # no redirect, no proxy from the env
            timeout=settings.callback_timeout_s,
            limits=httpx.Limits(max_keepalive_connections=0),  # one connection per POST
            headers={"User-Agent": "scanplan-callbacks"})

    # observation: which jobs changed since their last announcement
    def observe(self, now: float | None = None) -> int:
        """Queue the deliveries that the jobs' current states call for; returns how many."""
        now = time.time() if now is None else now
        subs = self.store.open_subscriptions()
        if not subs:
            return 0
        with self.store.engine.connect() as conn:
            rows = conn.execute(select(jobs).where(
                jobs.c.id.in_([s.job_id for s in subs]))).all()
        records = {r.id: JobRecord.from_row(r) for r in rows}
        queued = 0
        for sub in subs:
            job = records.get(sub.job_id)
            if job is None:  # deleted by its owner
                self.store.forget(sub.job_id)
            elif job.status in (SUCCESSFUL, FAILED):
                event = SUCCESS if job.status == SUCCESSFUL else FAILURE
                if sub.uris[event] is None:
                    self.store.transition(sub, job.status, now=now, close=True)
                elif self.store.transition(sub, job.status, now=now, close=True, event=event,
                                           body=encode(self.render(job, sub.base_url))):
                    queued += 1
            elif job.status == DISMISSED:
                self.store.transition(sub, job.status, now=now, close=True)
            else:
                queued += self._progress(sub, job, now)
        return queued

    def _progress(self, sub: Subscription, job: JobRecord, now: float) -> int:
        seen = _signature_of(job)
        if seen == sub.seen:
            return 0
        if sub.uris[IN_PROGRESS] is None:
            self.store.transition(sub, seen, now=now, close=False)
            return 0
        if now - sub.seen_at < self.settings.callback_progress_interval_s:
            return 0  # the change is announced once the interval has passed
        return int(self.store.transition(sub, seen, now=now, close=False, event=IN_PROGRESS,
                                         body=encode(self.render(job, sub.base_url))))

    # delivery: claim what is due and post it from the pool
    def send_due(self, now: float | None = None) -> list[Any]:
        """Claim the due deliveries the pool has room for and start them (futures)."""
        now = time.time() if now is None else now
        with self._lock:
            room = self.senders - self._in_flight
        if room <= 0:
            return []
        lease_s = 2 * self.settings.callback_timeout_s + 30
        futures = []
        for delivery in self.store.claim_due(now, room, lease_s):
            with self._lock:
                self._in_flight += 1
            futures.append(self._pool.submit(self._send, delivery))
        return futures

    def _send(self, delivery: Delivery) -> None:
        try:
            attempt = self.post(delivery)
            attempts = delivery.attempts + 1
            if attempt["status_code"] is not None and 200 <= attempt["status_code"] < 300:
                state, next_attempt = DELIVERED, time.time()
            elif attempts >= self.settings.callback_max_attempts:
                state, next_attempt = GAVE_UP, time.time()
            else:
                state = PENDING
                next_attempt = time.time() + retry_delay_s(
                    attempts, self.settings.callback_retry_base_s)
            self.store.record(delivery, attempt, state=state, next_attempt=next_attempt)
            log.info("callback %s of job %s to %s: %s (attempt %d)", delivery.event,
                     delivery.job_id, delivery.uri, state, attempts)
        except Exception:  # the database may be briefly away: the lease runs out, and retries
            log.exception("callback %s of job %s could not be recorded", delivery.event,
                          delivery.job_id)
        finally:
            with self._lock:
                self._in_flight -= 1

    def post(self, delivery: Delivery) -> dict[str, Any]:
        """One attempt: check the URI's addresses again, POST to the first that connects.

        Returns ``{at, status_code, error, address}`` (status_code None: no response).
        """
        attempt: dict[str, Any] = {"at": iso(time.time()), "status_code": None,
                                   "error": None, "address": None}
        secret = self.settings.callback_secret
        if secret is None:
            attempt["error"] = "SCANPLAN_CALLBACK_SECRET is not set; nothing is sent unsigned"
            return attempt
        try:
            target = check_uri(delivery.uri, URI_FIELDS[delivery.event], self.allowed)
        except CallbackRefusedError as exc:
            attempt["error"] = f"refused: {exc}"
            return attempt
        url = httpx.URL(delivery.uri)
        headers = {
            "Host": url.netloc.decode("ascii"), "Content-Type": "application/json",
            SIGNATURE_HEADER: sign(secret.get_secret_value(), delivery.body),
            "X-Scanplan-Event": delivery.event, "X-Scanplan-Delivery": delivery.id,
            "X-Scanplan-Job": delivery.job_id,
        }
        # the TLS name and certificate check stay the URI's host
        extensions = {"sni_hostname": target.host} if url.scheme == "https" else {}
        for ip in target.addresses:
            attempt["address"] = str(ip)
            request = self._client.build_request(
                "POST", url.copy_with(host=str(ip)), content=delivery.body, headers=headers,
                extensions=extensions)
            try:
                # streamed: of the answer only the status and a few bytes of an error are read
                response = self._client.send(request, stream=True)
            except httpx.ConnectError as exc:
                attempt["error"] = f"cannot connect to {ip}: {exc}"
                continue  # the next address the name resolved to
            except httpx.HTTPError as exc:
                attempt["error"] = f"{type(exc).__name__}: {exc}"
                return attempt
            try:
                attempt["status_code"] = response.status_code
                attempt["error"] = None if response.is_success else _response_error(response)
            finally:
                response.close()
            return attempt
        return attempt

    def run_once(self) -> list[Any]:
        """One observation and one round of sends (the futures of the sends started)."""
        self.observe()
        return self.send_due()

    def start(self) -> None:
        """Run :meth:`run_once` every ``callback_poll_interval_s`` in a daemon thread."""
        self._thread = threading.Thread(target=self._loop, name="callbacks", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop polling; wait for the posts under way (each ends within its timeout)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self._pool.shutdown(wait=True)
        self._client.close()

    def _loop(self) -> None:
        purged = 0.0
        while not self._stop.wait(self.settings.callback_poll_interval_s):
            try:
                self.run_once()
                if time.monotonic() - purged > PURGE_INTERVAL_S:
                    self.store.purge_deleted()
                    purged = time.monotonic()
            except Exception:  # the database may be briefly away: try again next time
                log.exception("callback pass failed")


def _response_error(response: httpx.Response) -> str:
    """What a non-2xx answer said: its status and the start of its body."""
    if response.is_redirect:
        return (f"HTTP {response.status_code} redirect to "
                f"{response.headers.get('location', '?')[:200]!r}: redirects are not followed")
    start = b""
    try:
        for chunk in response.iter_raw(ERROR_BYTES):
            start = chunk[:ERROR_BYTES]
            break
    except httpx.HTTPError:
        pass
    text = start.decode("utf-8", "replace").strip()
    return f"HTTP {response.status_code}" + (f": {text}" if text else "")


def check_subscriber(settings: Settings, subscriber: dict[str, Any]) -> dict[str, str | None]:
    """The URIs of an execute request's ``subscriber`` (event -> URI), each checked.

    Raises :class:`CallbackRefusedError` when the service signs nothing (no
    ``SCANPLAN_CALLBACK_SECRET``) or a URI may not be called (:func:`check_uri`).
    """
    if settings.callback_secret is None:
        raise CallbackRefusedError(
            "subscriber", "this service makes no callbacks: its operator has not set "
            "SCANPLAN_CALLBACK_SECRET (the key that signs them); leave subscriber out and "
            "poll GET /jobs/{id}")
    allowed = parse_networks(settings.callback_allow)
    uris: dict[str, str | None] = {}
    for event, name in URI_FIELDS.items():
        uri = subscriber.get(name)
        if uri is not None:
            check_uri(uri, f"subscriber.{name}", allowed)
        uris[event] = uri
    return uris
