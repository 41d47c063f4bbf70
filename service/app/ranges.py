"""`Range` headers checked before a file is served, so a bad one is a problem+json 400 or
416 rather than Starlette's plain-text answer. The parsing is Starlette's own (the one
`FileResponse` then applies), so what passes here is served exactly as checked."""

from __future__ import annotations

from pathlib import Path

from starlette.responses import FileResponse, MalformedRangeHeader, RangeNotSatisfiable

from .problems import ProblemError


def check_range(range_header: str | None, path: Path) -> None:
    """Raise a ProblemError for a malformed (400) or unsatisfiable (416) Range header."""
    if range_header is None:
        return
    size = path.stat().st_size
    try:
        FileResponse._parse_range_header(range_header, size)
    except MalformedRangeHeader as exc:
        raise ProblemError(400, "bad-range", "Bad Range header",
                           f"{exc.content} Expected e.g. 'bytes=0-1023'") from None
    except RangeNotSatisfiable:
        raise ProblemError(416, "range-not-satisfiable", "Range Not Satisfiable",
                           f"the requested range lies outside the file's {size} bytes",
                           headers={"Content-Range": f"bytes */{size}"}, size=size) from None
