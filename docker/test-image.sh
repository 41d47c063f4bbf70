#!/usr/bin/env bash
# Build the image with buildah and run its commands for real (called from .ci/run).
#
# No container registry is reachable on the machines this runs on, so the base is a local
# stand-in for python:3.11-slim made by docker/make-base.sh (debootstrap; cached between
# runs), unless FLOCKLAB_BASE_IMAGE names one. In the image it then runs, as a non-root
# uid writing into a directory that uid owns: the README's batch command, one job of every
# model family (asserting Taichi compiled nothing: the warmed cache served every kernel),
# and a sweep; and, as the image's own user, its default command `flocklab serve` (on
# 127.0.0.1 only) until its health check answers, with one job per model family over HTTP.
# Prints the build time, the image size, the batch run time and each first-job time.
#
# Needs root (buildah with chroot isolation); installs buildah and debootstrap with apt
# when missing. Settings: FLOCKLAB_BASE_IMAGE, FLOCKLAB_TEST_IMAGE (the tag built, default
# localhost/flocklab:test), FLOCKLAB_TEST_PORT (default 18731), FLOCKLAB_IMAGE_CACHE.
set -euo pipefail
cd "$(dirname "$0")/.."
image="${FLOCKLAB_TEST_IMAGE:-localhost/flocklab:test}"
port="${FLOCKLAB_TEST_PORT:-18731}"
uid=12345  # a non-root uid the image knows nothing of, as `--user "$(id -u):$(id -g)"`
say() { echo "test-image: $*"; }
fail() { echo "test-image: FAILED: $*" >&2; exit 1; }
elapsed() { awk -v a="$1" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }'; }

