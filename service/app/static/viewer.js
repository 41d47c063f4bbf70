// flocklab's browser viewer: plain JavaScript against the public API (no build step, no
// CDN). The API key, when the service needs one, is typed once and kept in
// sessionStorage (this tab only); every request carries it as X-API-Key, which is why
// the event stream is read with fetch() rather than EventSource (which cannot send it).
"use strict";

const KEY_STORE = "flocklab-api-key";
const HUES = 24;  // heading colours: agents are drawn in one path per hue bucket
const BASE_FPS = 20;  // recorded frames per second at speed 1x
const TRAJECTORY_BUDGET = 48 * 2 ** 20;  // bytes of frames fetched for playback

const $ = (id) => document.getElementById(id);
const state = { key: sessionStorage.getItem(KEY_STORE) || "", presets: [], models: [],
                selected: null, selectedSweep: null, follow: null, player: null, jobs: [],
                sweeps: [], scenario: null, terminal: [] };

/** The final job states, read from the API's description (`JobView.status`, the schema's
 * one vocabulary): its enum lists the states in lifecycle order, the live ones up to
 * "running" first; a job in any later state never changes again. */
function terminalStates(openapi) {
  const states = openapi.components.schemas.JobView.properties.status.enum;
  return states.slice(states.indexOf("running") + 1);
}

// -- HTTP ---------------------------------------------------------------------------------

function authHeaders(extra) {
  const h = Object.assign({}, extra || {});
  if (state.key) h["X-API-Key"] = state.key;
  return h;
}

async function api(path, options) {
  const opts = Object.assign({}, options || {});
  opts.headers = authHeaders(opts.headers);
  const r = await fetch(path, opts);
  const type = r.headers.get("content-type") || "";
  const body = type.includes("json") ? await r.json() : null;
  if (!r.ok) {
    const err = new Error((body && (body.detail || body.title)) || r.statusText);
    err.status = r.status;
    err.problem = body;
    throw err;
  }
  return body;
}

// The observables a model's card plots by default (GET /v1/models), in order.
function defaultPlots(kind) {
  const card = state.models.find((m) => m.kind === kind);
  return card ? card.default_plots : [];
}

// -- API key ------------------------------------------------------------------------------

function showKeyState() {
  $("key-state").textContent = state.key ? "key set for this tab" : "";
  $("api-key").value = state.key;
}

$("key-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  state.key = $("api-key").value.trim();
  if (state.key) sessionStorage.setItem(KEY_STORE, state.key);
  else sessionStorage.removeItem(KEY_STORE);
  showKeyState();
  start();
});

// -- the scenario form --------------------------------------------------------------------

function flatten(obj, prefix, out) {
  for (const [k, v] of Object.entries(obj)) {
    const path = prefix ? `${prefix}.${k}` : k;
    if (v !== null && typeof v === "object" && !Array.isArray(v)) flatten(v, path, out);
    else out.push([path, v]);
  }
  return out;
}

function setPath(obj, path, value) {
  const parts = path.split(".");
  let o = obj;
  for (const p of parts.slice(0, -1)) o = o[p] = o[p] || {};
  o[parts[parts.length - 1]] = value;
}

function modelProperty(schema, path) {
  // The model's JSON Schema describes model.*; the scenario's other blocks are plain.
  if (!schema || !path.startsWith("model.") || path.split(".").length !== 2) return null;
  return (schema.properties || {})[path.split(".")[1]] || null;
}

// Each call of showPreset takes a number; only the newest builds the form. Two calls in
// flight (the page's first preset still fetching its schema when the user picks another)
// otherwise both appended their rows, and the older preset's values were submitted.
let presetShown = 0;

async function showPreset(name) {
  const call = ++presetShown;
  const preset = state.presets.find((p) => p.name === name);
  const fields = $("fields");
  fields.replaceChildren();
  delete fields.dataset.preset;
  $("submit-error").textContent = "";
  if (!preset) return;
  let schema = null;
  try { schema = await api(`/v1/models/${preset.scenario.model.kind}`); } catch (e) { /* plain */ }
  if (call !== presetShown) return;
  for (const [path, value] of flatten(preset.scenario, "", [])) {
    const row = document.createElement("div");
    row.className = "field";
    row.dataset.path = path;
    const id = "f-" + path.replace(/\W/g, "_");
    const label = document.createElement("label");
    label.htmlFor = id;
    label.textContent = path;
    const prop = modelProperty(schema, path);
    let input;
    if (prop && Array.isArray(prop.enum)) {  // a choice: the schema's values
      input = document.createElement("select");
      for (const choice of prop.enum) {
        const o = document.createElement("option");
        o.value = o.textContent = String(choice);
        input.append(o);
      }
      input.dataset.kind = "string";
    } else {
      input = document.createElement("input");
      input.dataset.kind = typeof value === "number" ? "number"
        : typeof value === "boolean" ? "boolean" : typeof value === "string" ? "string" : "json";
      input.readOnly = Boolean(prop && "const" in prop);
    }
    input.id = id;
    input.name = path;
    input.value = input.dataset.kind === "json" || input.dataset.kind === "boolean"
      ? JSON.stringify(value) : String(value);
    input.title = (prop && prop.description) || "";
    const msg = document.createElement("div");
    msg.className = "field-error";
    row.append(label, input, msg);
    fields.append(row);
  }
  fields.dataset.preset = name;
  state.scenario = preset.scenario;
  const axis = $("sweep-axis");
  axis.replaceChildren(...flatten(preset.scenario, "", [])
    .filter(([path, v]) => typeof v === "number" && path !== "seed")
    .map(([path]) => {
      const o = document.createElement("option");
      o.value = o.textContent = path;
      return o;
    }));
  const eta = [...axis.options].find((o) => o.value === "model.eta");
  if (eta) axis.value = eta.value;
}

