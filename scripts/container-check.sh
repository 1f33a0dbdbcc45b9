#!/usr/bin/env bash
# Build the glmav-observer image with podman and run the compose stack (compose.yaml:
# Zenoh router, simulator, observer) on the host network, loopback only; pass when the
# observer's estimates arrive over Zenoh in a subscriber running in the image, and the
# image's health checks report healthy. Documented in docs/container.md (the podman recipe,
# measured times, image size).
#
# Steps: (0) host tools (apt-get install podman buildah runc debootstrap ... when missing;
#        podman-compose, pinned, in a throwaway venv: Debian's 1.0.3 cannot do host networking),
#        (1) the stand-in base image (scripts/build-base-image.sh; skipped when present),
#        (2) `podman build` of ./Dockerfile against it with --pull=never,
#        (3) image checks: non-root user, entrypoint, HEALTHCHECK, installed = constraints.txt,
#        (4) the stack with podman-compose, (5) what arrives over Zenoh, (6) health checks.
#
# Usage: sudo scripts/container-check.sh [--build-only] [--keep]
#   --build-only   stop after step 3
#   --keep         leave the stack running at the end (podman-compose -p glmav-check down)
# Environment: GLMAV_IMAGE (default localhost/glmav-observer:latest, as compose.yaml), GLMAV_CHECK_DIR (logs;
#   default a new /tmp dir), GLMAV_CHECK_SECONDS (simulated seconds, default 40),
#   GLMAV_TOOLS_DIR (podman-compose venv, default /var/tmp/glmav-tools)
#
# The package index and CA bundle the build uses are read from this host at run time (pip
# config, PIP_* environment, SSL_CERT_FILE...) and handed to the build as secrets; nothing
# about them is stored in the repository or in the image.
set -euo pipefail
cd "$(dirname "$0")/.."

IMAGE="${GLMAV_IMAGE:-localhost/glmav-observer:latest}"  # the tag compose and the docs run
BASE_TAG=docker.io/library/python:3.11-slim-bookworm
PROJECT=glmav-check
SIM_SECONDS="${GLMAV_CHECK_SECONDS:-40}"
PODMAN_COMPOSE_VERSION=1.6.0
# What the subscriber waits for and asserts (reasons in docs/container.md, "The check"):
WINDOW_S=10      # vehicle-time span of velocity/active samples to collect
SETTLE_S=5       # vehicle seconds after the first sample before the accuracy window
ERR_MAX_MPS=0.3  # RMS |v_active - v_truth| (NED) bound over the window
BUILD_ONLY=0
KEEP=0
for arg in "$@"; do
    case "$arg" in
        --build-only) BUILD_ONLY=1 ;;
        --keep) KEEP=1 ;;
        -h | --help)
            sed -n '2,24p' "$0"
            exit 0
            ;;
        *)
            echo "container-check: unknown argument: $arg" >&2
            exit 2
            ;;
    esac
done

T0=$(date +%s)
log() { printf '[container-check %4ds] %s\n' "$(($(date +%s) - T0))" "$*" >&2; }
fail() {
    printf '[container-check] FAIL: %s\n' "$*" >&2
    exit 1
}

WORK="${GLMAV_CHECK_DIR:-$(mktemp -d /tmp/glmav-container-check.XXXXXX)}"
mkdir -p "$WORK"

# podman settings for a nested, systemd-less host (every podman call of this script and of
# podman-compose reads them): runc, cgroupfs, file events, and rlimits that runc may set
# (it cannot raise a container's rlimits above what this host allows). Shipped in the
# repository so that users' own podman commands can use the same file (docs/container.md).
cp deploy/container/containers.conf "$WORK/containers.conf"
export CONTAINERS_CONF="$WORK/containers.conf"

STACK_UP=0
COMPOSE=()
cleanup() {
    local rc=$?
    if [[ $STACK_UP -eq 1 ]]; then
        for service in zenoh-router observer sitl; do
            "${COMPOSE[@]}" logs "$service" >"$WORK/$service.log" 2>&1 || true
        done
        if [[ $KEEP -eq 0 ]]; then
            "${COMPOSE[@]}" down -t 5 >>"$WORK/compose.log" 2>&1 || true
        fi
    fi
    rm -f "$WORK/pip.conf" "$WORK/ca.crt"
    if [[ $rc -ne 0 ]]; then
        echo "[container-check] logs in $WORK" >&2
    fi
    exit "$rc"
}
trap cleanup EXIT

