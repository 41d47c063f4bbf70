"""A client-only install (no `[engine]`, no `[service]`): the commands that need an extra
answer one line naming it and exit 4, with no traceback; the rest work.

Two real, separate virtual environments: a fast one made here from the client's own
dependencies (numpy, pydantic, httpx and theirs, linked from the test environment) and
the checkout's editable install, so taichi, h5py, scipy, fastapi and uvicorn are absent; and a
slow one made exactly as a user would, `pip install -e .` (about 40 s: marked slow).
"""

from __future__ import annotations

import importlib.util
import subprocess
import venv
from pathlib import Path

import pytest

from flocklab.service.cli_extras import EXIT_MISSING_EXTRA

ROOT = Path(__file__).resolve().parents[2]

# The client's dependencies and theirs, by import name (pyproject's `dependencies`).
CLIENT_MODULES = ("numpy", "numpy.libs", "pydantic", "pydantic_core", "annotated_types",
                  "typing_extensions", "typing_inspection", "httpx", "httpcore", "anyio",
                  "h11", "idna", "certifi", "sniffio")
ENGINE_AND_SERVICE = ("taichi", "h5py", "scipy", "gsd", "fastapi", "uvicorn",
                      "pydantic_settings")


def _site_packages(env: Path) -> Path:
    return next((env / "lib").glob("python3*/site-packages"))


def _link_client_modules(site: Path) -> None:
    here = Path(importlib.util.find_spec("numpy").origin).parents[1]  # this env's site
    for name in CLIENT_MODULES:
        for src in (here / name, here / f"{name}.py"):
            if src.exists():
                (site / src.name).symlink_to(src)


def _link_editable_install(site: Path) -> None:
    """This env's `pip install -e` of the checkout (its path hook, its import finder that
    maps flocklab.* to the source folders, and its metadata), linked into `site`."""
    here = Path(importlib.util.find_spec("numpy").origin).parents[1]
    parts = [*here.glob("__editable__*flocklab*"), *here.glob("flocklab-*.dist-info")]
    assert parts, "the checkout is not installed in this environment (pip install -e .)"
    for src in parts:
        (site / src.name).symlink_to(src)


@pytest.fixture(scope="module")
def client_env(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A venv holding only the client's dependencies and the checkout's editable install."""
    env = tmp_path_factory.mktemp("client-only") / "venv"
    venv.EnvBuilder(with_pip=False).create(env)
    site = _site_packages(env)
    _link_client_modules(site)
    _link_editable_install(site)
    return env / "bin" / "python"


def _check_client_only(cli: list[str], python: Path, tmp_path: Path) -> None:
    probe = subprocess.run([str(python), "-c", "import importlib.util as u, sys; "
                            f"sys.exit(any(u.find_spec(m) for m in {ENGINE_AND_SERVICE!r}))"])
    assert probe.returncode == 0, "the environment is not client-only"
    for args, extra in ((["run", "--out", str(tmp_path / "o")], "engine"),
                        (["sweep", "preset:vicsek-1995-fig2a", "--out", str(tmp_path / "s")],
                         "engine"),
                        (["convert", str(tmp_path), "--to", "gsd"], "engine"),
                        (["serve", "--port", "1"], "service")):
        proc = subprocess.run([*cli, *args], capture_output=True, text=True, timeout=120)
        assert proc.returncode == EXIT_MISSING_EXTRA, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
        assert f"pip install 'flocklab[{extra}]'" in lines[0]
        assert not (tmp_path / "o").exists()
    version = subprocess.run([*cli, "--version"], capture_output=True, text=True, timeout=60)
    assert version.returncode == 0 and version.stdout.startswith("flocklab 0.1")
    valid = subprocess.run([*cli, "validate", "preset:vicsek-1995"], capture_output=True,
                           text=True, timeout=60)
    assert valid.returncode == 0 and "valid" in valid.stdout, valid.stderr
    client = subprocess.run([str(python), "-c", "import flocklab; "
                             "print(flocklab.Client('http://127.0.0.1:1').base_url)"],
                            capture_output=True, text=True, timeout=60)
    assert client.returncode == 0 and client.stdout.strip() == "http://127.0.0.1:1"


def test_client_only_environment(client_env: Path, tmp_path: Path):
    _check_client_only([str(client_env), "-m", "flocklab"], client_env, tmp_path)


@pytest.mark.slow
def test_pip_install_without_extras(tmp_path: Path):
    """`pip install -e .` into a fresh venv, then the `flocklab` script it installs."""
    env = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env)
    pip = subprocess.run([str(env / "bin" / "python"), "-m", "pip", "install", "-q", "-e",
                          str(ROOT)], capture_output=True, text=True, timeout=600)
    assert pip.returncode == 0, pip.stderr[-2000:]
    _check_client_only([str(env / "bin" / "flocklab")], env / "bin" / "python", tmp_path)

