#!/usr/bin/env bash
# The GPU path, verified where a GPU exists (issue 12): one script, one log.
#
#   bench/gpu_check.sh                 # on a machine with an NVIDIA GPU, project installed
#   bench/gpu_check.sh --dry-run       # print the plan and check the prerequisites only
#   bench/gpu_check.sh --smoke         # the same steps on the CPU at tiny sizes: checks
#                                      # this script itself on a machine without a GPU
#   options: --log FILE (default bench/gpu_check-<UTC time>.log), --backend cuda|vulkan
#
# Steps (each bounded by a timeout; a failing step is recorded and the next one runs):
#   1. the engine tests on the GPU: grid = brute force, every model against its reference
#      at small N (the CPU tests, with every "cpu" runtime request sent to the GPU by a
#      small pytest plugin written below), and same seed -> same trajectory run to run
#      (tests/schemas/test_schemas.py joins every backend it finds);
#   2. statistical agreement of GPU and CPU runs where the bits differ: every preset
#      family at small N over several seeds, mean final observables compared;
#   3. one job of each model through `flocklab serve` with backend cuda and auto: each
#      must succeed and report the GPU as its backend;
#   4. python -m bench.bench --backend cuda --sizes 1000000 10000000, and a table next to
#      FLAME GPU 2's published 4.7e8 agent-steps/s at 10^6 agents on an H100;
#   5. the batched schedule (Vicsek: every replica's agents in one launch a step) against
#      the per-step one on the GPU, N = 10^3 .. 10^5 with 1, 16 and 64 replicas
#      (python -m bench.schedules), and a batched run's bits run to run.
# Exit status: 0 when every step passed, 1 when one failed, 2 when prerequisites miss.

set -uo pipefail

cd "$(dirname "$0")/.."
BACKEND=cuda
DRY=0
SMOKE=0
LOG=""
while [ $# -gt 0 ]; do
    case "$1" in
        --dry-run) DRY=1 ;;
        --smoke) SMOKE=1 ;;
        --backend) BACKEND="$2"; shift ;;
        --log) LOG="$2"; shift ;;
        -h|--help) sed -n '2,22p' "$0"; exit 0 ;;
        *) echo "gpu_check: unknown option $1" >&2; exit 2 ;;
    esac
    shift
done
if [ "$SMOKE" = 1 ]; then
    BACKEND=cpu
fi
PY="${PYTHON:-python}"
LOG="${LOG:-bench/gpu_check-$(date -u +%Y%m%dT%H%M%SZ).log}"
WORK="$(mktemp -d -t flocklab-gpu-check.XXXXXX)"
trap 'rm -rf "$WORK"' EXIT
: > "$LOG"
FAILED=()

say() { echo "$*" | tee -a "$LOG"; }

# step NAME SECONDS COMMAND...: run it with a timeout, output into the log.
step() {
    local name="$1" limit="$2"
    shift 2
    say ""
    say "== $name (limit ${limit}s)"
    say "   \$ $*"
    if [ "$DRY" = 1 ]; then
        return 0
    fi
    local t0=$SECONDS rc
    timeout --kill-after=10 "$limit" "$@" >> "$LOG" 2>&1
    rc=$?
    if [ $rc -eq 0 ]; then
        say "   PASS ($((SECONDS - t0)) s)"
    else
        say "   FAIL (exit $rc after $((SECONDS - t0)) s$([ $rc -eq 124 ] && echo ', timed out'))"
        FAILED+=("$name")
    fi
}

# ---- prerequisites -------------------------------------------------------------------
say "flocklab GPU check: backend=$BACKEND dry_run=$DRY smoke=$SMOKE $(date -u +%FT%TZ)"
say "git: $(git rev-parse --short HEAD 2>/dev/null || echo unknown)  host: $(hostname)"
if ! "$PY" -c "import flocklab.kernels, flocklab.service, taichi" 2>> "$LOG"; then
    say "prerequisite missing: install the project first (pip install -e '.[dev]')"
    exit 2