function readForm() {
  const scenario = {};
  let ok = true;
  for (const row of $("fields").querySelectorAll(".field")) {
    const input = row.querySelector("input, select");
    const text = input.value.trim();
    let value = text;
    if (input.dataset.kind === "number") {
      value = text !== "" && Number.isFinite(Number(text)) ? Number(text) : text;
    } else if (input.dataset.kind !== "string") {
      try { value = JSON.parse(text); } catch (e) {
        ok = false;
        markField(row, "not valid JSON");
      }
    }
    setPath(scenario, row.dataset.path, value);
  }
  return ok ? scenario : null;
}

function clearMarks() {
  for (const row of $("fields").querySelectorAll(".field")) {
    row.classList.remove("invalid");
    row.querySelector(".field-error").textContent = "";
  }
  $("submit-error").textContent = "";
}

function markField(row, message) {
  row.classList.add("invalid");
  const el = row.querySelector(".field-error");
  el.textContent = el.textContent ? `${el.textContent}; ${message}` : message;
}

function showProblem(problem) {
  const rows = [...$("fields").querySelectorAll(".field")];
  const loose = [];
  for (const e of (problem && problem.errors) || []) {
    const loc = String(e.loc).replace(/^scenario\./, "");
    // the field itself, else the deepest field under the location (a whole block)
    const row = rows.find((r) => r.dataset.path === loc)
      || rows.find((r) => r.dataset.path.startsWith(loc + "."))
      || rows.filter((r) => loc.startsWith(r.dataset.path + ".")).pop();
    if (row) markField(row, e.msg);
    else loose.push(`${e.loc}: ${e.msg}`);
  }
  $("submit-error").textContent = loose.length ? loose.join("\n")
    : (problem && !(problem.errors || []).length ? problem.detail || problem.title : "");
}

$("preset").addEventListener("change", () => showPreset($("preset").value));

$("submit-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  clearMarks();
  const scenario = readForm();
  if (!scenario) return;
  $("submit").disabled = true;
  try {
    const job = await api("/v1/jobs", { method: "POST", body: JSON.stringify({ scenario }),
                                        headers: { "Content-Type": "application/json" } });
    await refreshLists();
    selectJob(job.id);
  } catch (err) {
    if (err.problem) showProblem(err.problem);
    else $("submit-error").textContent = err.message;
  } finally {
    $("submit").disabled = false;
  }
});

// A sweep of the form's scenario over one numeric field: the measure is the first of the
// model's default plots at the end of each run (the sweep plot draws it per value).
$("submit-sweep").addEventListener("click", async () => {
  clearMarks();
  const base = readForm();
  if (!base) return;
  const path = $("sweep-axis").value;
  const values = $("sweep-values").value.split(",").map((v) => v.trim()).filter((v) => v)
    .map((v) => (Number.isFinite(Number(v)) ? Number(v) : v));
  if (!values.length) { $("submit-error").textContent = "sweep: give the values, e.g. 0.5, 1, 2"; return; }
  const observable = defaultPlots(base.model && base.model.kind)[0];
  if (!observable) {
    $("submit-error").textContent = "sweep: the model's card names no observable to measure";
    return;
  }
  const body = { name: `${$("preset").value}-${path}`, base, replicas: Number($("sweep-replicas").value) || 1,
                 axes: [{ path, values }],
                 measure: { [observable]: { observable, reduce: "final" } } };
  $("submit-sweep").disabled = true;
  try {
    const sweep = await api("/v1/sweeps", { method: "POST", body: JSON.stringify(body),
                                            headers: { "Content-Type": "application/json" } });
    await refreshSweeps();
    selectSweep(sweep.id);
  } catch (err) {
    if (err.problem) showProblem(Object.assign({}, err.problem, { errors: (err.problem.errors || [])
      .map((e) => Object.assign({}, e, { loc: String(e.loc).replace(/^base\./, "") })) }));
    else $("submit-error").textContent = err.message;
  } finally {
    $("submit-sweep").disabled = false;
  }
});

// -- the job and sweep lists -------------------------------------------------------------

