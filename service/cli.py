"""The `flocklab` command: run, validate, models, presets, serve.

Exit codes: 0 success; 1 the run diverged or was interrupted; 2 bad input (invalid
scenario, unreadable file, unknown preset); 3 the requested backend is unavailable.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from schemas import PRESETS, Scenario, describe_models, field_errors, get_preset, parse_json_strict
from schemas.vicsek_presets import DEFAULT_PRESET

EXIT_OK, EXIT_RUN_FAILED, EXIT_BAD_INPUT, EXIT_BACKEND = 0, 1, 2, 3


class BadInput(Exception):
    """A user-facing input problem: printed as is, exit code 2."""


def load_scenario(source: str) -> Scenario:
    """A scenario from a JSON file path, '-' for stdin, or 'preset:NAME'."""
    if source.startswith("preset:"):
        try:
            return get_preset(source.removeprefix("preset:"))
        except KeyError as exc:
            raise BadInput(str(exc.args[0])) from exc
    try:
        text = sys.stdin.read() if source == "-" else Path(source).read_text()
    except OSError as exc:
        raise BadInput(f"cannot read {source}: {exc.strerror}") from exc
    try:
        data = parse_json_strict(text)
    except ValueError as exc:
        raise BadInput(f"{source}: not valid JSON: {exc}") from exc
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        lines = [f"{source}: {len(exc.errors())} problem(s):"]
        lines += [f"  {e.loc}: {e.msg}" for e in field_errors(exc)]
        raise BadInput("\n".join(lines)) from exc


class ProgressBar:
    """A one-line progress bar on a terminal; silent when stderr is not a terminal."""

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.t0 = time.perf_counter()

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        frac = done / total if total else 1.0
        elapsed = time.perf_counter() - self.t0
        eta = elapsed * (1 - frac) / frac if frac > 0 else 0.0
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r[{bar:<30}] {100 * frac:5.1f}%  step {done}/{total}  "
                         f"eta {eta:6.1f}s")
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def cmd_run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    if args.backend:
        scenario = scenario.model_copy(update={"backend": args.backend})
    from kernels import BackendUnavailable

    from .execute import execute_to_dir

    show = sys.stderr.isatty() and not args.quiet
    try:
        summary = execute_to_dir(
            scenario, Path(args.out), on_progress=ProgressBar(show), overwrite=args.overwrite
        )
    except FileExistsError as exc:
        raise BadInput(f"{exc}; pass --overwrite to replace it") from exc
    except BackendUnavailable as exc:
        print(f"flocklab: {exc}", file=sys.stderr)
        return EXIT_BACKEND
    brief = {k: summary[k] for k in ("status", "backend", "steps", "wall_seconds",
                                     "agent_steps_per_second")}
    print(json.dumps({"out": str(args.out), **brief}))
    if summary["status"] == "diverged":
        print(f"flocklab: run diverged: {summary['error']['message']}", file=sys.stderr)
        return EXIT_RUN_FAILED
    return EXIT_OK


def cmd_validate(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    print(f"{args.scenario}: valid ({scenario.model.kind}, N = {scenario.n_agents}, "
          f"{scenario.time.steps} steps, {scenario.n_frames} frames)")
    return EXIT_OK


def cmd_models(args: argparse.Namespace) -> int:
    catalog = describe_models()
    if args.json:
        print(json.dumps(catalog, indent=2))
        return EXIT_OK
    for m in catalog:
        print(f"{m['kind']}: {m['summary']}")
        print(f"  paper: {m['paper']}")
        print(f"  equations: {m['equations']}")
        print(f"  neighbourhood: |r_ij| {'<=' if m['paper_inclusive'] else '<'} radius "
              f"(paper's choice); state: {', '.join(m['state'])}")
        print("  parameters:")
        for p in m["parameters"]:
            default = "required" if p["required"] else f"default {_fmt(p['default'])}"
            print(f"    {p['name']} ({default}): {p['description']}")
        print()
    return EXIT_OK


def cmd_presets(args: argparse.Namespace) -> int:
    if args.name:
        if args.name not in PRESETS:
            raise BadInput(f"unknown preset {args.name!r}; known: {', '.join(sorted(PRESETS))}")
        print(get_preset(args.name).model_dump_json(indent=2))
        return EXIT_OK
    for p in PRESETS.values():
        print(f"{p.name}: {p.description}")
    return EXIT_OK


def cmd_serve(args: argparse.Namespace, rest: list[str]) -> int:
    from .serve import cli_main

    return cli_main(rest)


def _fmt(v: Any) -> str:
    return json.dumps(v) if not isinstance(v, str) else v


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="flocklab", description="Published flocking and formation models at scale."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run", help="run a scenario and write its artifacts to a folder")
    p.add_argument("scenario", nargs="?", default=f"preset:{DEFAULT_PRESET}",
                   help="scenario JSON file, '-' for stdin, or preset:NAME "
                   f"(default: the embedded preset:{DEFAULT_PRESET})")
    p.add_argument("--out", required=True, help="output folder (created atomically)")
    p.add_argument("--backend", choices=["cpu", "cuda", "vulkan", "auto"],
                   help="override the scenario's backend")
    p.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(fn=cmd_run)
    p = sub.add_parser("validate", help="check a scenario and report every problem")
    p.add_argument("scenario", help="scenario JSON file, '-' for stdin, or preset:NAME")
    p.set_defaults(fn=cmd_validate)
    p = sub.add_parser("models", help="list the models, their parameters and equations")
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
    if argv and argv[0] == "serve":
        return cmd_serve(argparse.Namespace(), argv[1:])
    args = parser.parse_args(argv)
    try:
        return args.fn(args)
    except BadInput as exc:
        print(f"flocklab: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("flocklab: interrupted", file=sys.stderr)
        return EXIT_RUN_FAILED


if __name__ == "__main__":
    sys.exit(main())
