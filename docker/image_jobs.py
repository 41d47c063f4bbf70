"""Inside the image: one job of every model family on a running `flocklab serve`.

Run by docker/test-image.sh. Each job is a preset shortened to a few hundred steps (the
same kernels). Prints one JSON line per job: the model, the seconds from submit to
result, and the engine's own setup and wall seconds. Exits 1 when a job did not succeed.
(The service's workers write Taichi's cache only when they exit, so the script counts
compiled kernels per job with the batch command instead, and for the service as a whole
once it has stopped.)

    python image_jobs.py http://127.0.0.1:PORT
"""

from __future__ import annotations

import json
import sys
import time

from flocklab.clients import Client

# One preset per model family (and per formation design), shortened.
JOBS = [("vicsek", "vicsek-1995"), ("flocking", "tjp-switching"),
        ("flocking_obstacles", "tanner-obstacles"), ("formation F1", "xi-abed-sim1"),
        ("formation F2", "xi-abed-sim3")]
STEPS = 200


def main(url: str) -> int:
    failed = 0
    with Client(url) as client:
        for family, preset in JOBS:
            t0 = time.perf_counter()
            job = client.submit(preset=preset, overrides={"time": {"steps": STEPS}})
            job.wait(timeout=300, progress=False)
            seconds = time.perf_counter() - t0
            summary = job.metrics()["summary"] if job.status == "succeeded" else {}
            print(json.dumps({"model": family, "preset": preset, "status": job.status,
                              "first_job_seconds": round(seconds, 2),
                              "setup_seconds": summary.get("setup_seconds"),
                              "engine_path": summary.get("engine_path"),
                              "wall_seconds": summary.get("wall_seconds")}),
                  flush=True)
            failed += job.status != "succeeded"
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