/** One list row: id, label, count, status and a progress bar; a click selects it. */
function listRow(item, selected, label, count, onSelect) {
  const tr = document.createElement("tr");
  tr.dataset.id = item.id;
  tr.className = item.id === selected ? "selected" : "";
  for (const [i, text] of [item.id.slice(0, 8), label, count, item.status].entries()) {
    const td = document.createElement("td");
    td.textContent = text;
    if (i === 0) td.className = "mono";
    if (i === 3) td.className = `status ${item.status}`;
    tr.append(td);
  }
  const td = document.createElement("td");
  const bar = document.createElement("progress");
  bar.max = 1;
  bar.value = item.progress;
  td.append(bar);
  tr.append(td);
  tr.addEventListener("click", () => onSelect(item.id));
  return tr;
}

/** Fetch a list route into state[key] and redraw its table (the key's problem shown). */
async function refreshList(path, key, stateId, tableSel, row) {
  try {
    state[key] = (await api(path)).items;
    $(stateId).textContent = "";
  } catch (err) {
    $(stateId).textContent = err.status === 401 ? "(enter the API key)" : `(${err.message})`;
    return;
  }
  document.querySelector(`${tableSel} tbody`).replaceChildren(...state[key].map(row));
}

function refreshJobs() {
  return refreshList("/v1/jobs?limit=30", "jobs", "list-state", "#jobs", (j) =>
    listRow(j, state.selected, j.model, String(j.n_agents), selectJob));
}

function sweepRuns(sw) {
  return `${sw.runs_done}/${sw.runs_total}` + (sw.runs_failed ? ` (${sw.runs_failed} failed)` : "");
}

function refreshSweeps() {
  return refreshList("/v1/sweeps?limit=30", "sweeps", "sweep-list-state", "#sweeps", (sw) =>
    listRow(sw, state.selectedSweep, sw.name || sw.model, sweepRuns(sw), selectSweep));
}

function refreshLists() {
  return Promise.all([refreshJobs(), refreshSweeps()]);
}

// -- one job: live status over SSE, then its results ---------------------------------------

function showJob(job) {
  $("job-id").textContent = job.id;
  const st = $("job-status");
  st.textContent = job.status;
  st.className = `status ${job.status}`;
  $("job-progress").value = job.progress;
  $("job-progress-text").textContent = `${Math.round(job.progress * 100)}%  `
    + `step ${job.steps_done}/${job.steps_total}`;
  $("cancel").disabled = state.terminal.includes(job.status);
  $("job-error").textContent = job.error ? `${job.error.title}: ${job.error.detail || ""}` : "";
  const row = document.querySelector(`#jobs tr[data-id="${job.id}"]`);
  if (row) {
    row.children[3].textContent = job.status;
    row.children[3].className = `status ${job.status}`;
    row.querySelector("progress").value = job.progress;
  }
}

/** Follow one job or sweep in the panel: its events until it ends, then its results;
 *  `live` (jobs) plots what arrives while it runs, until the results take over. */
async function follow(kind, id, { plotTitle, frames, show, load, live }) {
  if (state.follow) state.follow.abort();
  stopPlayer();
  state.selected = kind === "job" ? id : null;
  state.selectedSweep = kind === "sweep" ? id : null;
  markSelected();
  $("panel-kind").textContent = kind === "job" ? "Job" : "Sweep";
  $("plot-title").textContent = plotTitle;
  $("player").hidden = !frames;  // a sweep has no frames of its own
  $("downloads").replaceChildren();
  clearPlot();
  const ctl = new AbortController();
  state.follow = ctl;
  const liveCtl = new AbortController();
  ctl.signal.addEventListener("abort", () => liveCtl.abort());
  let last = null;
  try {
    await readEvents(`/v1/${kind}s/${id}/events`, ctl.signal, (event, data) => {
      if (event !== kind) return;
      const first = last === null;
      last = JSON.parse(data);
      show(last);
      if (first && live && !state.terminal.includes(last.status)) live(last, liveCtl.signal);
    });
  } catch (err) {
    if (ctl.signal.aborted) return;
    $("job-error").textContent = err.message;
    return;
  } finally {
    liveCtl.abort();  // the results (or nothing) replace the live plot
  }
  if (!ctl.signal.aborted && last && last.results === "available") await load(last);
}

function selectJob(id) {
  return follow("job", id, { plotTitle: "Observables", frames: true, show: showJob,
                             load: loadResults, live: followObservables });
}

async function readEvents(path, signal, onEvent) {
  const r = await fetch(path, { headers: authHeaders({ Accept: "text/event-stream" }), signal });
  if (!r.ok) throw new Error(`events: ${r.status} ${r.statusText}`);
  const reader = r.body.getReader();
  const decoder = new TextDecoder();
  let buf = "";
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buf += decoder.decode(value, { stream: true });
    let cut;
    while ((cut = buf.indexOf("\n\n")) >= 0) {
      const chunk = buf.slice(0, cut);
      buf = buf.slice(cut + 2);
      let event = "message", data = "";
      for (const line of chunk.split("\n")) {
        if (line.startsWith("event:")) event = line.slice(6).trim();
        else if (line.startsWith("data:")) data += line.slice(5).trim();
      }
      if (event === "end") return;
      onEvent(event, data);
    }
  }
}