[[ "$(id -u)" == 0 ]] || fail "needs root (buildah bud/run --isolation chroot)"
missing=()
command -v buildah >/dev/null || missing+=(buildah)
command -v debootstrap >/dev/null || missing+=(debootstrap)
if ((${#missing[@]})); then
    say "installing ${missing[*]} (apt)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}"
fi

base="${FLOCKLAB_BASE_IMAGE:-}"
if [[ -z "$base" ]]; then
    base=localhost/python:3.11-slim
    if buildah inspect --type image "$base" >/dev/null 2>&1; then
        say "base $base: the debootstrap stand-in for python:3.11-slim made earlier" \
            "by docker/make-base.sh (no registry is reachable here)"
    else
        docker/make-base.sh "$base"
    fi
fi

work="$(mktemp -d /tmp/flocklab-image-test.XXXXXX)"
ctr="" serve_pid=""
cleanup() {
    [[ -n "$serve_pid" ]] && kill "$serve_pid" 2>/dev/null || true
    [[ -n "$ctr" ]] && buildah rm "$ctr" >/dev/null 2>&1 || true
    rm -rf "$work"
}
trap cleanup EXIT

say "building $image from $base"
t0="$(date +%s.%N)"
buildah bud --isolation chroot --format docker --layers --build-arg BASE_IMAGE="$base" \
    -t "$image" . >"$work/build.log" 2>&1 || { tail -40 "$work/build.log"; fail "build"; }
build_s="$(elapsed "$t0")"
reused="$(grep -c '^--> Using cache' "$work/build.log" || true)"
size="$(buildah images --format '{{.Size}}' "$image" | head -1)"
grep '^warm: .* scenarios' "$work/build.log" || true
say "build ${build_s} s (${reused} steps from the layer cache), image size ${size}"

ctr="$(buildah from "$image")"
mkdir -p "$work/out"
chown "$uid:$uid" "$work/out"
as_user() {  # a command in the image as uid:uid, /out being the user-owned directory
    buildah run --isolation chroot --user "$uid:$uid" --volume "$work/out:/out" "$ctr" -- "$@"
}
# Kernels in the container's Taichi cache (one .tic file each), counted from the host.
cache_dir="$(buildah mount "$ctr")/cache/taichi"
[[ -d "$cache_dir" ]] || fail "the image has no /cache/taichi"
kernels() { find "$cache_dir" -name '*.tic' | wc -l; }
cached="$(kernels)"
say "warmed cache: $cached kernels"

# The README's batch command, as a user into that user's directory.
t0="$(date +%s.%N)"
as_user flocklab run examples/vicsek.json --out /out/vicsek --quiet >"$work/batch.log" 2>&1 \
    || { cat "$work/batch.log"; fail "batch command"; }
batch_s="$(elapsed "$t0")"
[[ "$(stat -c %u "$work/out/vicsek/summary.json")" == "$uid" ]] \
    || fail "the batch output is not owned by uid $uid"
if grep -iE 'warn|\[W ' "$work/batch.log"; then fail "the batch command printed warnings"; fi
say "batch: flocklab run examples/vicsek.json --out /out/vicsek as uid $uid: ${batch_s} s"

# One job of every model family, each a fresh process: nothing may compile.
declare -A first
for entry in vicsek:vicsek-1995 flocking:tjp-fixed flocking:tjp-switching \
             flocking_obstacles:tanner-obstacles formation-F1:xi-abed-sim1 \
             formation-F2:xi-abed-sim3; do
    family="${entry%%:*}" preset="${entry#*:}"
    t0="$(date +%s.%N)"
    as_user flocklab run "preset:$preset" --set time.steps=200 --out "/out/first-$preset" \
        --quiet >"$work/first.log" 2>&1 || { cat "$work/first.log"; fail "job $preset"; }
    s="$(elapsed "$t0")"
    now="$(kernels)"
    ((now == cached)) || fail "$preset compiled $((now - cached)) kernels on first use"
    first["$family/$preset"]="$s"
    say "first job $family ($preset, 200 steps, whole process): ${s} s, 0 kernels compiled"
done

# A sweep (80 fused runs), as the user.
t0="$(date +%s.%N)"
as_user flocklab sweep examples/sweep-fig2a-reduced.json --out /out/sweep --quiet \
    >"$work/sweep.log" 2>&1 || { cat "$work/sweep.log"; fail "sweep"; }
sweep_s="$(elapsed "$t0")"
rows="$(($(wc -l <"$work/out/sweep/table.csv") - 1))"
((rows == 20)) || fail "the sweep's table.csv has $rows rows, not 20"
(($(kernels) == cached)) || fail "the sweep compiled kernels"
say "sweep examples/sweep-fig2a-reduced.json: ${sweep_s} s, table.csv $rows rows"

# The image's default command as its own user, on loopback, until the health check answers.
config() {  # a list from the image's Docker config, one item a line (from item $2 on)
    buildah inspect --type image "$image" | python3 -c 'import json, sys
print("\n".join(json.load(sys.stdin)["Docker"]["config"]'"$1"'['"$2"':]))'
}
mapfile -t cmd < <(config '["Cmd"]' 0)
mapfile -t health < <(config '["Healthcheck"]["Test"]' 1)
((${#health[@]})) || fail "the image has no health check"
t0="$(date +%s.%N)"
buildah run --isolation chroot --env FLOCKLAB_HOST=127.0.0.1 --env FLOCKLAB_PORT="$port" \
    "$ctr" -- sh -c 'echo $$ >/tmp/serve.pid; exec "$@"' sh "${cmd[@]}" \
    >"$work/serve.log" 2>&1 &
for _ in $(seq 120); do
    if buildah run --isolation chroot --env FLOCKLAB_PORT="$port" "$ctr" -- "${health[@]}" \
        >/dev/null 2>&1; then healthy=1; break; fi
    sleep 1
done
serve_pid="$(buildah run --isolation chroot "$ctr" -- cat /tmp/serve.pid)"
[[ -n "${healthy:-}" ]] || { cat "$work/serve.log"; fail "the health check never answered"; }
say "serve: health check answered after $(elapsed "$t0") s (127.0.0.1:$port)"
buildah copy "$ctr" docker/image_jobs.py /tmp/image_jobs.py >/dev/null
buildah run --isolation chroot "$ctr" -- python /tmp/image_jobs.py "http://127.0.0.1:$port" \
    | tee "$work/jobs.log" || { cat "$work/serve.log"; fail "service jobs"; }
kill -TERM "$serve_pid"
wait || true
serve_pid=""
(($(kernels) == cached)) || fail "the service compiled kernels"
say "serve: stopped; 0 kernels compiled by its workers"

say "SUMMARY build_s=$build_s image_size='$size' batch_s=$batch_s sweep_s=$sweep_s"
for k in "${!first[@]}"; do say "SUMMARY first_job_s[$k]=${first[$k]}"; done
say "passed"
