"""`flocklab models [NAME]`: one model's entry in the catalog, as text.

Each model's card names the document that holds its details (the choices the papers leave
open, presets, observables); with the bibliography (docs/REFERENCES.md), the pointers the
command prints are files that exist (a test checks them).
"""

from __future__ import annotations

import json
from typing import Any

REFERENCES = "docs/REFERENCES.md"


def print_model(m: dict[str, Any]) -> None:
    """One catalog entry (from `schemas.describe_models()`) as indented text."""
    print(f"{m['kind']}: {m['summary']}")
    print(f"  paper: {m['paper']} (full reference: {REFERENCES})")
    print(f"  equations: {m['equations']}")
    kinds = m.get("neighbour_kinds", ["metric"])
    if not kinds:  # the model takes no neighbours block; its card says what it uses
        print(f"  neighbours: {m['neighbours_note']}; state: {', '.join(m['state'])}")
    else:
        print(f"  neighbourhood: |r_ij| {'<=' if m['paper_inclusive'] else '<'} radius "
              f"(paper's choice); state: {', '.join(m['state'])}")
    if "topological" in kinds:
        print(f"  neighbours.kind: {', '.join(kinds)} (topological: the k nearest)"
              + (f"; {m['neighbours_note']}" if m.get("neighbours_note") else ""))
    elif kinds:
        print("  neighbours.kind: metric only (topological is refused: not yet for this "
              "model)")
    if m.get("derived_arrays"):
        print(f"  also recordable per agent: {', '.join(m['derived_arrays'])}")
    if m.get("observables"):
        print(f"  observables: {', '.join(m['observables'])}")
    note = f" ({m['dimensions_note']})" if m.get("dimensions_note") else ""
    print(f"  dimensions: {', '.join(map(str, m['dimensions']))}{note}")
    units = {k: u for k, u in m["units"].items() if u}
    print("  units: " + (", ".join(f"{k} {u}" for k, u in units.items()) if units
                         else "the model's own (dimensionless)"))
    if m["default_plots"]:
        print(f"  plotted by default: {', '.join(m['default_plots'])}")
    print(f"  details: {m['details']}")
    print("  parameters:")
    for p in m["parameters"]:
        default = "required" if p["required"] else f"default {_fmt(p['default'])}"
        print(f"    {p['name']} ({default}): {p['description']}")


def _fmt(v: Any) -> str:
    return json.dumps(v) if not isinstance(v, str) else v