$("cancel").addEventListener("click", async () => {
  try {
    if (state.selectedSweep) {
      showSweep(await api(`/v1/sweeps/${state.selectedSweep}/cancel`, { method: "POST" }));
    } else if (state.selected) {
      showJob(await api(`/v1/jobs/${state.selected}/cancel`, { method: "POST" }));
    }
  } catch (err) { $("job-error").textContent = err.message; }
});

function markSelected() {
  for (const tr of document.querySelectorAll("#jobs tbody tr")) {
    tr.classList.toggle("selected", tr.dataset.id === state.selected);
  }
  for (const tr of document.querySelectorAll("#sweeps tbody tr")) {
    tr.classList.toggle("selected", tr.dataset.id === state.selectedSweep);
  }
}

// -- one sweep: live status over SSE, then its table plotted -------------------------------

function showSweep(sw) {
  $("job-id").textContent = sw.id;
  const st = $("job-status");
  st.textContent = sw.status;
  st.className = `status ${sw.status}`;
  $("job-progress").value = sw.progress;
  $("job-progress-text").textContent = `${Math.round(sw.progress * 100)}%  runs ${sweepRuns(sw)}`;
  $("cancel").disabled = state.terminal.includes(sw.status);
  $("job-error").textContent = sw.error ? `${sw.error.title}: ${sw.error.detail || ""}` : "";
  const row = document.querySelector(`#sweeps tr[data-id="${sw.id}"]`);
  if (row) {
    row.children[2].textContent = sweepRuns(sw);
    row.children[3].textContent = sw.status;
    row.children[3].className = `status ${sw.status}`;
    row.querySelector("progress").value = sw.progress;
  }
}

function selectSweep(id) {
  return follow("sweep", id, { plotTitle: "Measures", frames: false, show: showSweep,
                               load: loadSweepResults });
}

async function loadSweepResults(sw) {
  const base = `/v1/sweeps/${sw.id}`;
  const short = sw.id.slice(0, 8);
  $("downloads").replaceChildren(
    downloadButton("table.csv", `${base}/table?format=csv`, `${short}-table.csv`),
    downloadButton("runs.csv", `${base}/runs?format=csv`, `${short}-runs.csv`),
    downloadButton("plot.png", `${base}/render/plot.png`, `${short}-plot.png`));
  const [spec, table] = await Promise.all([api(`${base}/spec`), api(`${base}/table?format=json`)]);
  drawSweepPlot(spec, table);
}

function downloadButton(label, path, filename) {
  const b = document.createElement("button");
  b.textContent = label;
  b.dataset.href = path;
  b.addEventListener("click", async () => {
    const r = await fetch(path, { headers: authHeaders() });
    if (!r.ok) { $("job-error").textContent = `${label}: ${r.status} ${r.statusText}`; return; }
    const url = URL.createObjectURL(await r.blob());
    const a = document.createElement("a");
    a.href = url;
    a.download = filename;
    a.click();
    setTimeout(() => URL.revokeObjectURL(url), 10000);
  });
  return b;
}

async function loadResults(job) {
  const base = `/v1/jobs/${job.id}`;
  const short = job.id.slice(0, 8);
  $("downloads").replaceChildren(
    downloadButton("trajectory.h5", `${base}/trajectory.h5`, `${short}.h5`),
    downloadButton("metrics.json", `${base}/metrics`, `${short}-metrics.json`),
    downloadButton("snapshot.png", `${base}/render/snapshot.png`, `${short}-snapshot.png`),
    downloadButton("observables.png", `${base}/render/observables.png`, `${short}-obs.png`),
    downloadButton("movie.mp4", `${base}/render/movie.mp4`, `${short}.mp4`));
  const metrics = await api(`${base}/metrics`);
  drawPlot(metrics, job.model);
  const frames = metrics.summary.frames || 0;
  if (frames > 0) await loadTrajectory(job, frames);
}

// -- playback -----------------------------------------------------------------------------

// 3D jobs are seen through the renderer's camera (service/render/projection.py): an
// orthographic view from azimuth -60°, elevation 30°; agents far from the viewer are
// drawn first and paler, in DEPTHS bands of depth.
const CAMERA = (() => {
  const th = 30 * Math.PI / 180, ph = -60 * Math.PI / 180;
  return { right: [-Math.sin(ph), Math.cos(ph), 0],
           up: [-Math.sin(th) * Math.cos(ph), -Math.sin(th) * Math.sin(ph), Math.cos(th)],
           eye: [Math.cos(th) * Math.cos(ph), Math.cos(th) * Math.sin(ph), Math.sin(th)] };
})();
const DEPTHS = 4;
const dot3 = (a, x, y, z) => a[0] * x + a[1] * y + a[2] * z;