fi
say "taichi $("$PY" -c 'import taichi; print(taichi.__version__)' 2>/dev/null | tail -1)"
if [ "$BACKEND" != cpu ]; then
    if command -v nvidia-smi > /dev/null; then
        nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader \
            2>&1 | tee -a "$LOG"
    else
        say "nvidia-smi not found"
    fi
    if [ "$DRY" = 0 ] && ! "$PY" -c "
import sys
from kernels import runtime
sys.exit(0 if runtime.gpu_available('$BACKEND') else 1)"; then
        say "prerequisite missing: Taichi cannot start on $BACKEND on this machine"
        exit 2
    fi
fi

# ---- helpers written for this run -----------------------------------------------------
# A pytest plugin: the engine tests ask for "cpu" (their fixture and scenarios); send
# those requests to the backend under test instead, so the same assertions run there.
cat > "$WORK/flocklab_gpu_plugin.py" <<'EOF'
"""Loaded by bench/gpu_check.sh: every runtime request for "cpu" runs on $FLOCKLAB_GPU_BACKEND."""
import os

from kernels import runtime

_TARGET = os.environ["FLOCKLAB_GPU_BACKEND"]
_ensure = runtime.ensure


def _ensure_on_target(requested, threads=None):
    return _ensure(_TARGET if requested == "cpu" else requested, threads)


runtime.ensure = _ensure_on_target


def pytest_report_header(config):
    return f"flocklab_gpu_plugin: runtime requests for 'cpu' run on {_TARGET!r}"


def pytest_terminal_summary(terminalreporter):
    ran = runtime._current.backend if runtime._current is not None else None
    terminalreporter.write_line(f"flocklab_gpu_plugin: Taichi last ran on {ran!r}")
EOF

# Statistical agreement: `agree.py run BACKEND OUT` runs every family at small N over
# several seeds; `agree.py compare CPU GPU` compares the mean final observables.
cat > "$WORK/agree.py" <<'EOF'
import json
import math
import sys

SMOKE = sys.argv[-1] == "smoke"
PRESETS = ["vicsek-1995", "jlm-leader", "tjp-switching", "tanner-obstacles", "xi-abed-sim1"]
SEEDS = range(2 if SMOKE else 6)
MAX_STEPS = 50 if SMOKE else 1000


def run(backend, out):
    import kernels
    from schemas import PRESETS as ALL, Scenario

    rows = []
    for name in PRESETS[:1] if SMOKE else PRESETS:
        for seed in SEEDS:
            spec = ALL[name].build()
            spec["backend"], spec["seed"] = backend, seed
            spec["time"]["steps"] = min(spec["time"]["steps"], MAX_STEPS)
            spec.setdefault("recording", {})["every"] = 0
            result = kernels.run(Scenario.model_validate(spec))
            rows.append({"preset": name, "seed": seed, "backend": result.backend,
                         "status": result.status,
                         "final": {k: v for k, v in result.final.items()
                                   if isinstance(v, float) and math.isfinite(v)}})
    with open(out, "w") as f:
        json.dump(rows, f)


def stats(xs):
    m = sum(xs) / len(xs)
    var = sum((x - m) ** 2 for x in xs) / max(1, len(xs) - 1)
    return m, math.sqrt(var / len(xs))


def compare(cpu_path, gpu_path):
    cpu, gpu = json.load(open(cpu_path)), json.load(open(gpu_path))
    bad = 0
    print(f"{'preset':18} {'observable':22} {'cpu mean':>12} {'gpu mean':>12} "
          f"{'|diff|':>10} {'tol':>10} {'bitwise':>8}")
    for name in sorted({r["preset"] for r in cpu}):
        c = [r for r in cpu if r["preset"] == name]
        g = [r for r in gpu if r["preset"] == name]
        for r in c + g:
            if r["status"] != "completed":
                print(f"{name}: seed {r['seed']} on {r['backend']} ended {r['status']}")
                bad += 1
        for key in sorted(set(c[0]["final"]) & set(g[0]["final"])):
            xc = [r["final"][key] for r in c if key in r["final"]]
            xg = [r["final"][key] for r in g if key in r["final"]]
            (mc, sc), (mg, sg) = stats(xc), stats(xg)
            tol = 4 * math.hypot(sc, sg) + 1e-9 + 1e-6 * abs(mc)
            same = xc == xg
            ok = abs(mc - mg) <= tol
            bad += not ok
            print(f"{name:18} {key:22} {mc:12.6g} {mg:12.6g} {abs(mc - mg):10.3g} "
                  f"{tol:10.3g} {str(same):>8}{'' if ok else '  <-- outside'}")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    if sys.argv[1] == "run":
        run(sys.argv[2], sys.argv[3])
    else:
        compare(sys.argv[2], sys.argv[3])
