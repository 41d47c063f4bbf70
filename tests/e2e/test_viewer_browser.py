"""The browser viewer in real headless Chromium (Debian's `chromium`, driven by Playwright
for Python) against a real `flocklab serve` on 127.0.0.1.

Skipped, with the reason, when either is missing. CI installs them with
`apt-get install -y chromium` and `pip install playwright` (never `playwright install`:
the browser comes from Debian, not from a download).
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import pytest

from tests.service.svc_helpers import scenario, submit, wait_for

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
if not Path(CHROMIUM).exists():
    pytest.skip("no chromium (apt-get install -y chromium)", allow_module_level=True)
sync_api = pytest.importorskip("playwright.sync_api",
                               reason="no playwright (pip install playwright)")
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
# FLOCKLAB_DOCS_IMG=docs/img saves the viewer's screenshot for the README.
DOCS_IMG = os.environ.get("FLOCKLAB_DOCS_IMG")


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        yield b
        b.close()


class Watched:
    """A page whose console errors, page errors and requests are recorded."""

    def __init__(self, browser, url: str):
        self.page = browser.new_page(viewport={"width": 1280, "height": 900})
        self.errors: list[str] = []
        self.hosts: set[str] = set()
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error"
                     else None)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        # downloads are blob: URLs of this origin
        self.page.on("request", lambda r: self.hosts.add(
            urlsplit(r.url.removeprefix("blob:")).hostname or r.url))
        self.page.goto(url)
        self.page.wait_for_selector("#preset option", state="attached")


def canvas_ink(page, selector: str = "#canvas") -> float:
    """Fraction of the canvas's pixels that are not white."""
    return page.evaluate("""(sel) => {
        const c = document.querySelector(sel);
        const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
        let ink = 0;
        for (let i = 0; i < d.length; i += 4) {
            if (d[i + 3] > 0 && (d[i] < 230 || d[i + 1] < 230 || d[i + 2] < 230)) ink++;
        }
        return ink / (d.length / 4);
    }""", selector)


def preset_form(page, name: str, fields: dict[str, str]) -> None:
    """Choose a preset and fill form fields once the form shows it: choosing a preset
    rebuilds the form after fetching its model's schema, and the page's own first preset
    may still be fetching (the viewer builds only the newest; the form says which)."""
    page.select_option("#preset", name)
    page.wait_for_selector(f'#fields[data-preset="{name}"]')
    assert page.locator('#fields .field[data-path="time.steps"]').count() == 1
    for path, value in fields.items():
        page.fill(f'#fields .field[data-path="{path}"] input', value)
    for path, value in fields.items():
        got = page.input_value(f'#fields .field[data-path="{path}"] input')
        assert got == value, (path, got)


def test_submit_follow_play_and_validation(browser, server, tmp_path):
    w = Watched(browser, server.url + "/")
    page = w.page
    preset_form(page, "vicsek-1995", {"time.steps": "3000"})
    page.click("#submit")
    page.wait_for_function("() => document.querySelector('#job-id').textContent.length > 30")
    job_id = page.text_content("#job-id")
    page.wait_for_selector(f'#jobs tr[data-id="{job_id}"]')  # the job list shows it
    progress, deadline = [], time.monotonic() + 120
    while page.text_content("#job-status") != "succeeded":
        assert time.monotonic() < deadline, page.text_content("#job-status")
        assert page.text_content("#job-status") not in ("failed", "cancelled", "timed_out")
        progress.append(float(page.get_attribute("#job-progress", "value") or 0))
        time.sleep(0.1)
    progress.append(float(page.evaluate("document.querySelector('#job-progress').value")))
    assert progress == sorted(progress) and progress[-1] == 1.0
    assert any(0 < p < 1 for p in progress), progress  # seen part-way, over SSE

    # the results, announced on the event stream, draw the final plot without a click
    # (test_observables_plotted_while_the_job_runs: the plot before that)
    page.wait_for_function("""() => {
        const c = document.querySelector('#plot');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        for (let i = 3; i < d.length; i += 4) if (d[i] > 0) return true;
        return false;
    }""", timeout=60_000)
    page.wait_for_selector("#play:not([disabled])", timeout=60_000)
    assert canvas_ink(page) > 0.002
    page.click("#play")
    page.wait_for_function("() => Number(document.querySelector('#scrub').value) > 3")
    page.click("#play")
    assert canvas_ink(page) > 0.002
    assert page.locator("#downloads button").count() == 5
    assert canvas_ink(page, "#plot") > 0.002  # the observables plot
    if DOCS_IMG:
        page.evaluate("window.scrollTo(0, 0)")
        page.screenshot(path=str(Path(DOCS_IMG) / "viewer.png"))

    assert not w.errors, w.errors
    # a bad field: the server's own message, next to that field (Chromium logs the 422
    # response itself as a console error; nothing else may appear)
    bad = scenario(n=50, steps=10, every=5)
    bad["time"]["dt"] = -1.0
    expected = httpx.post(f"{server.url}/v1/jobs", json={"scenario": bad}).json()
    msg = next(e["msg"] for e in expected["errors"] if e["loc"] == "scenario.time.dt")
    page.fill('#fields .field[data-path="time.dt"] input', "-1")
    page.click("#submit")
    row = page.locator('#fields .field[data-path="time.dt"]')
    row.locator(".field-error").filter(has_text=msg).wait_for()
    assert "invalid" in (row.get_attribute("class") or "")
    assert all("status of 422" in e for e in w.errors), w.errors
    assert w.hosts == {"127.0.0.1"}, w.hosts


