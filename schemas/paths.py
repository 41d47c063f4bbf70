"""Dotted paths into a scenario's JSON ("model.eta", "initial.region.low.0").

One helper sets a value at a path; a sweep's axes and `flocklab run --set` both use it,
so a path means the same thing in both. Paths are checked against the *full* canonical
scenario (`Scenario.model_dump(mode="json")`, every default filled in), so a typo is an
"unknown field" error that lists the fields there are, not a silently ignored key.
"""

from __future__ import annotations

import json
import re
from typing import Any

_SEGMENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*|[0-9]+")


class PathError(ValueError):
    """A path that does not name a field of the document (message names the culprit)."""


def split_path(path: str) -> list[str]:
    """The segments of a dotted path; raises PathError on an empty or malformed one."""
    parts = path.split(".")
    if not path or not all(_SEGMENT.fullmatch(p) for p in parts):
        raise PathError(f"{path!r} is not a dotted field path like 'model.eta'")
    return parts


def check_path(doc: Any, path: str) -> None:
    """Raise PathError unless `path` names an existing field (or list item) of `doc`."""
    _walk(doc, split_path(path), path)


def set_path(doc: Any, path: str, value: Any) -> Any:
    """A copy of `doc` with the field at `path` replaced by `value` (copies along the path
    only; the rest is shared). The field must exist in `doc`."""
    parts = split_path(path)
    _walk(doc, parts, path)
    root = _copy(doc)
    node = root
    for part in parts[:-1]:
        key = int(part) if isinstance(node, list) else part
        node[key] = _copy(node[key])
        node = node[key]
    node[int(parts[-1]) if isinstance(node, list) else parts[-1]] = value
    return root


def parse_assignment(text: str) -> tuple[str, Any]:
    """'model.eta=3' -> ('model.eta', 3). The value is JSON (numbers, true, null, objects,
    quoted strings), else taken as a plain string ('model.rule=average')."""
    path, sep, raw = text.partition("=")
    if not sep:
        raise PathError(f"{text!r}: expected PATH=VALUE, e.g. model.eta=3")
    split_path(path.strip())
    try:
        value = json.loads(raw)
    except ValueError:
        value = raw
    return path.strip(), value


def _walk(doc: Any, parts: list[str], path: str) -> Any:
    """The node at `parts` of `doc`; raises PathError naming the first missing segment."""
    node = doc
    for depth, part in enumerate(parts):
        where = ".".join(parts[:depth]) or "the scenario"
        if isinstance(node, dict):
            if part not in node:
                known = ", ".join(sorted(node))
                raise PathError(f"{path}: unknown field {part!r} in {where} (fields: {known})")
            node = node[part]
        elif isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise PathError(f"{path}: {where} is a list of {len(node)}; {part!r} is not "
                                "an index of it")
            node = node[int(part)]
        elif node is None:
            raise PathError(f"{path}: {where} is null here; set {where} as a whole")
        else:
            raise PathError(f"{path}: {where} is a value ({json.dumps(node)}), not an object")
    return node


def _copy(node: Any) -> Any:
    if isinstance(node, dict):
        return dict(node)
    if isinstance(node, list):
        return list(node)
    return node


def merge(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """Recursive merge of JSON objects (a preset's `overrides`); any other value replaces
    the base's. An override that switches a union member (a different `kind`) replaces the
    object whole, so the old member's fields do not leak into the new one. The job service's
    preset submissions merge with it too."""
    out = dict(base)
    for key, value in overrides.items():
        old = out.get(key)
        if (isinstance(old, dict) and isinstance(value, dict)
                and value.get("kind", old.get("kind")) == old.get("kind")):
            out[key] = merge(old, value)
        else:
            out[key] = value
    return out