# ---- 0. host tools ----------------------------------------------------------------------
need=()
for tool in podman buildah runc debootstrap python3; do
    command -v "$tool" >/dev/null || need+=("$tool")
done
python3 -c 'import venv, ensurepip' 2>/dev/null || need+=(python3-venv)
if [[ ${#need[@]} -gt 0 ]]; then
    [[ $(id -u) -eq 0 ]] || fail "missing ${need[*]}: apt-get install podman buildah runc debootstrap python3-venv"
    log "installing ${need[*]} (apt-get)"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq podman buildah runc debootstrap \
        python3 python3-venv >"$WORK/apt.log" 2>&1 || fail "apt-get install (see $WORK/apt.log)"
fi

ensure_podman_compose() {
    local dir="${GLMAV_TOOLS_DIR:-/var/tmp/glmav-tools}/podman-compose-$PODMAN_COMPOSE_VERSION"
    if [[ ! -x $dir/bin/podman-compose ]]; then
        log "installing podman-compose==$PODMAN_COMPOSE_VERSION into $dir"
        rm -rf "$dir"
        python3 -m venv "$dir"
        "$dir/bin/pip" install --quiet "podman-compose==$PODMAN_COMPOSE_VERSION" \
            >"$WORK/pip-podman-compose.log" 2>&1 || fail "pip install podman-compose (see $WORK)"
    fi
    PODMAN_COMPOSE=("$dir/bin/podman-compose")
}

free_port() { # tcp|udp: a free loopback port
    python3 -c '
import socket, sys
kind = socket.SOCK_STREAM if sys.argv[1] == "tcp" else socket.SOCK_DGRAM
with socket.socket(socket.AF_INET, kind) as s:
    s.bind(("127.0.0.1", 0))
    print(s.getsockname()[1])
' "$1"
}
tcp_open() { python3 -c 'import socket, sys; socket.create_connection(("127.0.0.1", int(sys.argv[1])), 1).close()' "$1" 2>/dev/null; }
wait_for() { # WHAT SECONDS COMMAND...: poll COMMAND until it succeeds or the deadline
    local what=$1 seconds=$2
    shift 2
    local deadline=$(($(date +%s) + seconds))
    until "$@"; do
        [[ $(date +%s) -lt $deadline ]] || fail "timed out after ${seconds}s waiting for $what"
        sleep 0.5
    done
}

# --no-healthcheck: podman schedules health checks with systemd timers, absent here; this
# script runs them itself (`podman healthcheck run`, step 6).
run_in_image() { podman run --rm --pull=never --no-healthcheck "$@"; }

T_BASE="" T_BUILD="" T_STACK="" SIZE_BYTES=0
summary() {
    printf 'container-check: PASS; base image %ss, app image build %ss, stack %ss, total %ss; image %s MB\n' \
        "$T_BASE" "$T_BUILD" "${T_STACK:-n/a }" "$(($(date +%s) - T0))" "$((SIZE_BYTES / 1000000))"
}

# ---- 1. the base image ------------------------------------------------------------------
t=$(date +%s)
scripts/build-base-image.sh
T_BASE=$(($(date +%s) - t))

# ---- 2. the app image -------------------------------------------------------------------
# pip configuration for the build, derived from this host: the index URLs pip would use here
# (pip config files and PIP_* environment), keeping only network indexes (a file:// or
# local path on the host does not exist inside the build), and the CA bundle.
host_pip_conf() {
    local pip_cmd=()
    if command -v pip3 >/dev/null; then
        pip_cmd=(pip3)
    elif python3 -m pip --version >/dev/null 2>&1; then
        pip_cmd=(python3 -m pip)
    fi
    {
        if [[ ${#pip_cmd[@]} -gt 0 ]]; then "${pip_cmd[@]}" config list 2>/dev/null || true; fi
        env | grep -E '^PIP_(INDEX_URL|EXTRA_INDEX_URL|TRUSTED_HOST|DEFAULT_TIMEOUT|TIMEOUT)=' |
            sed -E 's/^PIP_([A-Z_]+)=(.*)$/:env:.\1=\2/' || true
    } | python3 -c '
import sys
values = {}
for line in sys.stdin:
    key, _, value = line.strip().partition("=")
    name = key.rpartition(".")[2].lower().replace("_", "-")
    value = value.strip().strip("\x27\"")
    if name == "default-timeout":
        name = "timeout"
    if name in ("index-url", "extra-index-url", "trusted-host", "timeout") and value:
        values[name] = value  # later lines (environment) override files, as in pip
def keep(url):
    return url.startswith(("http://", "https://"))
print("[global]")
if keep(values.get("index-url", "")):
    print("index-url =", values["index-url"])
extra = [u for u in values.get("extra-index-url", "").split() if keep(u)]
if extra:
    print("extra-index-url =", " ".join(extra))
for name in ("trusted-host", "timeout"):
    if name in values:
        print(name, "=", values[name])
'
}
host_ca_bundle() {
    local f
    for f in "${PIP_CERT:-}" "${REQUESTS_CA_BUNDLE:-}" "${SSL_CERT_FILE:-}" \
        /etc/ssl/certs/ca-certificates.crt /etc/pki/tls/certs/ca-bundle.crt; do
        if [[ -n $f && -r $f ]]; then
            echo "$f"
            return
        fi
    done
}
(
    umask 077
    host_pip_conf >"$WORK/pip.conf"
    ca="$(host_ca_bundle)"
    if [[ -n $ca ]]; then cp "$ca" "$WORK/ca.crt"; else : >"$WORK/ca.crt"; fi
)

log "building $IMAGE (log: $WORK/build.log)"
previous_id="$(podman image inspect --format '{{.Id}}' "$IMAGE" 2>/dev/null || true)"
t=$(date +%s)
# --format docker: the OCI image format has no HEALTHCHECK; --network host: the build's pip
# reaches the index like the host does; --pull=never: use the local base image.
if ! podman build --format docker --pull=never --network host \
    --secret id=pipconf,src="$WORK/pip.conf" --secret id=cacert,src="$WORK/ca.crt" \
    --build-arg PYTHON_IMAGE="$BASE_TAG" -t "$IMAGE" -f Dockerfile . >"$WORK/build.log" 2>&1; then
    tail -n 40 "$WORK/build.log" >&2
    fail "podman build"
fi
T_BUILD=$(($(date +%s) - t))
# The image this tag named before, now untagged: remove it (its layers stay as build cache
# while the new image shares them).
if [[ -n $previous_id && $previous_id != "$(podman image inspect --format '{{.Id}}' "$IMAGE")" ]]; then
    podman rmi "$previous_id" >/dev/null 2>&1 || true
fi
SIZE_BYTES=$(podman image inspect --format '{{.Size}}' "$IMAGE")
log "image built in ${T_BUILD}s, size $((SIZE_BYTES / 1000000)) MB"

# ---- 3. image checks -------------------------------------------------------------------
user="$(run_in_image --network none --entrypoint id "$IMAGE" -u)"
[[ $user != 0 ]] || fail "the image runs as root"
entry="$(podman image inspect --format '{{json .Config.Entrypoint}}' "$IMAGE")"
[[ $entry == '["glmav-observer"]' ]] || fail "entrypoint is $entry, expected [\"glmav-observer\"]"
health="$(podman image inspect --format '{{json .Config.Healthcheck}}' "$IMAGE")"
[[ $health == *healthcheck.py* ]] || fail "no HEALTHCHECK in the image config ($health)"
run_in_image --network none "$IMAGE" --help >/dev/null || fail "glmav-observer --help"
run_in_image --network none --entrypoint glmav-sitl "$IMAGE" --help >/dev/null ||
    fail "glmav-sitl --help"
# The installed distributions are exactly the pinned ones (plus the project itself).
# Names normalised as in PEP 503 (typing_extensions = typing-extensions).
normalise() { sed -E -e '/^[A-Za-z0-9]/!d' -e ':a' -e 's/^([^=]*)[_.]/\1-/' -e 'ta' | tr '[:upper:]' '[:lower:]' | sort; }
run_in_image --network none --entrypoint pip "$IMAGE" freeze --exclude glmav-observer \
    2>/dev/null | normalise >"$WORK/freeze.txt"
normalise <constraints.txt | diff -u - "$WORK/freeze.txt" >&2 ||
    fail "installed packages differ from constraints.txt"
log "image checks passed (uid $user, entrypoint $entry, $(wc -l <"$WORK/freeze.txt") pinned distributions)"

if [[ $BUILD_ONLY -eq 1 ]]; then
    summary
    exit 0
fi

# ---- 4. the stack (compose.yaml, host network, loopback only) ---------------------------
ensure_podman_compose
ZPORT="$(free_port tcp)"
MPORT="$(free_port udp)"
# The mounted configs/: the repository's, with the observer's Zenoh client config pointed at
# this run's router port.
CFG="$WORK/configs"
rm -rf "$CFG"
cp -r configs "$CFG"
mkdir -p "$CFG/zenoh"
printf '// written by scripts/container-check.sh: a client of this run'"'"'s router, loopback only
{
  mode: "client",
  connect: { endpoints: ["tcp/127.0.0.1:%s"] },
  scouting: { multicast: { enabled: false } },
}
' "$ZPORT" >"$CFG/zenoh/client-router.json5"
chmod -R a+rX "$CFG"
export GLMAV_IMAGE="$IMAGE" GLMAV_CONFIG_DIR="$CFG" \
    GLMAV_ZENOH_LISTEN="tcp/127.0.0.1:$ZPORT" \
    GLMAV_ZENOH_CONFIG=/etc/glmav-observer/zenoh/client-router.json5 \
    GLMAV_LINK="udpin:127.0.0.1:$MPORT" GLMAV_SITL_LINK="udpout:127.0.0.1:$MPORT" \
    GLMAV_SCENARIO=hover GLMAV_SIM_SECONDS="$SIM_SECONDS" GLMAV_RERUN=off
COMPOSE=("${PODMAN_COMPOSE[@]}" --in-pod false -p "$PROJECT" -f compose.yaml)
"${COMPOSE[@]}" down -t 2 >/dev/null 2>&1 || true # leftovers of an earlier --keep run
STACK_UP=1

t=$(date +%s)
log "stack: router tcp/127.0.0.1:$ZPORT, MAVLink udp 127.0.0.1:$MPORT, hover ${SIM_SECONDS}s"
"${COMPOSE[@]}" up -d zenoh-router >>"$WORK/compose.log" 2>&1 || fail "compose up zenoh-router"
wait_for "the router on tcp/127.0.0.1:$ZPORT" 60 tcp_open "$ZPORT"
"${COMPOSE[@]}" up -d --no-deps observer >>"$WORK/compose.log" 2>&1 || fail "compose up observer"
"${COMPOSE[@]}" up -d --no-deps sitl >>"$WORK/compose.log" 2>&1 || fail "compose up sitl"

# ---- 5. estimates over Zenoh, seen by a subscriber in the image ------------------------
# A small subscriber of its own (not `glmav-observer echo`) so that the check states its
# assertions in one place; it prints one JSON object: metrics and failures.
read -r -d '' SUBSCRIBER <<'PY' || true
import bisect, json, math, os, sys, threading, time
import zenoh

deadline_s = float(os.environ["SUB_DEADLINE_S"])
window_s = float(os.environ["SUB_WINDOW_S"])
settle_s = float(os.environ["SUB_SETTLE_S"])
err_max = float(os.environ["SUB_ERR_MAX_MPS"])
active_hz = float(os.environ["SUB_ACTIVE_HZ"])
health_hz = float(os.environ["SUB_HEALTH_HZ"])
P = "glmav/1/"
lock = threading.Lock()
got: dict = {}
bad: list = []

def on_sample(sample):
    key = str(sample.key_expr)
    try:
        d = json.loads(sample.payload.to_bytes())
    except ValueError as exc:
        bad.append(f"{key}: payload is not JSON ({exc})")
        return
    with lock:
        got.setdefault(key, []).append((d, str(sample.encoding)))

def span(key):
    xs = got.get(key, [])
    return xs[-1][0]["t_boot_s"] - xs[0][0]["t_boot_s"] if len(xs) > 1 else 0.0

session = zenoh.open(zenoh.Config.from_file(os.environ["SUB_ZENOH"]))
sub = session.declare_subscriber("glmav/**", on_sample)
t0 = time.monotonic()
while time.monotonic() - t0 < deadline_s:
    with lock:
        if span(P + "velocity/active") >= settle_s + window_s:
            break
    time.sleep(0.2)
sub.undeclare()
alive = [str(r.ok.key_expr) for r in session.liveliness().get("glmav/@alive/**", timeout=5.0) if r.ok]
state = [json.loads(r.ok.payload.to_bytes()) for r in session.get("glmav/*/state", timeout=5.0) if r.ok]
session.close()

fails = list(bad)
metrics = {"keys": len(got)}
for name in ("full", "c1", "c2", "c3", "active"):
    key = P + "velocity/" + name
    xs = got.get(key, [])
    if len(xs) < 2:
        fails.append(f"{key}: {len(xs)} samples")
        continue
    for d, enc in xs:
        if d.get("schema") != "glmav.velocity/1" or d.get("sysid") != 1 or not enc.startswith("application/json"):
            fails.append(f"{key}: bad sample {d} ({enc})")
            break
        if not all(math.isfinite(x) for x in d["v_body_mps"] + d["v_ned_mps"]):
            fails.append(f"{key}: non-finite velocity {d}")
            break
    t = [d["t_boot_s"] for d, _ in xs]
    if any(b <= a for a, b in zip(t, t[1:])):
        fails.append(f"{key}: t_boot_s not strictly increasing")
    metrics[f"{name}_hz"] = round((len(xs) - 1) / (t[-1] - t[0]), 1)
# The active estimate keeps at least half its configured rate: on loopback nothing is
# lost in transit, only Zenoh's congestion control DROP sheds samples under CPU load (a
# few % measured on 2 cores); half catches a wrong IMU stream or decimation (ATTITUDE-
# driven updates would give 100/250 = 40 %).
if metrics.get("active_hz", 0.0) < 0.5 * active_hz:
    fails.append(f"active at {metrics.get('active_hz')} Hz < half of {active_hz} Hz")
health = got.get(P + "health", [])
if len(health) < 2 or any(d.get("schema") != "glmav.health/1" for d, _ in health):
    fails.append(f"{P}health: {len(health)} samples or wrong schema")
else:
    th = [d["t_boot_s"] for d, _ in health]
    metrics["health_hz"] = round((len(th) - 1) / (th[-1] - th[0]), 1)
    # design.md: health at 10 Hz of vehicle time; +-20 % covers the sample-to-grid
    # quantisation of a 10 s window (one sample in 100 is 1 %) with a wide margin.
    if abs(metrics["health_hz"] - health_hz) > 0.2 * health_hz:
        fails.append(f"health rate {metrics['health_hz']} Hz, expected {health_hz} Hz +-20 %")
# Accuracy against the simulator's truth (SIM_STATE, republished on .../truth), over the
# window after the observer settled: RMS of |v_active - v_truth| (NED), truth matched to
# the nearest vehicle time within 25 ms (SIM_STATE runs at 50 Hz: 20 ms apart).
truth = got.get(P + "truth", [])
active = got.get(P + "velocity/active", [])
if len(truth) < 10 or len(active) < 10:
    fails.append(f"truth {len(truth)} / active {len(active)} samples: cannot compare")
else:
    tt = [d["t_boot_s"] for d, _ in truth]
    t_start = active[0][0]["t_boot_s"] + settle_s
    sq, n = 0.0, 0
    for d, _ in active:
        if d["t_boot_s"] < t_start:
            continue
        i = bisect.bisect_left(tt, d["t_boot_s"])
        j = min((k for k in (i - 1, i) if 0 <= k < len(tt)), key=lambda k: abs(tt[k] - d["t_boot_s"]))
        if abs(tt[j] - d["t_boot_s"]) > 0.025:
            continue
        sq += sum((a - b) ** 2 for a, b in zip(d["v_ned_mps"], truth[j][0]["v_ned_mps"]))
        n += 1
    metrics["compared"] = n
    metrics["rms_err_mps"] = round(math.sqrt(sq / n), 4) if n else None
    if n < 100:
        fails.append(f"only {n} active samples matched to truth")
    elif metrics["rms_err_mps"] > err_max:
        fails.append(f"RMS error {metrics['rms_err_mps']} m/s > {err_max} m/s")
metrics["alive"] = len(alive)
if not any(k.startswith("glmav/@alive/") for k in alive):
    fails.append("no liveliness token under glmav/@alive/")
metrics["state_replies"] = len(state)
if not any(s.get("sysid") == 1 for s in state if isinstance(s, dict)):
    fails.append(f"state query: no reply for sysid 1 ({state!r:.200})")
print(json.dumps({"metrics": metrics, "failures": fails, "keys": sorted(got), "alive": sorted(alive)}))
sys.exit(1 if fails else 0)
PY

# The rates to expect: the simulator's best IMU stream (its packaged sitl.toml, the one
# copy since the configuration moved into the simulator's package; the image holds the same
# file) capped by the service's Zenoh rate of each stream ([zenoh.rates], "every" = no cap)
# over its decimation; health at the estimator's rate, capped the same way.
read -r ACTIVE_HZ HEALTH_HZ < <(python3 -c '
import sys, tomllib
sitl = tomllib.load(open(sys.argv[2], "rb"))
svc = tomllib.load(open(sys.argv[1] + "/service.toml", "rb"))
zen = svc.get("zenoh", {})
dec, rates = zen.get("decimation", {}), zen.get("rates", {})
def cap(hz, stream):
    r = rates.get(stream, "every")
    return hz if r == "every" or zen.get("full_rate", False) else min(hz, float(r))
imu = max(sitl["rates_hz"].get(m, 0.0) for m in ("highres_imu", "scaled_imu", "raw_imu"))
health = svc.get("estimation", {}).get("health_rate_hz", 10.0)
print(cap(imu, "active") / dec.get("active", 1), cap(health, "health") / dec.get("health", 1))' \
    "$CFG" sim_bridge/glmav_sitl/data/sitl.toml)
log "subscribing to glmav/** (window ${SETTLE_S}+${WINDOW_S}s of vehicle time; expecting active ${ACTIVE_HZ} Hz, health ${HEALTH_HZ} Hz)"
if ! run_in_image --network host -v "$CFG:/etc/glmav-observer:ro" \
    -e SUB_ZENOH=/etc/glmav-observer/zenoh/client-router.json5 \
    -e SUB_DEADLINE_S="$((SIM_SECONDS + 30))" -e SUB_WINDOW_S="$WINDOW_S" \
    -e SUB_SETTLE_S="$SETTLE_S" -e SUB_ERR_MAX_MPS="$ERR_MAX_MPS" \
    -e SUB_ACTIVE_HZ="$ACTIVE_HZ" -e SUB_HEALTH_HZ="$HEALTH_HZ" \
    --entrypoint python "$IMAGE" -c "$SUBSCRIBER" >"$WORK/subscriber.json" 2>"$WORK/subscriber.err"; then
    cat "$WORK/subscriber.json" "$WORK/subscriber.err" >&2
    fail "estimates over Zenoh (subscriber output above)"
fi
log "over Zenoh: $(python3 -c 'import json, sys; m = json.load(open(sys.argv[1]))["metrics"]; print(", ".join(f"{k}={v}" for k, v in m.items()))' "$WORK/subscriber.json")"

# The project's own `echo`, validating every payload against its schema.
if ! run_in_image --network host -v "$CFG:/etc/glmav-observer:ro" "$IMAGE" \
    echo 'glmav/1/**' --format jsonl --validate --count 500 --duration 20 \
    --zenoh /etc/glmav-observer/zenoh/client-router.json5 >"$WORK/echo.jsonl" 2>"$WORK/echo.err"; then
    tail -n 20 "$WORK/echo.err" >&2
    fail "glmav-observer echo --validate"
fi
n_echo=$(wc -l <"$WORK/echo.jsonl")
[[ $n_echo -eq 500 ]] || fail "glmav-observer echo --count 500 printed $n_echo samples"
log "glmav-observer echo --validate: $n_echo samples, all valid"

# ---- 6. the image's health checks ------------------------------------------------------
container_of() {
    podman ps -q --filter "label=com.docker.compose.project=$PROJECT" \
        --filter "label=com.docker.compose.service=$1"
}
for service in observer zenoh-router; do
    cid="$(container_of "$service")"
    [[ -n $cid ]] || fail "no running $service container"
    if ! out="$(podman healthcheck run "$cid" 2>&1)"; then
        fail "health check of $service: $out"
    fi
    log "health check of $service: ${out:-healthy}"
done
# ... and it can fail: once the observer stops (SIGTERM), its token is gone and the same
# probe, run from the router's container for that service id, reports unhealthy.
service_id="$(python3 -c '
import json, sys
alive = json.load(open(sys.argv[1]))["alive"]
print(next(k.split("/")[2] for k in alive if k.count("/") == 2))' "$WORK/subscriber.json")"
"${COMPOSE[@]}" stop -t 10 observer >>"$WORK/compose.log" 2>&1 || fail "compose stop observer"
if out="$(podman exec -e GLMAV_HEALTH=observer -e GLMAV_SERVICE_ID="$service_id" \
    -e GLMAV_HEALTH_ZENOH=/etc/glmav-observer/zenoh/client-router.json5 \
    "$(container_of zenoh-router)" python /opt/glmav/healthcheck.py 2>&1)"; then
    fail "the observer stopped but the health probe still says: $out"
fi
log "observer stopped -> probe for '$service_id': ${out}"
if [[ $KEEP -eq 1 ]]; then
    "${COMPOSE[@]}" start observer >>"$WORK/compose.log" 2>&1 || fail "compose start observer"
fi
T_STACK=$(($(date +%s) - t))

summary