EOF

# One job of each model through a real `flocklab serve`, with backend B and auto.
cat > "$WORK/serve_jobs.py" <<'EOF'
import sys
import time
from pathlib import Path

import httpx

from flocklab.service.serve import ServerProcess

backend, work, smoke = sys.argv[1], Path(sys.argv[2]), sys.argv[3] == "smoke"
PRESETS = {"vicsek": "vicsek-1995", "flocking": "tjp-switching",
           "flocking_obstacles": "tanner-obstacles", "formation": "xi-abed-sim1"}
server = ServerProcess(work / "data", env={"FLOCKLAB_WARMUP_PRESET": ""}).start(timeout=120)
failures = 0
try:
    with httpx.Client(base_url=server.url, timeout=60) as http:
        kinds = http.get("/v1/models").json()
        kinds = [m["kind"] for m in (kinds["models"] if isinstance(kinds, dict) else kinds)]
        for kind in kinds:
            preset = PRESETS.get(kind)
            if preset is None:
                print(f"{kind}: no preset listed here; add one to bench/gpu_check.sh")
                failures += 1
                continue
            for requested in ((backend,) if backend == "cpu" else (backend, "auto")):
                body = {"preset": preset, "overrides": {
                    "backend": requested, "time": {"steps": 20 if smoke else 500}}}
                r = http.post("/v1/jobs", json=body)
                job = r.json()
                t0 = time.monotonic()
                while r.status_code == 202 and job["status"] in ("queued", "running"):
                    job = http.get(f"/v1/jobs/{job['id']}", params={"wait": 10}).json()
                want = "cpu" if backend == "cpu" else backend
                ok = job.get("status") == "succeeded" and job.get("backend") == want
                failures += not ok
                print(f"{kind:20} backend={requested:6} -> status={job.get('status')} "
                      f"ran_on={job.get('backend')} {time.monotonic() - t0:.1f}s"
                      f"{'' if ok else '  <-- FAIL ' + str(job.get('error') or job)}")
finally:
    server.stop()
sys.exit(1 if failures else 0)
EOF

# Bench lines -> a table next to FLAME GPU 2 (4.7e8 agent-steps/s, 10^6 agents, H100).
cat > "$WORK/table.py" <<'EOF'
import json
import sys

FLAME = 4.7e8
print(f"{'model':28} {'N':>10} {'backend':>8} {'agent-steps/s':>14} {'vs FLAME GPU 2':>15}")
for line in open(sys.argv[1]):
    line = line.strip()
    if not line.startswith("{"):
        continue
    r = json.loads(line)
    if "error" in r:
        print(f"{r['model']:28} {r['N']:>10} {'':>8} {'error':>14}")
        continue
    label = r["model"] + (f"/{r['rule']}" if r.get("rule") else "")
    rate = r["agent_steps_per_second"]
    print(f"{label:28} {r['N']:>10} {r['backend']:>8} {rate:14.3g} {rate / FLAME:14.2f}x")
print("FLAME GPU 2 (published): 4.7e8 agent-steps/s at N = 10^6 on an H100")
EOF