async function loadTrajectory(job, frames) {
  // one agent of one frame first: the state's dimension (2 or 3) sizes the budget
  const probe = await api(`/v1/jobs/${job.id}/trajectory?format=json&stop=1&agents=0`
                          + "&arrays=position");
  const dim = probe.position[0][0].length;
  const n = job.n_agents;
  const perAgentFrame = 2 * dim * 8;  // position + velocity (or heading) as float64
  const agentStride = Math.max(1, Math.ceil(n * perAgentFrame / TRAJECTORY_BUDGET));
  const shown = Math.ceil(n / agentStride);
  const stride = Math.max(1, Math.ceil(frames * shown * perAgentFrame / TRAJECTORY_BUDGET));
  const query = `stride=${stride}` + (agentStride > 1 ? `&agents=0:${n}:${agentStride}` : "");
  const r = await fetch(`/v1/jobs/${job.id}/trajectory?${query}`, { headers: authHeaders() });
  if (!r.ok) { $("job-error").textContent = `trajectory: ${r.status}`; return; }
  const arrays = readNpz(await r.arrayBuffer());
  setPlayer(arrays);
}

/** Each agent's unit heading in frame-agent i, as [x, y, z]: the recorded heading (an
 *  angle in 2D, a unit vector in 3D), else the velocity's direction, else the x axis. */
function headingReader(arrays, dim) {
  const h = arrays.heading, v = arrays.velocity;
  if (h && h.shape.length === 2) return (i) => [Math.cos(h.data[i]), Math.sin(h.data[i]), 0];
  const vec = h || v;
  if (!vec) return () => [1, 0, 0];
  const d = vec.data;
  return (i) => {
    const x = d[dim * i], y = d[dim * i + 1], z = dim === 3 ? d[dim * i + 2] : 0;
    const len = Math.hypot(x, y, z);
    return len > 0 ? [x / len, y / len, z / len] : [1, 0, 0];
  };
}

/** The frames as what a drawing needs, computed once: each agent's picture (sx, sy), its
 *  unit heading as seen (ux, uy) and its colour bucket (depth band x heading hue, the
 *  hue from the heading's azimuth); in 3D the box around every frame, as a wireframe. */
function setPlayer(arrays) {
  const pos = arrays.position;
  const [frames, n] = pos.shape;
  const dim = pos.shape[2] || 2;
  const count = frames * n;
  const p = pos.data;
  const heading = headingReader(arrays, dim);
  const sx = new Float32Array(count), sy = new Float32Array(count);
  const ux = new Float32Array(count), uy = new Float32Array(count);
  const depth = dim === 3 ? new Float32Array(count) : null;
  const bucket = new Uint8Array(count);
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < count; i++) {
    const x = p[dim * i], y = p[dim * i + 1], z = dim === 3 ? p[dim * i + 2] : 0;
    const [hx, hy, hz] = heading(i);
    if (depth) {
      sx[i] = dot3(CAMERA.right, x, y, z);
      sy[i] = dot3(CAMERA.up, x, y, z);
      depth[i] = dot3(CAMERA.eye, x, y, z);
      ux[i] = dot3(CAMERA.right, hx, hy, hz);
      uy[i] = dot3(CAMERA.up, hx, hy, hz);
    } else {
      sx[i] = x; sy[i] = y; ux[i] = hx; uy[i] = hy;
    }
    if (x < lo[0]) lo[0] = x; if (x > hi[0]) hi[0] = x;
    if (y < lo[1]) lo[1] = y; if (y > hi[1]) hi[1] = y;
    if (z < lo[2]) lo[2] = z; if (z > hi[2]) hi[2] = z;
    const turn = (Math.atan2(hy, hx) + Math.PI) / (2 * Math.PI);
    let b = Math.floor((turn - Math.floor(turn)) * HUES);
    if (!(b >= 0 && b < HUES)) b = 0;
    bucket[i] = b;
  }
  const box = depth ? wireframe(lo, hi) : null;
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const [x, y] of box ? box.corners : [[lo[0], lo[1]], [hi[0], hi[1]]]) {
    if (x < x0) x0 = x; if (x > x1) x1 = x; if (y < y0) y0 = y; if (y > y1) y1 = y;
  }
  if (depth) {  // the depth band: 0 the farthest .. DEPTHS - 1 the nearest (2D: nearest)
    const span = Math.max(box.near - box.far, 1e-12);
    for (let i = 0; i < count; i++) {
      const band = Math.min(DEPTHS - 1, Math.floor((depth[i] - box.far) / span * DEPTHS));
      bucket[i] += HUES * Math.max(0, band);
    }
  } else {
    for (let i = 0; i < count; i++) bucket[i] += HUES * (DEPTHS - 1);
  }
  const half = Math.max(x1 - x0, y1 - y0, 1e-9) / 2 * 1.05;
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
  state.player = { frames, n, dim, sx, sy, ux, uy, bucket, box,
                   time: arrays.time ? arrays.time.data : null,
                   step: arrays.step ? arrays.step.data : null, frame: 0, playing: false,
                   view: [cx - half, cy - half, 2 * half], acc: 0, last: 0,
                   order: new Int32Array(n), counts: new Int32Array(BUCKETS + 1), draws: 0,
                   fpsSince: performance.now() };
  $("scrub").max = String(frames - 1);
  $("scrub").value = "0";
  $("scrub").disabled = false;
  $("play").disabled = false;
  drawFrame(0);
}

