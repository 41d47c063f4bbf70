"""Peak RSS and CPU of admitting a maximum-size sweep (issue 28 #1): what the API process
spends in `parse_submission("sweep", ...)` on a 100,000-run sweep (1000 grid points x 100
replicas). Run: python bench/sweep_admission_memory.py [points] [replicas]."""

from __future__ import annotations

import json
import resource
import sys
import tempfile
import time

from flocklab.service.app.settings import Settings
from flocklab.service.app.submit import parse_submission


def main() -> None:
    points = int(sys.argv[1]) if len(sys.argv) > 1 else 1000
    replicas = int(sys.argv[2]) if len(sys.argv) > 2 else 100
    spec = {
        "name": "max-size",
        "base": {"model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03},
                 "space": {"kind": "periodic", "L": 5.0}, "neighbours": {"radius": 1.0},
                 "initial": {"kind": "random", "N": 100}, "time": {"steps": 100},
                 "recording": {"every": 0, "observables_every": 10}, "seed": 1},
        "axes": [{"path": "model.eta", "values": [round(5 * i / points, 6)
                                                  for i in range(points)]}],
        "replicas": replicas,
        "measure": {"va": {"observable": "polarization", "reduce": "mean"}},
    }
    raw = json.dumps(spec).encode()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.process_time()
    with tempfile.TemporaryDirectory() as d:
        new = parse_submission("sweep", raw, Settings(data_dir=d))
    cpu = time.process_time() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{new.steps_total} runs, body {len(raw)} B: peak RSS {peak:.0f} MiB "
          f"(+{peak - before:.0f} MiB over the {before:.0f} MiB before), {cpu:.1f} s CPU")


if __name__ == "__main__":
    main()