def test_preset_picked_while_the_first_one_loads(browser, server):
    """The page's first preset still fetching its model's schema when another is picked:
    the form shows the picked preset alone (both once appended their rows, and the first
    preset's values were what a submit sent)."""
    page = browser.new_page()
    held: list = []

    def hold_first(route):
        if held:
            route.continue_()
        else:
            held.append(route)  # the page's own first fetch, answered below

    page.route("**/v1/models/*", hold_first)
    page.goto(server.url + "/")
    page.wait_for_selector("#preset option", state="attached")
    assert page.input_value("#preset") != "vicsek-1995"
    page.select_option("#preset", "vicsek-1995")
    page.wait_for_function("""() => [...document.querySelectorAll(
        '#fields .field[data-path="initial.N"] input')].some((i) => i.value === "300")""")
    assert len(held) == 1
    held[0].continue_()  # the first preset's schema arrives last
    page.wait_for_load_state("networkidle")
    page.wait_for_timeout(300)
    assert page.locator('#fields .field[data-path="initial.N"]').count() == 1
    assert page.get_attribute("#fields", "data-preset") == "vicsek-1995"
    assert page.input_value('#fields .field[data-path="initial.N"] input') == "300"
    page.close()


def test_default_plots_come_from_the_model_cards(browser, server):
    """The viewer plots each family's default observables as GET /v1/models serves them
    (the model cards), not from a table of its own."""
    from flocklab.schemas import MODELS

    w = Watched(browser, server.url + "/")
    got = w.page.evaluate("(kinds) => kinds.map((k) => window.flocklabViewer.defaultPlots(k))",
                          list(MODELS))
    assert got == [list(card.default_plots) for card in MODELS.values()]
    assert w.page.evaluate("() => window.flocklabViewer.defaultPlots('no-such-model')") == []
    assert not w.errors, w.errors
    w.page.close()


def curve_pixels(page) -> int:
    """Pixels of the observables plot in its curves' blue (#1565c0, antialiased)."""
    return page.evaluate("""() => {
        const c = document.querySelector('#plot');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let n = 0;
        for (let i = 0; i < d.length; i += 4) {
            if (d[i + 3] > 0 && d[i + 2] > 120 && d[i] < 120 && d[i + 2] - d[i] > 60) n++;
        }
        return n;
    }""")


def test_observables_plotted_while_the_job_runs(browser, server):
    """A long job submitted from the page: its observables' curves are on the plot while
    its status still says running (polled rows, before any result), drawn again as rows
    arrive; cancelled then, its results draw the final plot over the rows it kept."""
    w = Watched(browser, server.url + "/")
    page = w.page
    preset_form(page, "vicsek-1995", {"time.steps": "200000",  # minutes
                                      "recording.every": "0",
                                      "recording.observables_every": "10"})
    page.click("#submit")
    page.wait_for_function("() => document.querySelector('#job-status').textContent === "
                           "'running'", timeout=60_000)
    seen, legends, deadline = [], set(), time.monotonic() + 120
    while True:
        status_before = page.text_content("#job-status")
        pixels = curve_pixels(page)
        legend = page.text_content("#plot-legend")
        status_after = page.text_content("#job-status")
        assert status_after == "running", (status_after, seen)
        if status_before == status_after == "running" and pixels:
            seen.append(pixels)
            legends.add(legend)
            if pixels > 50 and len(legends) >= 2:
                break  # curves drawn, and drawn again over a longer time as rows came
        assert time.monotonic() < deadline, seen
        time.sleep(0.2)
    assert all(lg.startswith("time 0 … ") for lg in legends), legends
    page.click("#cancel")
    page.wait_for_function("() => document.querySelector('#job-status').textContent === "
                           "'cancelled'", timeout=60_000)
    page.wait_for_selector("#downloads button >> nth=4", timeout=60_000)  # the results
    assert curve_pixels(page) > 50
    assert not w.errors, w.errors
    assert w.hosts == {"127.0.0.1"}, w.hosts


