# scanplan: the API and its worker processes on the embedded default (SQLite + /data).
# Scale-out (Redis queue, PostgreSQL job table): see compose.yaml, profile "scale".
FROM python:3.11-slim

# numba's cache of the planner's compiled kernels is made when the image is built (below);
# site-packages is read-only for the service user, who has no home: matplotlib's config,
# ezdxf's and the examples' caches go to /tmp
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    SCANPLAN_DATA_DIR=/data \
    NUMBA_CACHE_DIR=/var/cache/scanplan/numba \
    MPLCONFIGDIR=/tmp/matplotlib \
    XDG_CACHE_HOME=/tmp/cache

WORKDIR /app
COPY pyproject.toml README.md ./
COPY planner ./planner
COPY service ./service
# the project itself with its Dask extra (the compose dask services run this image); its
# dependencies and their versions are those of pyproject.toml, not of this line
# The kernels are compiled here, for x86-64-v3 (planner.kernels), so that no container's
# first plan compiles them (IfcOpenHouse: 34 s instead of 4 s on 2 cores): the cache serves
# every x86-64-v3 machine the image runs on. The service user may add to it.
# hadolint ignore=DL3013
RUN pip install --no-cache-dir ".[dask]" \
    && scanplan compile-kernels \
    && rm -rf /tmp/* \
    && groupadd --gid 10001 scanplan \
    && useradd --uid 10001 --gid 10001 --no-create-home --shell /usr/sbin/nologin scanplan \
    && mkdir -p /data \
    && chown 10001:10001 /data \
    && chown -R 10001:10001 /var/cache/scanplan

USER 10001:10001
VOLUME ["/data"]
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"]

# Without SCANPLAN_API_KEYS the service binds to loopback only (unreachable from outside).
CMD ["scanplan", "serve", "--host", "0.0.0.0", "--data-dir", "/data"]
