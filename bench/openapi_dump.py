"""Write the service's OpenAPI document as stable JSON (keys sorted, indent 1), so two
versions of the code can be compared with `diff`: a refactoring that must not change the
public API shows an empty diff. Run: python bench/openapi_dump.py OUT.json."""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from flocklab.service.app.factory import create_app
from flocklab.service.app.settings import load_settings


def openapi_text() -> str:
    """The document of an app built with default settings (no server is started)."""
    with tempfile.TemporaryDirectory() as data:
        app = create_app(load_settings(data_dir=data))
        return json.dumps(app.openapi(), sort_keys=True, indent=1) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description="Write the service's OpenAPI document as "
                                     "stable JSON (keys sorted), for diffing two versions.")
    parser.add_argument("out", type=Path, help="the JSON file to write")
    parser.parse_args().out.write_text(openapi_text())


if __name__ == "__main__":
    main()