def test_api_key_is_asked_once_and_kept_in_the_tab(browser, make_server):
    s = make_server({"FLOCKLAB_API_KEY": "k3y"})
    page = browser.new_page()
    page.goto(s.url + "/")
    page.wait_for_function(
        "() => document.querySelector('#list-state').textContent.includes('API key')")
    page.fill("#api-key", "k3y")
    page.click("#key-form button")
    page.wait_for_selector("#preset option", state="attached")
    assert page.evaluate("sessionStorage.getItem('flocklab-api-key')") == "k3y"
    page.reload()  # the key survives a reload of the tab
    page.wait_for_selector("#preset option", state="attached")
    assert page.text_content("#list-state") == ""


def test_playback_rate_at_ten_thousand_agents(browser, make_server, capsys):
    """Reported, not asserted: frames drawn per second at N = 10^4 (the bar: >= 20)."""
    s = make_server({"FLOCKLAB_MAX_AGENTS": "20000",
                     "FLOCKLAB_MAX_TRAJECTORY_BYTES": str(256 * 2**20),
                     "FLOCKLAB_MAX_BODY_BYTES": str(2**20)})
    with httpx.Client(base_url=s.url, timeout=60) as http:
        sc = scenario(n=10_000, steps=60, every=2)
        sc["space"]["L"] = 50.0
        job = submit(http, sc)
        assert wait_for(http, job["id"], timeout=240)["status"] == "succeeded"
    w = Watched(browser, s.url + "/")
    w.page.evaluate("(id) => window.flocklabViewer.selectJob(id)", job["id"])
    w.page.wait_for_selector("#play:not([disabled])", timeout=120_000)
    fps = w.page.evaluate("() => window.flocklabViewer.measurePlayback(100)")
    w.page.select_option("#speed", "4")  # 80 recorded frames a second asked for
    w.page.click("#play")
    time.sleep(2)
    live = w.page.text_content("#fps")
    w.page.click("#play")
    with capsys.disabled():
        print(f"\nviewer playback at N = 10^4: {fps:.1f} frames/s drawn back to back; "
              f"live counter {live}")
    assert fps > 0 and canvas_ink(w.page) > 0.002
    assert not w.errors, w.errors


def test_playback_of_a_3d_job(browser, server):
    """A 3D job plays back through the renderer's camera: each agent where
    `service.render.projection.Camera` puts it, in depth bands (far ones paler), the
    wireframe and the agents on the canvas, no console errors."""
    import numpy as np

    from flocklab.service.render.projection import Camera

    sc = scenario(n=300, steps=40, every=4)
    sc["space"]["dimension"] = 3
    with httpx.Client(base_url=server.url, timeout=60) as http:
        job = submit(http, sc)
        assert wait_for(http, job["id"])["status"] == "succeeded"
        first = http.get(f"/v1/jobs/{job['id']}/trajectory",
                         params={"format": "json", "stop": 1, "arrays": "position"}).json()
    w = Watched(browser, server.url + "/")
    w.page.evaluate("(id) => window.flocklabViewer.selectJob(id)", job["id"])
    w.page.wait_for_selector("#play:not([disabled])", timeout=120_000)
    player = w.page.evaluate("""() => {
        const pl = window.flocklabViewer.state.player;
        const bands = new Set(Array.from(pl.bucket.slice(0, pl.n), (b) => Math.floor(b / 24)));
        return { dim: pl.dim, n: pl.n, frames: pl.frames, bands: bands.size,
                 sx: Array.from(pl.sx.slice(0, pl.n)), sy: Array.from(pl.sy.slice(0, pl.n)) };
    }""")
    assert (player["dim"], player["n"], player["frames"]) == (3, 300, 11)
    expected = Camera(3).screen(np.array(first["position"][0]))
    np.testing.assert_allclose(np.column_stack([player["sx"], player["sy"]]), expected,
                               atol=1e-4)
    assert player["bands"] >= 3  # the cube spans the depth bands
    assert canvas_ink(w.page) > 0.002
    w.page.click("#play")
    w.page.wait_for_function("() => Number(document.querySelector('#scrub').value) > 3")
    w.page.click("#play")
    assert "3D" in w.page.text_content("#frame-info")
    if DOCS_IMG:
        w.page.locator("#player").screenshot(path=str(Path(DOCS_IMG) / "viewer_3d.png"))
    assert not w.errors, w.errors
    assert w.hosts == {"127.0.0.1"}, w.hosts


