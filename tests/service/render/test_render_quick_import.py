"""`mpl_import.import_for_drawing`: the quick matplotlib import of the drawing processes
draws the same pixels as the usual import, and leaves matplotlib as usual afterwards."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tests.service.render.conftest import read_image

DRAW = """
import json, sys
{first}
from flocklab.service.render.cli import main
rc = main([{folder!r}, '--out', {out!r}, '--edges', '--size', '300x300'])
print(json.dumps({{"rc": rc, "agl": type(sys.modules.get("fontTools.agl")).__name__}}))
"""
USUAL = "import matplotlib.figure, matplotlib.backends.backend_agg"  # then a no-op


def _draw(folder, out, first: str) -> str:
    """Draw in a fresh interpreter; the type of its `fontTools.agl` module."""
    code = DRAW.format(first=first, folder=str(folder), out=str(out))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout.strip().splitlines()[-1])
    assert report["rc"] == 0
    return report["agl"]


@pytest.mark.slow
def test_quick_import_draws_the_same_pixels(runs, tmp_path):
    quick, usual = tmp_path / "quick.png", tmp_path / "usual.png"
    assert _draw(runs["vicsek"], quick, "") == "_Deferred"  # the glyph list never used
    assert _draw(runs["vicsek"], usual, USUAL) == "module"
    a, b = read_image(quick), read_image(usual)
    assert a.shape == b.shape == (300, 300, 3)  # opaque: RGB
    assert np.array_equal(a, b)


def test_matplotlib_is_as_usual_after_the_quick_import():
    code = """
import gc, json
from flocklab.service.render.mpl_import import import_for_drawing
import_for_drawing()
from matplotlib import artist
from matplotlib.lines import Line2D
import fontTools.agl

class Later(artist.Artist):  # defined after: its set() documented as usual
    pass

line = Line2D([0, 1], [0, 1])
line.set(linewidth=3, color="red")  # set() works on the classes made quickly
print(json.dumps({
    "gc": gc.isenabled(),
    "later_doc": "Supported properties" in (Later.set.__doc__ or ""),
    "kwdoc": "linewidth" in artist.kwdoc(Line2D),
    "agl": fontTools.agl.toUnicode("A"),
    "lw": line.get_linewidth(),
}))
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout.strip().splitlines()[-1])
    assert got == {"gc": True, "later_doc": True, "kwdoc": True, "agl": "A", "lw": 3.0}
