"""The `flocklab` command: run, sweep, validate, convert, models, presets, serve.

Exit codes: 0 success; 1 the run diverged or was interrupted; 2 bad input (invalid
scenario, unreadable file, unknown preset); 3 the requested backend is unavailable;
4 the command needs an extra that is not installed (`engine` for run, sweep and convert,
`service` for serve: service/cli_extras.py).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from flocklab.schemas import (
    PRESETS,
    FieldError,
    Scenario,
    describe_models,
    field_errors,
    get_preset,
    parse_json_strict,
)
from flocklab.schemas.paths import PathError, parse_assignment, set_path
from flocklab.schemas.sweep import Sweep, SweepError, describe_sweep, is_sweep_document, load_sweep
from flocklab.schemas.sweep_presets import SWEEP_PRESETS
from flocklab.schemas.vicsek_presets import DEFAULT_PRESET

from .cli_extras import EXIT_MISSING_EXTRA, MissingExtra, require_extras, version
from .cli_models import REFERENCES, print_model
from .progress import ProgressBar

EXIT_OK, EXIT_RUN_FAILED, EXIT_BAD_INPUT, EXIT_BACKEND = 0, 1, 2, 3


class BadInput(Exception):
    """A user-facing input problem: printed as is, exit code 2."""


def load_scenario(source: str, sets: Sequence[str] = ()) -> Scenario:
    """A scenario from a JSON file path, '-' for stdin, or 'preset:NAME', with `--set
    PATH=VALUE` assignments applied (the same dotted paths as a sweep's axes)."""
    if source.startswith("preset:") and not sets:
        try:
            return get_preset(source.removeprefix("preset:"))
        except KeyError as exc:
            raise BadInput(str(exc.args[0])) from exc
    scenario = _validated(source, _scenario_data(source))
    if not sets:
        return scenario
    doc = scenario.model_dump(mode="json")
    for text in sets:
        try:
            path, value = parse_assignment(text)
            doc = set_path(doc, path, value)
        except PathError as exc:
            raise BadInput(f"--set {exc}") from exc
    return _validated(f"{source} with --set {' --set '.join(sets)}", doc)


def _scenario_data(source: str) -> Any:
    if source.startswith("preset:"):
        name = source.removeprefix("preset:")
        if name not in PRESETS:
            raise BadInput(f"unknown preset {name!r}; known: {', '.join(sorted(PRESETS))}")
        return PRESETS[name].build()
    data = read_json(source)
    if is_sweep_document(data):
        raise BadInput(f"{source} is a sweep: run it with `flocklab sweep {source} --out DIR`")
    return data


def _validated(source: str, data: Any) -> Scenario:
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        raise BadInput(_problems(source, field_errors(exc))) from exc


def read_json(source: str) -> Any:
    """A JSON document from a file path or '-' (stdin); NaN and ±Inf are refused."""
    try:
        text = sys.stdin.read() if source == "-" else Path(source).read_text()
    except OSError as exc:
        raise BadInput(f"cannot read {source}: {exc.strerror}") from exc
    try:
        return parse_json_strict(text)
    except ValueError as exc:
        raise BadInput(f"{source}: not valid JSON: {exc}") from exc


def _problems(source: str, errors: list[FieldError]) -> str:
    lines = [f"{source}: {len(errors)} problem(s):"]
    return "\n".join(lines + [f"  {e.loc}: {e.msg}" for e in errors])


def load_sweep_source(source: str) -> Sweep:
    """A sweep from a JSON file, '-' or 'preset:NAME' (a named sweep), fully checked."""
    if source.startswith("preset:"):
        name = source.removeprefix("preset:")
        if name not in SWEEP_PRESETS:
            raise BadInput(f"unknown sweep preset {name!r}; known: "
                           f"{', '.join(sorted(SWEEP_PRESETS))}")
        data = SWEEP_PRESETS[name].build()
    else:
        data = read_json(source)
        if not is_sweep_document(data):
            raise BadInput(f"{source}: not a sweep (a sweep has 'axes', 'base' or 'preset'; "
                           "run a scenario with `flocklab run`)")
    try:
        return load_sweep(data)
    except SweepError as exc:
        raise BadInput(_problems(source, exc.errors)) from exc


def cmd_run(args: argparse.Namespace) -> int:
    if args.resume is not None:
        if (args.out is not None or args.set or args.backend or args.overwrite
                or args.path != "auto" or args.scenario is not None):
            raise BadInput("--resume DIR takes the scenario, backend and path from the run "
                           "folder: give it alone (with --quiet at most)")
        args.out = args.resume
        scenario = None
    elif args.out is None:
        raise BadInput("run needs --out DIR (or --resume DIR)")
    else:
        scenario = load_scenario(args.scenario or f"preset:{DEFAULT_PRESET}", args.set or ())
        if args.backend:
            scenario = scenario.model_copy(update={"backend": args.backend})
    from flocklab.kernels import BackendUnavailable, PathUnavailable
    from flocklab.kernels.checkpoint import CheckpointUnsupported
    from flocklab.kernels.checks import warnings as check_warnings

    from .checkpoints import CheckpointRefused
    from .execute import execute_to_dir, resume_dir

    show = sys.stderr.isatty() and not args.quiet
    stop = _StopOnInterrupt()  # Ctrl-C stops between steps; what was computed is kept
    try:
        with stop:
            if scenario is None:
                summary = resume_dir(Path(args.resume), on_progress=ProgressBar(show),
                                     should_stop=stop, stopped_status="interrupted")
                scenario = load_scenario(str(Path(args.resume) / "scenario.json"))
            else:
                summary = execute_to_dir(
                    scenario, Path(args.out), on_progress=ProgressBar(show),
                    should_stop=stop, overwrite=args.overwrite,
                    stopped_status="interrupted", path=args.path,
                )
    except CheckpointRefused as exc:
        raise BadInput(f"cannot resume: {exc}") from exc
    except CheckpointUnsupported as exc:
        raise BadInput(f"recording.checkpoint_every: {exc}") from exc
    except FileExistsError as exc:
        raise BadInput(f"{exc}; pass --overwrite to replace it") from exc
    except PathUnavailable as exc:
        raise BadInput(f"--path {args.path}: {exc}") from exc
    except BackendUnavailable as exc:
        print(f"flocklab: {exc}", file=sys.stderr)
        return EXIT_BACKEND
    brief = {k: summary[k] for k in ("status", "backend", "steps", "wall_seconds",
                                     "agent_steps_per_second")}
    if "resumed_from_step" in summary:
        brief["resumed_from_step"] = summary["resumed_from_step"]
    print(json.dumps({"out": str(args.out), **brief}))
    for line in check_warnings(summary.get("checks", {})):
        print(f"flocklab: warning: {line}", file=sys.stderr)
    if summary["status"] == "diverged":
        print(f"flocklab: run diverged: {summary['error']['message']}", file=sys.stderr)
        return EXIT_RUN_FAILED
    if summary["status"] == "interrupted":
        print(f"flocklab: interrupted at step {summary['steps']} of {scenario.time.steps}: "
              f"the {summary['frames']} frame(s) and the observables so far are in "
              f"{args.out} (status interrupted)", file=sys.stderr)
        if (Path(args.out) / "checkpoint.npz").exists():
            print(f"flocklab: continue it with: flocklab run --resume {args.out}",
                  file=sys.stderr)
        return EXIT_RUN_FAILED
    return EXIT_OK


def cmd_sweep(args: argparse.Namespace) -> int:
    sweep = load_sweep_source(args.sweep)
    out = Path(args.out)
    if args.overwrite and out.exists():
        if not (out / "sweep.json").exists():
            raise BadInput(f"{out} holds no sweep; --overwrite replaces sweep folders only")
        shutil.rmtree(out)
    from flocklab.kernels import BackendUnavailable

    from .sweeps.executors import ExecutorConfig
    from .sweeps.factory import make_executor
    from .sweeps.ray_executor import ClusterError
    from .sweeps.runner import SweepFolderConflict, run_sweep

    show = sys.stderr.isatty() and not args.quiet
    bar = ProgressBar(show, unit="run")
    stop = _StopOnInterrupt()
    t0 = time.perf_counter()
    try:
        with stop:
            executor = make_executor(ExecutorConfig(
                kind=args.executor, ray_address=args.ray_address, threads=args.ray_threads))
            outcome = run_sweep(sweep, out, should_stop=stop, executor=executor,
                                on_progress=lambda p: bar(p.runs_done + p.runs_failed,
                                                          p.runs_total),
                                on_resumed=None if args.quiet else _say_resumed)
    except SweepFolderConflict as exc:
        raise BadInput(f"{exc}, or pass --overwrite to start it afresh") from exc
    except SweepError as exc:
        raise BadInput(_problems(args.sweep, exc.errors)) from exc
    except OSError as exc:  # an unwritable or full output folder
        raise BadInput(f"cannot write the sweep into {out}: {exc.strerror or exc}") from exc
    except (BackendUnavailable, ClusterError) as exc:  # the finished runs are kept
        print(f"flocklab: {exc}", file=sys.stderr)
        return EXIT_BACKEND
    print(json.dumps({"out": str(out), "status": outcome.status,
                      "runs_done": outcome.runs_done, "runs_failed": outcome.runs_failed,
                      "runs_total": outcome.runs_total, "runs_resumed": outcome.runs_resumed,
                      **({"checkpoints_resumed": {str(k): v for k, v in
                                                  outcome.checkpoints_resumed.items()}}
                         if outcome.checkpoints_resumed else {}),
                      "wall_seconds": round(time.perf_counter() - t0, 3)}))
    finished = outcome.runs_done + outcome.runs_failed
    if outcome.status == "cancelled":
        print(f"flocklab: interrupted: {finished} of {outcome.runs_total} runs finished and "
              f"kept in {out}; run the same command again to resume", file=sys.stderr)
        return EXIT_RUN_FAILED
    if outcome.runs_failed:
        print(f"flocklab: {outcome.runs_failed} run(s) diverged (status in runs.csv; left "
              "out of table.csv)", file=sys.stderr)
    return EXIT_OK


def _say_resumed(run: int, step: int | None) -> None:
    """A sweep run going on from its checkpoint (docs/CHECKPOINTS.md), on stderr."""
    if step is not None:
        print(f"flocklab: run {run} goes on from its checkpoint at step {step}",
              file=sys.stderr)


class _StopOnInterrupt:
    """The sweep's should_stop: true after Ctrl-C (SIGINT), so the run in progress stops
    between steps and the finished runs are kept. A second Ctrl-C interrupts at once."""

    def __init__(self) -> None:
        self.stopped = False
        self.previous: Any = None

    def __call__(self) -> bool:
        return self.stopped

    def _handle(self, signum: int, frame: Any) -> None:
        if self.stopped:
            raise KeyboardInterrupt
        self.stopped = True

    def __enter__(self) -> _StopOnInterrupt:
        # Signal handlers can only be set on the main thread (elsewhere: no Ctrl-C hook).
        if threading.current_thread() is threading.main_thread():
            self.previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.previous is not None:
            signal.signal(signal.SIGINT, self.previous)


def cmd_validate(args: argparse.Namespace) -> int:
    source = args.scenario
    if source.startswith("preset:"):
        name = source.removeprefix("preset:")
        if name in SWEEP_PRESETS:
            return _validate_sweep(source, SWEEP_PRESETS[name].build())
        scenario = load_scenario(source)
    else:
        data = read_json(source)
        if is_sweep_document(data):
            return _validate_sweep(source, data)
        scenario = _validated(source, data)
    print(f"{source}: valid ({scenario.model.kind}, N = {scenario.n_agents}, "
          f"{scenario.time.steps} steps, {scenario.n_frames} frames)")
    if scenario.n_frames == 0:
        print(f"flocklab: warning: {source} records no frames (recording.every is 0): the "
              "run keeps its observables but no trajectory; set recording.every = k to "
              "record a frame every k steps", file=sys.stderr)
    return EXIT_OK


def cmd_convert(args: argparse.Namespace) -> int:
    """`flocklab convert RUN_DIR --to gsd`: the run's trajectory.h5 frames as trajectory.gsd."""
    from .gsd_trajectory import ConvertError, convert_run

    try:
        path, frames = convert_run(Path(args.run_dir), overwrite=args.overwrite)
    except ConvertError as exc:
        raise BadInput(str(exc)) from exc
    print(f"{path}: {frames} frames")
    return EXIT_OK


def _validate_sweep(source: str, data: Any) -> int:
    try:
        sweep = load_sweep(data)
    except SweepError as exc:
        raise BadInput(_problems(source, exc.errors)) from exc
    print(f"{source}: valid sweep ({sweep.n_points} grid points, {sweep.n_runs} runs, "
          f"{sweep.total_agent_steps:.4g} agent-steps)")
    return EXIT_OK


def cmd_models(args: argparse.Namespace) -> int:
    catalog = describe_models()
    if args.name is not None:
        return _one_model(catalog, args.name, as_json=args.json)
    if args.json:  # the models, then the sweep file's schema (kind "sweep")
        print(json.dumps([*catalog, describe_sweep()], indent=2))
        return EXIT_OK
    for m in catalog:
        print_model(m)
        print()
    print(f"one model: flocklab models NAME; references: {REFERENCES}")
    return EXIT_OK


def _one_model(catalog: list[dict[str, Any]], name: str, *, as_json: bool) -> int:
    found = [m for m in catalog if m["kind"] == name]
    if not found:
        raise BadInput(f"unknown model {name!r}; known: "
                       f"{', '.join(m['kind'] for m in catalog)}")
    if as_json:
        print(json.dumps({**found[0], "references": REFERENCES}, indent=2))
    else:
        print_model(found[0])
    return EXIT_OK


def cmd_presets(args: argparse.Namespace) -> int:
    if args.name in SWEEP_PRESETS:
        print(json.dumps(SWEEP_PRESETS[args.name].build(), indent=2))
        return EXIT_OK
    if args.name:
        if args.name not in PRESETS:
            known = ", ".join(sorted([*PRESETS, *SWEEP_PRESETS]))
            raise BadInput(f"unknown preset {args.name!r}; known: {known}")
        print(get_preset(args.name).model_dump_json(indent=2))
        return EXIT_OK
    for p in PRESETS.values():
        print(f"{p.name}: {p.description}")
    print("\nsweeps (flocklab sweep preset:NAME --out DIR):")
    for sp in SWEEP_PRESETS.values():
        print(f"{sp.name}: {sp.description}")
    return EXIT_OK


def cmd_serve(args: argparse.Namespace, rest: list[str]) -> int:
    from .serve import cli_main

    return cli_main(rest)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="flocklab", description="Published flocking and formation models at scale."
    )
    parser.add_argument("--version", action="version", version=f"flocklab {version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run", help="run a scenario and write its artifacts to a folder")
    p.add_argument("scenario", nargs="?", default=None,
                   help="scenario JSON file, '-' for stdin, or preset:NAME "
                   f"(default: the embedded preset:{DEFAULT_PRESET})")
    p.add_argument("--out", help="output folder (created atomically)")
    p.add_argument("--resume", metavar="DIR", help="continue the checkpointed run of the "
                   "output folder DIR from its latest checkpoint (recording.checkpoint_every;"
                   " docs/CHECKPOINTS.md), bit for bit")
    p.add_argument("--backend", choices=["cpu", "cuda", "vulkan", "auto"],
                   help="override the scenario's backend")
    p.add_argument("--path", choices=["auto", "per_step", "fused", "batched"], default="auto",
                   help="the engine's schedule (default auto: chosen from the scenario "
                   "and the backend; summary.json's engine_path says which ran)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--set", action="append", metavar="PATH=VALUE",
                   help="override a field, e.g. --set model.eta=3 --set initial.N=400 "
                   "(VALUE is JSON, else a string; repeatable)")
    p.set_defaults(fn=cmd_run)
    p = sub.add_parser("sweep", help="run a sweep (many runs, one table) into a folder; "
                       "running it again resumes")
    p.add_argument("sweep", help="sweep JSON file, '-' for stdin, or preset:NAME")
    p.add_argument("--out", required=True, help="output folder (resumed if it holds this "
                   "sweep: its finished runs kept, a run with checkpoints continued from "
                   "its latest)")
    p.add_argument("--overwrite", action="store_true",
                   help="discard a sweep folder's finished runs and start afresh")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--executor", choices=["local", "ray"], default="local",
                   help="where the runs execute: this process, or tasks on a Ray cluster")
    p.add_argument("--ray-address", default="auto", metavar="ADDR",
                   help="the Ray cluster: 'auto', host:port or ray://host:port (default auto)")
    p.add_argument("--ray-threads", type=int, default=1, metavar="T",
                   help="CPU threads (num_cpus) per Ray task for runs that name none")
    p.set_defaults(fn=cmd_sweep)
    p = sub.add_parser("validate", help="check a scenario or a sweep; report every problem")
    p.add_argument("scenario", help="scenario or sweep JSON file, '-' for stdin, or "
                   "preset:NAME")
    p.set_defaults(fn=cmd_validate)
    p = sub.add_parser("convert", help="write a run folder's trajectory in another format "
                       "(its trajectory.h5 frames as trajectory.gsd)")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run folder holding trajectory.h5")
    p.add_argument("--to", required=True, choices=["gsd"], help="the format to write")
    p.add_argument("--overwrite", action="store_true", help="replace an existing "
                   "trajectory.gsd")
    p.set_defaults(fn=cmd_convert)
    p = sub.add_parser("models", help="list the models, their parameters and equations")
    p.add_argument("name", nargs="?", help="show only this model (a kind, e.g. vicsek)")
    p.add_argument("--json", action="store_true", help="machine-readable catalog")
    p.set_defaults(fn=cmd_models)
    p = sub.add_parser("presets", help="list the paper presets, or print one as JSON")
    p.add_argument("name", nargs="?", help="a preset to print")
    p.set_defaults(fn=cmd_presets)
    p = sub.add_parser("render", help="draw a run (snapshot, observables, movie) or a sweep")
    from .render.cli import add_arguments, cmd_render

    add_arguments(p)
    p.set_defaults(fn=cmd_render)
    p = sub.add_parser("serve", help="start the HTTP job service (see `serve --help`)",
                       add_help=False)
    p.set_defaults(fn=None)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    try:
        if argv and argv[0] == "serve":
            require_extras("serve")
            return cmd_serve(argparse.Namespace(), argv[1:])
        args = parser.parse_args(argv)
        require_extras(args.command)
        return args.fn(args)
    except MissingExtra as exc:
        print(f"flocklab: {exc}", file=sys.stderr)
        return EXIT_MISSING_EXTRA
    except BadInput as exc:
        print(f"flocklab: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("flocklab: interrupted", file=sys.stderr)
        return EXIT_RUN_FAILED
    except BrokenPipeError:  # `flocklab models | head`: the reader left, not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
