"""`flocklab models [NAME]`: one model's entry in the catalog, as text.

Each model also names the document that holds its details (the choices the papers leave
open, presets, observables) and the bibliography (docs/REFERENCES.md), so the pointers the
command prints are files that exist (a test checks them).
"""

from __future__ import annotations

import json
from typing import Any

REFERENCES = "docs/REFERENCES.md"

# The details of each model family: where they are written down.
MODEL_DOCS: dict[str, str] = {
    "vicsek": "README.md (M1 details)",
    "flocking": "docs/MODELS_M2_M3.md",
    "flocking_obstacles": "docs/MODELS_M2_M3.md",
    "formation": "docs/MODELS_M4.md",
}


def model_details(kind: str) -> dict[str, str]:
    """The documents for one model kind: {"details": path, "references": path}."""
    return {"details": MODEL_DOCS.get(kind, "README.md (Models)"), "references": REFERENCES}


def print_model(m: dict[str, Any]) -> None:
    """One catalog entry (from `schemas.describe_models()`) as indented text."""
    docs = model_details(m["kind"])
    print(f"{m['kind']}: {m['summary']}")
    print(f"  paper: {m['paper']} (full reference: {docs['references']})")
    print(f"  equations: {m['equations']}")
    print(f"  neighbourhood: |r_ij| {'<=' if m['paper_inclusive'] else '<'} radius "
          f"(paper's choice); state: {', '.join(m['state'])}")
    if m.get("derived_arrays"):
        print(f"  also recordable per agent: {', '.join(m['derived_arrays'])}")
    if m.get("observables"):
        print(f"  observables: {', '.join(m['observables'])}")
    note = f" ({m['dimensions_note']})" if m.get("dimensions_note") else ""
    print(f"  dimensions: {', '.join(map(str, m['dimensions']))}{note}")
    print(f"  details: {docs['details']}")
    print("  parameters:")
    for p in m["parameters"]:
        default = "required" if p["required"] else f"default {_fmt(p['default'])}"
        print(f"    {p['name']} ({default}): {p['description']}")


def _fmt(v: Any) -> str:
    return json.dumps(v) if not isinstance(v, str) else v