/** The box lo..hi seen through the camera: its corners' pictures, its 12 edges (those
 *  meeting at the farthest corner hidden), and its depth range. */
function wireframe(lo, hi) {
  const corners = [], depths = [];
  for (let c = 0; c < 8; c++) {
    const x = c & 4 ? hi[0] : lo[0], y = c & 2 ? hi[1] : lo[1], z = c & 1 ? hi[2] : lo[2];
    corners.push([dot3(CAMERA.right, x, y, z), dot3(CAMERA.up, x, y, z)]);
    depths.push(dot3(CAMERA.eye, x, y, z));
  }
  const far = depths.indexOf(Math.min(...depths));
  const edges = [];
  for (let a = 0; a < 8; a++) {
    for (const bit of [1, 2, 4]) {
      if (!(a & bit)) edges.push([a, a | bit, a === far || (a | bit) === far]);
    }
  }
  return { corners, edges, far: Math.min(...depths), near: Math.max(...depths) };
}

function stopPlayer() {
  if (state.player) state.player.playing = false;
  state.player = null;
  $("play").textContent = "Play";
  $("play").disabled = true;
  $("scrub").disabled = true;
  const c = $("canvas");
  c.getContext("2d").clearRect(0, 0, c.width, c.height);
  $("frame-info").textContent = "";
  $("fps").textContent = "";
}

// Colour buckets: depth band (far ones paler, mixed towards white) x heading hue.
const BUCKETS = DEPTHS * HUES;
const BUCKET_COLOURS = Array.from({ length: BUCKETS }, (_, k) => {
  const band = Math.floor(k / HUES), hue = k % HUES;
  return `hsl(${(hue + 0.5) * 360 / HUES}, 90%, ${45 + (DEPTHS - 1 - band) * 12}%)`;
});

function drawFrame(k) {
  const pl = state.player;
  if (!pl) return;
  const canvas = $("canvas");
  const ctx = canvas.getContext("2d");
  const size = canvas.width;
  const [vx, vy, vw] = pl.view;
  const s = size / vw;
  const base = k * pl.n;
  // counting sort of the agents by bucket: one stroke per colour, far bands first
  const counts = pl.counts;
  counts.fill(0);
  for (let i = 0; i < pl.n; i++) counts[pl.bucket[base + i] + 1]++;
  for (let b = 0; b < BUCKETS; b++) counts[b + 1] += counts[b];
  const fill = counts.slice(0, BUCKETS);
  for (let i = 0; i < pl.n; i++) pl.order[fill[pl.bucket[base + i]]++] = i;
  ctx.fillStyle = "#fff";
  ctx.fillRect(0, 0, size, size);
  if (pl.box) drawWireframe(ctx, pl.box, (x) => (x - vx) * s, (y) => size - (y - vy) * s);
  const len = pl.n > 2000 ? 4 : pl.n > 200 ? 7 : 12;
  ctx.lineWidth = pl.n > 2000 ? 1 : 2;
  for (let b = 0; b < BUCKETS; b++) {
    if (counts[b] === counts[b + 1]) continue;
    ctx.strokeStyle = BUCKET_COLOURS[b];
    ctx.beginPath();
    for (let j = counts[b]; j < counts[b + 1]; j++) {
      const i = base + pl.order[j];
      const x = (pl.sx[i] - vx) * s, y = size - (pl.sy[i] - vy) * s;
      const u = len * pl.ux[i], v = len * pl.uy[i];
      ctx.moveTo(x - 0.3 * u, y + 0.3 * v);
      ctx.lineTo(x + u, y - v);
    }
    ctx.stroke();
  }
  pl.frame = k;
  pl.draws++;
  $("scrub").value = String(k);
  const t = pl.time ? pl.time[k] : k;
  $("frame-info").textContent = `frame ${k + 1}/${pl.frames}  t = ${Number(t).toPrecision(4)}`
    + (pl.dim === 3 ? "  (3D: paler = farther)" : "");
}

function drawWireframe(ctx, box, X, Y) {
  ctx.lineWidth = 1;
  ctx.strokeStyle = "#999";
  for (const hidden of [true, false]) {
    ctx.setLineDash(hidden ? [3, 3] : []);
    ctx.beginPath();
    for (const [a, b, back] of box.edges) {
      if (back !== hidden) continue;
      ctx.moveTo(X(box.corners[a][0]), Y(box.corners[a][1]));
      ctx.lineTo(X(box.corners[b][0]), Y(box.corners[b][1]));
    }
    ctx.stroke();
  }
  ctx.setLineDash([]);
}

