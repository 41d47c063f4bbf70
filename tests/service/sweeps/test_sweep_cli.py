"""`flocklab sweep`, `validate` for sweeps, `run --set`, and the catalogs, as a user runs them."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from flocklab.schemas.sweep import load_sweep
from flocklab.service.cli import main

SWEEP = {
    "name": "cli",
    "preset": "vicsek-1995",
    "overrides": {"time": {"steps": 30}, "initial": {"N": 20}, "space": {"L": 4.0},
                  "recording": {"every": 0, "observables_every": 5}},
    "axes": [{"path": "model.eta", "values": [0.5, 4.0]}],
    "replicas": 2,
    "measure": {"va": {"observable": "polarization", "reduce": "mean", "from_step": 10}},
}


def flocklab(*args, stdin=None):
    return subprocess.run([sys.executable, "-m", "flocklab", *args], capture_output=True,
                          text=True, input=stdin, timeout=300)


def write(tmp_path, name, doc):
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return str(path)


@pytest.mark.slow
def test_sweep_runs_resumes_and_refuses_another_sweep_in_its_folder(tmp_path):
    path, out = write(tmp_path, "s.json", SWEEP), str(tmp_path / "out")
    proc = flocklab("sweep", path, "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert "eta" not in proc.stderr  # no progress bar when stderr is not a terminal
    line = json.loads(proc.stdout)
    assert (line["status"], line["runs_done"], line["runs_total"]) == ("completed", 4, 4)
    table = (tmp_path / "out" / "table.csv").read_text().splitlines()
    assert table[0] == "point,model.eta,va_mean,va_sd,va_sem,va_count" and len(table) == 3
    again = flocklab("sweep", path, "--out", out)
    assert again.returncode == 0 and json.loads(again.stdout)["runs_resumed"] == 4
    other = write(tmp_path, "o.json", dict(SWEEP, replicas=3))
    clash = flocklab("sweep", other, "--out", out)
    assert clash.returncode == 2 and "different sweep" in clash.stderr
    assert "--overwrite" in clash.stderr
    assert (tmp_path / "out" / "table.csv").read_text().splitlines() == table
    fresh = flocklab("sweep", other, "--out", out, "--overwrite")
    assert fresh.returncode == 0 and json.loads(fresh.stdout)["runs_done"] == 6


def test_bad_sweeps_exit_2_listing_every_problem_before_anything_runs(tmp_path, capsys):
    bad = dict(SWEEP, axes=[{"path": "model.eta", "values": [0.5, -1.0]},
                            {"path": "initial.N", "values": [20, 0]}],
               measure={"va": {"observable": "polarization", "reduce": "mean",
                               "from_step": 99}})
    path = write(tmp_path, "bad.json", bad)
    assert main(["validate", path]) == 2
    err = capsys.readouterr().err
    for fragment in ("runs[2].initial.N", "runs[4].model.eta", "(runs[4..5] at model.eta=-1.0",
                     "measure.va.from_step", "time.steps = 30"):
        assert fragment in err, err
    proc = flocklab("sweep", path, "--out", str(tmp_path / "never"))
    assert proc.returncode == 2 and "runs[4].model.eta" in proc.stderr
    assert not (tmp_path / "never").exists()
    cases = {
        "unknown path": (dict(SWEEP, axes=[{"path": "model.etta", "values": [1]}]),
                         "axes.0.path: model.etta: unknown field 'etta'"),
        "unequal zip": (dict(SWEEP, axes=[{"zip": [{"path": "initial.N", "values": [1, 2]},
                                                   {"path": "space.L", "values": [4.0]}]}]),
                        "zip lists must have equal lengths"),
        "empty axis": (dict(SWEEP, axes=[{"path": "model.eta", "values": []}]),
                       "axes.0.values: an axis needs at least one value"),
        "too many runs": (dict(SWEEP, replicas=100_000), "more than the limit of 100000"),
    }
    for name, (doc, fragment) in cases.items():
        assert main(["validate", write(tmp_path, "c.json", doc)]) == 2, name
        assert fragment in capsys.readouterr().err, name
    assert main(["sweep", write(tmp_path, "scen.json", {"model": {"kind": "vicsek"}}),
                 "--out", str(tmp_path / "x")]) == 2
    assert "not a sweep" in capsys.readouterr().err
    assert main(["run", write(tmp_path, "ok.json", SWEEP), "--out", str(tmp_path / "x")]) == 2
    assert "is a sweep: run it with `flocklab sweep" in capsys.readouterr().err
    (tmp_path / "file").write_text("")
    assert main(["sweep", write(tmp_path, "ok.json", SWEEP), "--out",
                 str(tmp_path / "file")]) == 2
    assert "is not a folder" in capsys.readouterr().err
    assert main(["sweep", "preset:nope", "--out", str(tmp_path / "x")]) == 2
    assert "vicsek-1995-fig2a" in capsys.readouterr().err
    assert main(["validate", write(tmp_path, "ok.json", SWEEP)]) == 0
    assert "valid sweep (2 grid points, 4 runs, 2400 agent-steps)" in capsys.readouterr().out
    assert main(["validate", "preset:vicsek-1995-fig2a"]) == 0
    assert "140 runs" in capsys.readouterr().out


def test_run_set_overrides_a_scenario_file_and_a_preset(tmp_path, capsys, taichi_cpu):
    scen = {"model": {"kind": "vicsek", "eta": 0.1}, "space": {"kind": "periodic", "L": 6.0},
            "neighbours": {"radius": 1.0}, "initial": {"kind": "random", "N": 50},
            "time": {"steps": 10}}
    path = write(tmp_path, "scen.json", scen)
    out = tmp_path / "a"
    assert main(["run", path, "--out", str(out), "--quiet", "--set", "model.eta=3",
                 "--set", "initial.N=70", "--set", "model.rule=average",
                 "--set", "neighbours.inclusive=false"]) == 0
    ran = json.loads((out / "scenario.json").read_text())
    assert (ran["model"]["eta"], ran["initial"]["N"], ran["model"]["rule"]) == (3, 70, "average")
    assert ran["neighbours"]["inclusive"] is False and ran["space"]["L"] == 6.0
    out = tmp_path / "b"
    assert main(["run", "preset:vicsek-1995", "--out", str(out), "--quiet",
                 "--set", "time.steps=5", "--set", "initial.N=30"]) == 0
    ran = json.loads((out / "scenario.json").read_text())
    assert (ran["time"]["steps"], ran["initial"]["N"], ran["space"]["L"]) == (5, 30, 7.0)
    capsys.readouterr()
    for sets, fragment in ((["model.etaa=1"], "unknown field 'etaa' in model"),
                           (["model.eta=-2"], "model.eta: Input should be greater"),
                           (["model.eta"], "expected PATH=VALUE"),
                           (["initial.region.low=[0, 0]"], "initial.region is null")):
        argv = ["run", "preset:vicsek-1995", "--out", str(tmp_path / "never")]
        assert main([*argv, *(x for s in sets for x in ("--set", s))]) == 2
        assert fragment in capsys.readouterr().err
    assert not (tmp_path / "never").exists()


def test_catalogs_list_the_sweep_schema_and_the_sweep_presets(capsys):
    assert main(["models", "--json"]) == 0
    catalog = json.loads(capsys.readouterr().out)
    sweep = catalog[-1]
    assert sweep["kind"] == "sweep" and "axes" in sweep["json_schema"]["properties"]
    assert any(m["kind"] == "vicsek" for m in catalog)
    assert main(["presets"]) == 0
    listing = capsys.readouterr().out
    assert "vicsek-1995-fig2a" in listing and "vicsek-1995-fig2b" in listing
    assert main(["presets", "vicsek-1995-fig2b"]) == 0
    assert load_sweep(json.loads(capsys.readouterr().out)).n_runs == 40


@pytest.mark.slow
def test_ctrl_c_keeps_finished_runs_and_a_rerun_resumes(tmp_path):
    # One run per engine call (the engine would fuse the four runs into one launch that
    # ends them together), each long enough (about a second) for the interrupt to land.
    doc = dict(SWEEP, overrides={**SWEEP["overrides"], "time": {"steps": 30_000},
                                 "initial": {"N": 100}, "space": {"L": 5.0}},
               axes=[{"path": "model.eta", "values": [0.5, 3.0]}], replicas=2,
               measure={"va": {"observable": "polarization", "reduce": "mean"}})
    path, out = write(tmp_path, "long.json", doc), tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "flocklab", "sweep", path, "--out",
                             str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "FLOCKLAB_SWEEP_BATCH_RUNS": "1"})
    journal = out / "runs.jsonl"
    deadline = time.monotonic() + 120
    while not (journal.exists() and journal.read_text().count("\n") >= 1):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert json.loads(stdout)["status"] == "cancelled" and proc.returncode == 1
    assert "interrupted" in stderr and "run the same command again to resume" in stderr
    kept = journal.read_text().count("\n")
    assert 1 <= kept < 4 and "Traceback" not in stderr
    again = flocklab("sweep", path, "--out", str(out))
    assert again.returncode == 0, again.stderr
    line = json.loads(again.stdout)
    assert (line["status"], line["runs_done"], line["runs_resumed"]) == ("completed", 4, kept)
