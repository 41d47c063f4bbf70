"""The `flocklab` console script's first stop: `flocklab render` is dispatched to its own
parser before `service.cli` is imported.

`service.cli` imports the pydantic schemas (and the presets) at module level for the
commands that run scenarios; a 10^3-agent snapshot draws in a third of a second, less
than that start-up, so the render command must not pay for it. Every other command goes
to `service.cli.main` unchanged.
"""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["render"]:
        from .render.cli import main as render_main

        return render_main(argv[1:])
    from .cli import main as cli_main

    return cli_main(argv)


if __name__ == "__main__":
    sys.exit(main())
