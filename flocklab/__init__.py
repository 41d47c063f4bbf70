"""flocklab: the published flocking and formation-control models at scale.

One installed namespace: `flocklab.schemas` (the wire types), `flocklab.kernels` (the
Taichi engine, the `engine` extra), `flocklab.service` (the CLI and the job service) and
`flocklab.clients` (the HTTP client). `import flocklab` gives the client:

    import flocklab
    with flocklab.Client("http://127.0.0.1:8000") as c:
        job = c.submit(preset="vicsek-1995").wait()

The client's names are looked up on first use (PEP 562), so that `import flocklab`, and
every `flocklab.*` module (the `flocklab` command among them), imports nothing heavy.
"""

import importlib
from typing import Any


def __getattr__(name: str) -> Any:
    if name == "__version__":  # read on first use: importlib.metadata costs ~70 ms
        return importlib.import_module("flocklab.schemas.version").version()
    clients = importlib.import_module("flocklab.clients")
    if name in clients.__all__:
        return getattr(clients, name)
    raise AttributeError(f"module 'flocklab' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), "__version__",
                   *importlib.import_module("flocklab.clients").__all__])
