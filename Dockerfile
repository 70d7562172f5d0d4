# scanplan: the API and its worker processes on the embedded default (SQLite + /data).
# Scale-out (Redis queue, PostgreSQL job table): see compose.yaml, profile "scale".
FROM python:3.11-slim

# numba caches the compiled limits kernel; site-packages is read-only for the service user,
# who has no home: matplotlib's config, ezdxf's and the examples' caches go to /tmp
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    SCANPLAN_DATA_DIR=/data \
    NUMBA_CACHE_DIR=/tmp/numba-cache \
    MPLCONFIGDIR=/tmp/matplotlib \
    XDG_CACHE_HOME=/tmp/cache

WORKDIR /app
COPY pyproject.toml README.md ./
COPY planner ./planner
COPY service ./service
# the project itself with its Dask extra (the compose dask services run this image); its
# dependencies and their versions are those of pyproject.toml, not of this line
# hadolint ignore=DL3013
RUN pip install --no-cache-dir ".[dask]" \
    && groupadd --gid 10001 scanplan \
    && useradd --uid 10001 --gid 10001 --no-create-home --shell /usr/sbin/nologin scanplan \
    && mkdir -p /data \
    && chown 10001:10001 /data

USER 10001:10001
VOLUME ["/data"]
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"]

# Without SCANPLAN_API_KEYS the service binds to loopback only (unreachable from outside).
CMD ["scanplan", "serve", "--host", "0.0.0.0", "--data-dir", "/data"]
