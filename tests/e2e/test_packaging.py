"""The package as users get it: one `flocklab` namespace in site-packages, never a
generic top-level name (`kernels` is another distribution on PyPI), a wheel and an sdist
that `python -m build` makes from a checkout, and a wheel that installs beside the PyPI
`kernels` with both importable afterwards."""

from __future__ import annotations

import ast
import subprocess
import sys
import tarfile
import venv
import zipfile
from pathlib import Path

import pytest

from tests.project_version import VERSION

ROOT = Path(__file__).resolve().parents[2]
PARTS = ("kernels", "schemas", "service", "clients")
SKIP = {".venv", ".ci-venv", ".git", "build", "dist", "node_modules"}


def _sources() -> list[Path]:
    return [p for p in ROOT.rglob("*.py")
            if not SKIP & set(p.relative_to(ROOT).parts)]


def test_no_module_imports_the_parts_by_their_bare_names():
    bare = []
    for path in _sources():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0
                     and node.module else [])
            bare += [f"{path.relative_to(ROOT)}:{node.lineno} {n}" for n in names
                     if n.split(".")[0] in PARTS]
    assert bare == [], "import these as flocklab.<part>: " + ", ".join(bare)


def test_import_flocklab_gives_the_client_and_loads_nothing_heavy():
    code = ("import sys, flocklab; client = flocklab.Client; "
            "print(client.__module__, flocklab.__version__, "
            "any(m.startswith(('pydantic', 'httpx', 'flocklab.clients')) for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd="/").stdout.split()
    assert out == ["flocklab.clients.sync", VERSION, "True"]
    lazy = subprocess.run([sys.executable, "-c", "import sys, flocklab; print(sorted("
                           "m for m in sys.modules if m.startswith(('flocklab.', 'pydantic'))))"],
                          capture_output=True, text=True, check=True, cwd="/").stdout
    assert lazy.strip() == "[]", lazy


@pytest.mark.slow
def test_wheel_and_sdist_install_beside_the_pypi_kernels(tmp_path: Path):
    dist = tmp_path / "dist"
    subprocess.run([sys.executable, "-m", "build", "--outdir", str(dist), str(ROOT)],
                   check=True, capture_output=True, timeout=600)
    (wheel,) = dist.glob("flocklab-*.whl")
    (sdist,) = dist.glob("flocklab-*.tar.gz")
    with zipfile.ZipFile(wheel) as z:
        tops = {n.split("/")[0] for n in z.namelist()}
        meta = z.read(next(n for n in z.namelist() if n.endswith("dist-info/METADATA")))
    assert tops == {"flocklab", f"flocklab-{VERSION}.dist-info"}, tops
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
    assert {"flocklab/kernels/space/grid.py", "flocklab/service/app/static/index.html",
            "flocklab/schemas/scenario.py", "flocklab/clients/sync.py"} <= names
    assert b"Name: flocklab" in meta and b"Provides-Extra: engine" in meta
    with tarfile.open(sdist) as t:
        members = {m.name.split("/", 1)[1] for m in t.getmembers() if "/" in m.name}
    assert {"setup.py", "pyproject.toml", "kernels/engine.py", "flocklab/__init__.py"} <= members

    env = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env)
    py = str(env / "bin" / "python")
    pip = [py, "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    subprocess.run([*pip, "kernels"], check=True, capture_output=True, timeout=600)
    subprocess.run([*pip, str(wheel)], check=True, capture_output=True, timeout=600)
    code = ("import kernels, flocklab, flocklab.schemas; "
            "print(kernels.__file__.split('site-packages/')[1], flocklab.__version__, "
            "flocklab.Client('http://127.0.0.1:1').base_url)")
    out = subprocess.run([py, "-c", code], capture_output=True, text=True, check=True,
                         cwd=tmp_path, timeout=120).stdout.split()
    assert out == ["kernels/__init__.py", VERSION, "http://127.0.0.1:1"], out
    cli = subprocess.run([str(env / "bin" / "flocklab"), "--version"], capture_output=True,
                         text=True, timeout=60)
    assert cli.returncode == 0 and cli.stdout.strip() == f"flocklab {VERSION}", cli.stderr