function tick(now) {
  const pl = state.player;
  if (!pl || !pl.playing) return;
  const speed = Number($("speed").value);
  pl.acc += (now - (pl.last || now)) / 1000 * BASE_FPS * speed;
  pl.last = now;
  const advance = Math.floor(pl.acc);
  if (advance > 0) {
    pl.acc -= advance;
    drawFrame((pl.frame + advance) % pl.frames);
  }
  if (now - pl.fpsSince > 1000) {
    $("fps").textContent = `${(pl.draws * 1000 / (now - pl.fpsSince)).toFixed(0)} fps`;
    pl.draws = 0;
    pl.fpsSince = now;
  }
  requestAnimationFrame(tick);
}

$("play").addEventListener("click", () => {
  const pl = state.player;
  if (!pl) return;
  pl.playing = !pl.playing;
  $("play").textContent = pl.playing ? "Pause" : "Play";
  if (pl.playing) {
    pl.last = 0;
    pl.draws = 0;
    pl.fpsSince = performance.now();
    requestAnimationFrame(tick);
  }
});

$("scrub").addEventListener("input", () => drawFrame(Number($("scrub").value)));

// Draws `count` frames back to back and returns frames per second (the browser test's
// playback measurement; the display's refresh rate caps the live counter, not this).
function measurePlayback(count) {
  const pl = state.player;
  if (!pl) return null;
  const t0 = performance.now();
  for (let i = 0; i < count; i++) drawFrame(i % pl.frames);
  const ctx = $("canvas").getContext("2d");
  ctx.getImageData(0, 0, 1, 1);  // wait for the drawing to finish
  return count / ((performance.now() - t0) / 1000);
}

// -- observables --------------------------------------------------------------------------

const LIVE_POLL_MS = 1000;  // between asks for a running job's new observation rows

/** Plot a running job's observables as they arrive: ask for the rows after those held
 *  (`start`), append, redraw; until `signal` aborts (the job ended: its results draw the
 *  final plot) or the service says the series is final. */
async function followObservables(job, signal) {
  const held = {};
  let rows = 0;
  while (!signal.aborted) {
    let body = null;
    try {
      body = await api(`/v1/jobs/${job.id}/observables?start=${rows}`, { signal });
    } catch (err) {
      if (signal.aborted) return;  // a failed ask is retried at the next poll
    }
    if (body && !signal.aborted) {
      for (const [name, values] of Object.entries(body.observables)) {
        const col = held[name] || (held[name] = []);
        for (const v of values) col.push(v);
      }
      rows += body.rows;
      if (body.rows) drawPlot({ observables: held, summary: {} }, job.model);
      if (!body.partial) return;
      if (body.more) continue;
    }
    await new Promise((resolve) => {
      const t = setTimeout(resolve, LIVE_POLL_MS);
      signal.addEventListener("abort", () => { clearTimeout(t); resolve(); }, { once: true });
    });
  }
}

function clearPlot() {
  const c = $("plot");
  c.getContext("2d").clearRect(0, 0, c.width, c.height);
  $("plot-legend").textContent = "";
}