# ---- the steps ------------------------------------------------------------------------
export FLOCKLAB_GPU_BACKEND="$BACKEND"
ENGINE_TESTS=(tests/kernels/space/test_grid.py tests/kernels/vicsek/test_vicsek.py
              tests/kernels/flocking/test_flocking.py
              tests/kernels/flocking/test_flocking_reference.py
              tests/kernels/formation/test_formation.py tests/kernels/flocking/test_obstacles.py)
if [ "$SMOKE" = 1 ]; then
    ENGINE_TESTS=(tests/kernels/space/test_grid.py)
fi
step "1a. engine tests on $BACKEND (grid = brute force, models vs reference)" 900 \
    env PYTHONPATH="$WORK${PYTHONPATH:+:$PYTHONPATH}" "$PY" -m pytest -q -x \
    -p flocklab_gpu_plugin -m "not slow" -p no:cacheprovider "${ENGINE_TESTS[@]}"
step "1b. same seed -> same trajectory on every backend found, run to run" 600 \
    "$PY" -m pytest -q -p no:cacheprovider \
    "tests/schemas/test_schemas.py::test_every_model_runs_reproducibly_on_every_available_backend"
SMOKE_ARG=$([ "$SMOKE" = 1 ] && echo smoke || echo full)
step "2a. agreement runs on cpu" 900 "$PY" "$WORK/agree.py" run cpu "$WORK/cpu.json" "$SMOKE_ARG"
step "2b. agreement runs on $BACKEND" 900 \
    "$PY" "$WORK/agree.py" run "$BACKEND" "$WORK/gpu.json" "$SMOKE_ARG"
step "2c. $BACKEND vs cpu: mean final observables within 4 standard errors" 60 \
    "$PY" "$WORK/agree.py" compare "$WORK/cpu.json" "$WORK/gpu.json" "$SMOKE_ARG"
step "3. one job of each model through flocklab serve ($BACKEND and auto)" 900 \
    "$PY" "$WORK/serve_jobs.py" "$BACKEND" "$WORK" "$SMOKE_ARG"
if [ "$SMOKE" = 1 ]; then
    BENCH=(--backend cpu --sizes 10000 --steps 20 --models vicsek --no-baseline)
else
    BENCH=(--backend "$BACKEND" --sizes 1000000 10000000)
fi
step "4. python -m bench.bench ${BENCH[*]}" 1800 \
    bash -c "set -o pipefail; $PY -m bench.bench ${BENCH[*]} | tee '$WORK/bench.jsonl'"
if [ "$DRY" = 0 ] && [ -s "$WORK/bench.jsonl" ]; then
    say ""
    "$PY" "$WORK/table.py" "$WORK/bench.jsonl" | tee -a "$LOG"
fi
if [ "$SMOKE" = 1 ]; then
    SCHED=(--backend cpu --sizes 100 --replicas 1 4 --paths per_step batched)
else
    SCHED=(--backend "$BACKEND" --sizes 1000 10000 100000 --replicas 1 16 64
           --paths per_step batched)
fi
step "5a. python -m bench.schedules ${SCHED[*]}" 900 "$PY" -m bench.schedules "${SCHED[@]}"
step "5b. a batched run gives the same bits twice on $BACKEND" 300 "$PY" -c "
import numpy as np
from flocklab import kernels
from bench.schedules import scenario
import bench.schedules as s
s.BACKEND = '$BACKEND'
scs = [scenario(2000, seed, 50) for seed in (1, 2, 3)]
a, b = (kernels.run_batch(scs, path='batched') for _ in range(2))
assert all(r.extra['engine_path'] == 'batched' for r in a + b)
assert all(np.array_equal(x.observables[k], y.observables[k], equal_nan=True)
           for x, y in zip(a, b) for k in x.observables), 'bits differ run to run'
print('batched on', a[0].backend, ': same bits twice;', a[0].final)
"

say ""
if [ "${#FAILED[@]}" -eq 0 ]; then
    say "gpu_check: every step passed$([ "$DRY" = 1 ] && echo ' (dry run: nothing ran)')"
    say "log: $LOG"
    exit 0
fi
say "gpu_check: FAILED: ${FAILED[*]}"
say "log: $LOG"
exit 1