def test_sweep_list_follows_a_sweep_submitted_from_the_page(browser, server):
    """The form's scenario swept over model.eta from the page: the sweep list shows it
    running, then ended with its runs counted, without a reload (the event stream and
    the list's refresh), and its table is plotted (one point per eta) with the download
    buttons. The engine fuses a chunk of runs into one launch, so the counter may jump
    from 0 to 6: only its order is asserted."""
    w = Watched(browser, server.url + "/")
    page = w.page
    preset_form(page, "vicsek-1995", {"time.steps": "800"})
    page.select_option("#sweep-axis", "model.eta")
    page.fill("#sweep-values", "0.5, 2, 4")
    page.fill("#sweep-replicas", "2")
    page.click("#submit-sweep")
    page.wait_for_function("() => document.querySelector('#panel-kind').textContent === 'Sweep'"
                           " && document.querySelector('#job-id').textContent.length > 30")
    sweep_id = page.text_content("#job-id")
    row = page.locator(f'#sweeps tr[data-id="{sweep_id}"]')
    row.wait_for()  # the sweep list shows it
    seen, deadline = [], time.monotonic() + 240
    while True:
        cells = row.locator("td").all_text_contents()
        seen.append((int(cells[2].split("/")[0]), cells[3]))
        if cells[3] in ("succeeded", "failed", "cancelled", "timed_out"):
            break
        assert time.monotonic() < deadline, seen
        time.sleep(0.1)
    assert seen[-1] == (6, "succeeded"), seen
    done = [d for d, _ in seen]
    assert done == sorted(done), seen
    states = [st for _, st in seen]
    assert states[0] in ("queued", "running") and "running" in states, seen
    assert page.text_content("#job-status") == "succeeded"
    page.wait_for_selector("#downloads button >> nth=2")
    assert page.locator("#downloads button").count() == 3
    with page.expect_download() as download:
        page.click("#downloads button >> text=table.csv")
    header = Path(download.value.path()).read_text().splitlines()[0].split(",")
    assert "model.eta" in header and "polarization_mean" in header, header
    page.wait_for_function(
        "() => document.querySelector('#plot-legend').textContent.includes('model.eta')")
    assert canvas_ink(page, "#plot") > 0.001
    if DOCS_IMG:
        page.evaluate("window.scrollTo(0, 0)")
        page.screenshot(path=str(Path(DOCS_IMG) / "viewer_sweep.png"))
    assert not w.errors, w.errors
    assert w.hosts == {"127.0.0.1"}, w.hosts


@pytest.mark.parametrize("path, rendered", [("/docs", ".swagger-ui .info .title"),
                                            ("/redoc", "h1")])
def test_api_docs_render_offline(browser, server, path, rendered):
    """Swagger UI and ReDoc draw the API's title from the package's own files."""
    title = httpx.get(f"{server.url}/openapi.json").json()["info"]["title"]
    page = browser.new_page()
    errors: list[str] = []
    hosts: set[str] = set()
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    # ReDoc starts a web worker from a blob: URL of this origin
    page.on("request", lambda r: hosts.add(urlsplit(r.url.removeprefix("blob:")).hostname
                                           or r.url))
    page.goto(server.url + path)
    page.locator(rendered).filter(has_text=title).first.wait_for(timeout=60_000)
    assert not errors, errors
    assert hosts == {"127.0.0.1"}, hosts
    page.close()


def test_cancel_from_the_page(browser, server):
    w = Watched(browser, server.url + "/")
    page = w.page
    preset_form(page, "vicsek-1995", {"time.steps": "200000",
                                      "recording.every": "0"})  # within the limits
    page.click("#submit")
    page.wait_for_function("() => document.querySelector('#job-status').textContent === "
                           "'running'", timeout=60_000)
    page.click("#cancel")
    page.wait_for_function("() => document.querySelector('#job-status').textContent === "
                           "'cancelled'", timeout=60_000)
    assert page.is_disabled("#cancel")
    job_id = page.text_content("#job-id")
    assert httpx.get(f"{server.url}/v1/jobs/{job_id}").json()["status"] == "cancelled"
    assert not w.errors, w.errors
    assert w.hosts == {"127.0.0.1"}, w.hosts