function drawPlot(metrics, model) {
  const obs = metrics.observables;
  const names = defaultPlots(model).filter((n) => n in obs);
  if (!names.length) names.push(...Object.keys(obs).filter((n) => n !== "step" && n !== "time").slice(0, 3));
  const t = obs.time || [];
  const c = $("plot");
  const ctx = c.getContext("2d");
  ctx.clearRect(0, 0, c.width, c.height);
  const panel = c.height / Math.max(1, names.length);
  const tmax = t.length ? t[t.length - 1] : 1;
  const conv = (metrics.summary && metrics.summary.convergence) || {};
  ctx.font = "11px sans-serif";
  // Long series: at most about two points per pixel column (every k-th row).
  const every = Math.max(1, Math.floor(t.length / (2 * c.width)));
  names.forEach((name, p) => {
    let lo = Infinity, hi = -Infinity;  // a loop: spreading 10^5 values overflows the stack
    for (const v of obs[name]) {
      if (v !== null) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    }
    const top = p * panel + 14, h = panel - 24, left = 50, w = c.width - 60;
    ctx.strokeStyle = "#ccd";
    ctx.strokeRect(left, top, w, h);
    ctx.fillStyle = "#334";
    ctx.fillText(name, left + 4, top - 3);
    ctx.fillText(hi.toPrecision(3), 2, top + 9);
    ctx.fillText(lo.toPrecision(3), 2, top + h);
    ctx.strokeStyle = "#1565c0";
    ctx.beginPath();
    obs[name].forEach((v, i) => {
      if (v === null || (i % every && i !== t.length - 1)) return;
      const x = left + (t[i] / (tmax || 1)) * w;
      const y = top + h - (hi > lo ? (v - lo) / (hi - lo) : 0.5) * h;
      if (i === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
    });
    ctx.stroke();
    if (typeof conv[name] === "number") {
      const x = left + (conv[name] / (tmax || 1)) * w;
      ctx.strokeStyle = "#c62828";
      ctx.setLineDash([4, 3]);
      ctx.beginPath(); ctx.moveTo(x, top); ctx.lineTo(x, top + h); ctx.stroke();
      ctx.setLineDash([]);
    }
  });
  $("plot-legend").textContent = `time 0 … ${Number(tmax).toPrecision(4)}`
    + (Object.keys(conv).length ? "; dashed: convergence time" : "");
}

const CURVE_COLOURS = ["#1565c0", "#c62828", "#2e7d32", "#6a1b9a", "#ef6c00", "#00838f"];

function axisPath(axis) {
  if (typeof axis === "string") return axis;
  if (axis && axis.path) return axis.path;
  return axis && axis.zip && axis.zip.length ? axisPath(axis.zip[0]) : null;
}

// Each measure's mean against the first axis, one curve per value of the second, with
// the replicas' standard error as bars (the sweep plot of `flocklab render SWEEP_DIR`).
function drawSweepPlot(spec, table) {
  const c = $("plot");
  const ctx = c.getContext("2d");
  ctx.clearRect(0, 0, c.width, c.height);
  const col = (name) => table.columns.indexOf(name);
  const axes = (spec.axes || []).map(axisPath).filter((p) => p && col(p) >= 0);
  const measures = table.columns.filter((n) => n.endsWith("_mean")).map((n) => n.slice(0, -5));
  if (!axes.length || !measures.length || !table.data.length) {
    $("plot-legend").textContent = "no measures to plot";
    return;
  }
  const xi = col(axes[0]), gi = axes.length > 1 ? col(axes[1]) : -1;
  const groups = [...new Set(table.data.map((r) => (gi >= 0 ? String(r[gi]) : "")))];
  const xs = table.data.map((r) => Number(r[xi]));
  const x0 = Math.min(...xs), x1 = Math.max(...xs);
  const shown = measures.slice(0, 3);
  const panel = c.height / shown.length;
  ctx.font = "11px sans-serif";
  shown.forEach((m, p) => {
    const mi = col(`${m}_mean`), ei = col(`${m}_sem`) >= 0 ? col(`${m}_sem`) : col(`${m}_sd`);
    const rows = table.data.filter((r) => r[mi] !== null);
    const lo = Math.min(...rows.map((r) => r[mi] - (ei >= 0 && r[ei] !== null ? r[ei] : 0)));
    const hi = Math.max(...rows.map((r) => r[mi] + (ei >= 0 && r[ei] !== null ? r[ei] : 0)));
    const top = p * panel + 14, h = panel - 24, left = 50, w = c.width - 60;
    const X = (x) => left + (x1 > x0 ? (x - x0) / (x1 - x0) : 0.5) * w;
    const Y = (y) => top + h - (hi > lo ? (y - lo) / (hi - lo) : 0.5) * h;
    ctx.strokeStyle = "#ccd";
    ctx.strokeRect(left, top, w, h);
    ctx.fillStyle = "#334";
    ctx.fillText(`${m} against ${axes[0]}`, left + 4, top - 3);
    ctx.fillText(hi.toPrecision(3), 2, top + 9);
    ctx.fillText(lo.toPrecision(3), 2, top + h);
    groups.forEach((g, k) => {
      const pts = rows.filter((r) => gi < 0 || String(r[gi]) === g)
        .map((r) => [Number(r[xi]), r[mi], ei >= 0 ? r[ei] : null]).sort((a, b) => a[0] - b[0]);
      ctx.strokeStyle = ctx.fillStyle = CURVE_COLOURS[k % CURVE_COLOURS.length];
      ctx.beginPath();
      pts.forEach(([x, y], i) => (i ? ctx.lineTo(X(x), Y(y)) : ctx.moveTo(X(x), Y(y))));
      ctx.stroke();
      for (const [x, y, e] of pts) {
        ctx.fillRect(X(x) - 2, Y(y) - 2, 4, 4);
        if (e) { ctx.beginPath(); ctx.moveTo(X(x), Y(y - e)); ctx.lineTo(X(x), Y(y + e)); ctx.stroke(); }
      }
    });
  });
  $("plot-legend").textContent = `${axes[0]} ${x0} … ${x1}`
    + (gi >= 0 ? `; one curve per ${axes[1]}: ${groups.join(", ")}` : "")
    + "; bars: standard error over replicas";
}

// -- start --------------------------------------------------------------------------------

let listTimer = null;

async function start() {
  showKeyState();
  try {
    state.presets = await api("/v1/presets");
    state.models = await api("/v1/models");
    state.terminal = terminalStates(await api("/openapi.json"));
  } catch (err) {
    $("list-state").textContent = err.status === 401 ? "(enter the API key)" : `(${err.message})`;
    return;
  }
  const sel = $("preset");
  sel.replaceChildren(...state.presets.map((p) => {
    const o = document.createElement("option");
    o.value = p.name;
    o.textContent = p.name;
    o.title = p.description;
    return o;
  }));
  await showPreset(sel.value);
  await refreshLists();
  if (listTimer === null) listTimer = setInterval(refreshLists, 2000);
}

window.flocklabViewer = { state, measurePlayback, drawFrame, selectJob, selectSweep,
                          defaultPlots };
start();
