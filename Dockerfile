# syntax=docker/dockerfile:1
# glmav-observer: the daemon, the simulator and the Zenoh router in one image.
# How it is built and run (Docker or podman, the podman recipe for hosts without Docker
# Hub access, measured times and size): docs/container.md.
#
#   docker build -t glmav-observer .
#   podman build --format docker --pull=never -t glmav-observer .   # see scripts/container-check.sh
#
# Package index and CA bundle: pip reads its configuration from the optional build secret
# `pipconf` (a pip.conf) and the CA bundle from the optional secret `cacert`; nothing about
# the host's registry is stored in this file or in the image. scripts/container-check.sh
# derives both from the host at build time.

ARG PYTHON_IMAGE=docker.io/library/python:3.11-slim-bookworm

# ---------------------------------------------------------------------------------------
FROM ${PYTHON_IMAGE} AS builder

ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ROOT_USER_ACTION=ignore \
    PYTHONDONTWRITEBYTECODE=1

# The runtime virtualenv (copied whole into the final stage) and a throwaway one that only
# builds the project's wheel (its build backend never reaches the image).
RUN python -m venv /opt/glmav && python -m venv /opt/build

# 1) Dependencies: exactly the pinned runtime closure (binary wheels only: no compiler in
#    the image), and the project's build backend (pyproject: setuptools>=77, Cython) pinned here.
#    Own layer, so that source edits do not re-download ~200 MB of wheels.
COPY constraints.txt /src/constraints.txt
RUN --mount=type=secret,id=pipconf --mount=type=secret,id=cacert \
    export PIP_CONFIG_FILE=/run/secrets/pipconf; \
    if [ -s /run/secrets/cacert ]; then export PIP_CERT=/run/secrets/cacert; fi; \
    /opt/glmav/bin/pip install --only-binary=:all: -r /src/constraints.txt \
    && /opt/build/bin/pip install setuptools==84.2.1 wheel==0.48.0 Cython==3.3.1

# The C compiler for the project's compiled core (setup.py: Cython): this stage only; the
# runtime stage gets the built wheel and has no compiler.
RUN apt-get update \
    && apt-get install -y --no-install-recommends gcc libc6-dev python3-dev \
    && rm -rf /var/lib/apt/lists/*

RUN /opt/glmav/bin/python -m compileall -q /opt/glmav/lib

# 2) The project's wheel (installed in the final stage, so that a source edit rebuilds a
#    small layer instead of copying the whole environment again).
COPY pyproject.toml setup.py MANIFEST.in README.md /src/
COPY service /src/service
COPY sim_bridge /src/sim_bridge
COPY common /src/common
RUN cd /src && /opt/build/bin/pip wheel --no-deps --no-build-isolation --wheel-dir /wheels .

# ---------------------------------------------------------------------------------------
FROM ${PYTHON_IMAGE} AS runtime

LABEL org.opencontainers.image.title="glmav-observer" \
      org.opencontainers.image.description="MAVLink velocity observer for the GLMAV, with SITL, Zenoh and Rerun" \
      org.opencontainers.image.licenses="MIT"

ENV PATH=/opt/glmav/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    GLMAV_CONFIG_DIR=/etc/glmav-observer

# A fixed, unprivileged user; /var/lib/glmav-observer is its writable state (recordings, logs).
RUN groupadd --gid 10001 glmav \
    && useradd --uid 10001 --gid glmav --no-log-init --home-dir /var/lib/glmav-observer \
       --create-home --shell /usr/sbin/nologin glmav

COPY --from=builder /opt/glmav /opt/glmav
# The project, without touching the dependency set; `pip check` fails the build if
# constraints.txt no longer satisfies pyproject.toml. (COPY, not RUN --mount=from=builder:
# buildah's layer cache does not see a change in a mounted stage, COPY's checksum does.)
COPY --from=builder /wheels /tmp/wheels
RUN PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 \
       pip install --no-deps --no-index --no-compile /tmp/wheels/glmav_observer-*.whl \
    && rm -rf /tmp/wheels \
    && pip check \
    && python -m compileall -q /opt/glmav/lib/python3.11/site-packages/glmav_observer \
       /opt/glmav/lib/python3.11/site-packages/glmav_sitl \
    && python -c "import glmav_observer, glmav_sitl"
# Default configuration; compose (or `-v ./configs:/etc/glmav-observer:ro`) mounts the
# site's own over it. The working directory holds a `configs` link so that relative
# default paths (configs/...) resolve too.
COPY configs /etc/glmav-observer
COPY deploy/container/healthcheck.py /opt/glmav/healthcheck.py
RUN ln -s /etc/glmav-observer /var/lib/glmav-observer/configs

USER glmav:glmav
WORKDIR /var/lib/glmav-observer

# Healthy = this container's `glmav-observer serve` holds its Zenoh liveliness token
# glmav/@alive/<service-id>, seen through a Zenoh session opened with GLMAV_HEALTH_ZENOH
# (default /etc/glmav-observer/zenoh/client-router.json5). GLMAV_HEALTH=zenoh checks a router
# instead, GLMAV_HEALTH=off disables it (simulator). See docs/container.md.
HEALTHCHECK --interval=30s --timeout=15s --start-period=30s --retries=3 \
    CMD ["python", "/opt/glmav/healthcheck.py"]

ENTRYPOINT ["glmav-observer"]
# The default command matches compose and the health check: MAVLink on loopback port 14551
# (not the ground station's 14550; serve has no built-in link), published through the
# router of configs/zenoh/client-router.json5 (it exits with a clear error when none answers).
CMD ["serve", "--config", "/etc/glmav-observer/service.toml", \
     "--link", "udpin:127.0.0.1:14551", \
     "--zenoh", "/etc/glmav-observer/zenoh/client-router.json5"]
