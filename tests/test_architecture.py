"""The layering, read from the source: an `ast` pass over every module of the tree.

Every import counts, at module level, under `if TYPE_CHECKING:` and inside functions
(lazy) alike. The rules (../shared/ARCHITECTURE.md):
- no import cycle anywhere;
- schemas/ imports no other flocklab package; clients/ only schemas; kernels/ only schemas;
- service/ reaches kernels/ only inside functions (or for annotations, under
  TYPE_CHECKING: the API process never imports Taichi), and never a model family
  (`flocklab.kernels.models`);
- no model family imports another;
- bench/ and docker/ never import tests/.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# Source folders and the module prefix each installs as (setup.py maps the four parts).
PREFIX = {"schemas": "flocklab.schemas", "kernels": "flocklab.kernels",
          "service": "flocklab.service", "clients": "flocklab.clients",
          "flocklab": "flocklab", "bench": "bench", "docker": "docker", "tests": "tests"}


@dataclass(frozen=True)
class Edge:
    source: str
    target: str
    where: str  # "module", "type_checking" or "lazy"
    line: int


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT)
    parts = [PREFIX[rel.parts[0]], *rel.parts[1:]]
    parts[-1] = parts[-1].removesuffix(".py")
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(p for p in ".".join(parts).split(".") if p)


@cache
def modules() -> dict[str, Path]:
    out = {}
    for top in PREFIX:
        for path in sorted((ROOT / top).rglob("*.py")):
            if "__pycache__" not in path.parts:
                out[_module_name(path)] = path
    return out


def _resolve(mod: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute name `from ... import` names (relative imports resolved)."""
    if not node.level:
        return node.module or ""
    base = mod.split(".") if is_package else mod.split(".")[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _targets(name: str, names: list[str]) -> list[str]:
    """The project modules an import of `names` from `name` reaches: each `name.n` that
    is a module, else `name` itself (a package's __init__ or a module)."""
    known = modules()
    out = [f"{name}.{n}" for n in names if f"{name}.{n}" in known]
    if len(out) < len(names) and name in known:
        out.append(name)
    return out


class _Walker(ast.NodeVisitor):
    def __init__(self, mod: str, is_package: bool):
        self.mod, self.is_package = mod, is_package
        self.where = "module"
        self.edges: list[Edge] = []

    def _scoped(self, node: ast.AST, where: str) -> None:
        saved, self.where = self.where, where
        self.generic_visit(node)
        self.where = saved

    def visit_FunctionDef(self, node: ast.FunctionDef) -> None:
        self._scoped(node, "lazy")

    visit_AsyncFunctionDef = visit_FunctionDef  # type: ignore[assignment]

    def visit_If(self, node: ast.If) -> None:
        test = node.test
        if (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
                isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"):
            for stmt in node.body:
                self._scoped(ast.Module(body=[stmt], type_ignores=[]),
                             "lazy" if self.where == "lazy" else "type_checking")
            for stmt in node.orelse:
                self.visit(stmt)
            return
        self.generic_visit(node)

    def _add(self, targets: list[str], line: int) -> None:
        self.edges += [Edge(self.mod, t, self.where, line) for t in targets
                       if t != self.mod]

    def visit_Import(self, node: ast.Import) -> None:
        known = modules()
        for alias in node.names:
            name = alias.name
            while name and name not in known:
                name = name.rpartition(".")[0]
            if name:
                self._add([name], node.lineno)

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        name = _resolve(self.mod, self.is_package, node)
        self._add(_targets(name, [a.name for a in node.names]), node.lineno)


@cache
def edges() -> tuple[Edge, ...]:
    out: list[Edge] = []
    for mod, path in modules().items():
        walker = _Walker(mod, path.name == "__init__.py")
        walker.visit(ast.parse(path.read_text(), str(path)))
        out += walker.edges
    return tuple(out)


def _layer(mod: str) -> str:
    parts = mod.split(".")
    return parts[1] if parts[0] == "flocklab" and len(parts) > 1 else parts[0]


def _family(mod: str) -> str | None:
    parts = mod.split(".")
    if parts[:3] == ["flocklab", "kernels", "models"] and len(parts) > 3:
        return parts[3]
    return None


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def _show(found: list[Edge]) -> str:
    return "\n".join(f"{e.source} -> {e.target} ({e.where}, line {e.line})" for e in found)


@pytest.mark.slow
def test_the_walk_sees_every_kind_of_import():
    """The pass finds module-level, TYPE_CHECKING and lazy imports (else every rule below
    would pass vacuously)."""
    kinds = {e.where for e in edges()}
    assert kinds == {"module", "type_checking", "lazy"}
    assert Edge("flocklab.kernels.engine", "flocklab.kernels.driver", "module", 0) in {
        Edge(e.source, e.target, e.where, 0) for e in edges()}
    assert len(modules()) > 200


def test_no_import_cycle():
    graph: dict[str, set[str]] = {m: set() for m in modules()}
    for e in edges():
        graph[e.source].add(e.target)
    cycles = _cycles(graph)
    assert not cycles, "\n".join(" <-> ".join(c) for c in cycles)


@pytest.mark.parametrize("layer,allowed", [
    ("schemas", {"schemas"}),
    ("clients", {"clients", "schemas"}),
    ("kernels", {"kernels", "schemas"}),
])
def test_a_layer_imports_only_the_layers_below(layer, allowed):
    bad = [e for e in edges() if _layer(e.source) == layer
           and e.target.startswith("flocklab") and _layer(e.target) not in allowed]
    assert not bad, _show(bad)


def test_service_reaches_the_engine_only_inside_functions_and_never_a_family():
    into = [e for e in edges() if _layer(e.source) == "service" and _layer(e.target) == "kernels"]
    assert into, "the service runs the engine somewhere"
    bad = [e for e in into if e.where == "module" or _family(e.target) is not None]
    assert not bad, _show(bad)


def test_no_model_family_imports_another():
    bad = [e for e in edges() if _family(e.source) and _family(e.target)
           and _family(e.source) != _family(e.target)]
    assert not bad, _show(bad)


def test_bench_and_docker_never_import_tests():
    bad = [e for e in edges() if _layer(e.source) in ("bench", "docker")
           and _layer(e.target) == "tests"]
    assert not bad, _show(bad)
