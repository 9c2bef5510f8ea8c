// micam's operator page: draws the state that `micam web` sends over its WebSocket, and sends
// the operator's commands. No framework: a state object, one render function per part.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const WAITING = ["references", "reference_microphone", "waiting_for_pose"];
const SESSION_STATES = [...WAITING, "session_open", "capturing", "paused"];
let state = {};
// For tests and benchmarks: every event's seq as it arrived, and its delay (ms) from the
// daemon's time stamp to its arrival here (both clocks are this machine's when local).
window.micam = { seen: [], latencies: [], updates: 0, snapshots: 0 };

function el(tag, attrs = {}, text = null, ns = null) {
  const node = ns ? document.createElementNS(ns, tag) : document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (text !== null) node.textContent = text;
  return node;
}
const svg = (tag, attrs = {}, text = null) => el(tag, attrs, text, SVG);
const $ = (id) => document.getElementById(id);
const plural = (n, noun) => `${n} ${noun}${n === 1 ? "" : "s"}`;
const mm = (m, digits = 3) => (m === null || m === undefined) ? "n/a" : (m * 1e3).toFixed(digits) + " mm";

// -- the connection --------------------------------------------------------------------------

function connect(delay = 500) {
  const ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws");
  ws.onmessage = (message) => {
    const data = JSON.parse(message.data);
    if (data.kind === "snapshot") {
      state = data.state;
      window.micam.snapshots += 1;
      render(Object.keys(state));
    } else if (data.kind === "update") {
      Object.assign(state, data.state);
      window.micam.updates += 1;
      if (data.event) arrived(data.event);
      render(Object.keys(data.state).concat(data.event && data.event.line ? ["log"] : []));
    }
  };
  ws.onopen = () => { delay = 500; };
  ws.onclose = () => {
    document.body.dataset.state = "disconnected";
    $("daemon").textContent = "page disconnected: reconnecting";
    $("daemon").className = "badge bad";
    setTimeout(() => connect(Math.min(delay * 2, 5000)), delay);
  };
}

function arrived(event) {
  const m = window.micam;
  m.seen.push(event.seq);
  m.latencies.push(Date.now() - Date.parse(event.time_utc));
  if (m.seen.length > 20000) { m.seen.splice(0, 10000); m.latencies.splice(0, 10000); }
  if (event.line) {
    state.log = (state.log || []).concat([{ seq: event.seq, time_utc: event.time_utc, line: event.line }]).slice(-100);
  }
}

const RENDER = {
  daemon: renderHeader, status: renderHeader, progress: renderHeader, describe: renderAll,
  cameras: renderCameras, previews: renderCameras, live: renderLive, live_history: renderLive,
  levels: renderLevels, sessions: renderSessions, log: renderLog, live_stream: renderLiveStream,
  live_view: renderLiveView,
};

function render(keys) {
  const done = new Set();
  for (const key of keys) {
    const f = RENDER[key];
    if (f && !done.has(f)) { done.add(f); f(); }
  }
  if (keys.includes("status") || keys.includes("live")) { renderCameras(); renderControls(); renderLiveStream(); }
}

function renderAll() { renderHeader(); renderCameras(); renderLevels(); renderLive(); renderLiveStream(); renderSessions(); renderLog(); }

// -- header and control ----------------------------------------------------------------------

function renderHeader() {
  const daemon = state.daemon || {};
  const status = state.status;
  const badge = $("daemon");
  badge.textContent = daemon.connected ? "daemon connected" : ("daemon unreachable: " + (daemon.error || ""));
  badge.className = "badge " + (daemon.connected ? "good" : "bad");
  if (!status) return;
  document.body.dataset.state = status.state;
  $("state").textContent = status.state.replace(/_/g, " ") + (status.simulated ? " (simulated)" : "");
  $("state").className = "badge state-" + status.state;
  const s = status.session;
  $("session").textContent = s ? s.id : (status.resumable ? "no session (" + status.resumable + " can be resumed)" : "no session");
  const progress = $("progress");
  if (s) {
    progress.dataset.poses = s.poses_done;
    progress.dataset.steps = s.steps_done;
    progress.querySelector(".bar").style.width = (100 * s.steps_done / Math.max(1, s.steps_total)) + "%";
    progress.querySelector(".text").textContent = `${s.steps_done}/${s.steps_total} steps, ${s.poses_done}/${s.n_poses} poses`;
  } else {
    progress.querySelector(".bar").style.width = "0%";
    progress.querySelector(".text").textContent = "";
  }
  $("instruction").textContent = status.step ? `${status.step}: ${status.instruction || ""}` : "";
  const last = status.last_capture;
  $("last-capture").textContent = last ? `last capture ${last.number}: ${last.step} ${last.outcome}` +
    (last.reason ? ` (${last.reason})` : "") + (last.warnings.length ? ` (${last.warnings.join("; ")})` : "") : "";
  renderControls();
}

function renderControls() {
  const status = state.status;
  const st = status ? status.state : "unknown";
  const connected = state.daemon && state.daemon.connected;
  const inSession = SESSION_STATES.includes(st);
  const enable = {
    start: st === "idle", capture: WAITING.includes(st) || st === "session_open",
    redo: st === "capturing", pause: WAITING.includes(st) || st === "capturing",
    resume: st === "paused", stop: inSession, abort: inSession,
    "live-start": st === "idle", "live-record": st === "live", "live-stop": st === "live",
  };
  for (const [id, on] of Object.entries(enable)) $(id).disabled = !(connected && on);
  const d = state.describe;
  if (d && !$("start-poses").value) $("start-poses").placeholder = String(d.n_poses);
  const list = $("resumable");
  const wanted = ["last"].concat(status && status.resumable ? [status.resumable] : []);
  if (list.children.length !== wanted.length) {
    list.replaceChildren(...wanted.map((v) => el("option", { value: v })));
  }
}

async function command(name, args = {}, extra = {}) {
  const message = $("message");
  message.textContent = name + "…";
  message.className = "message";
  try {
    const reply = await fetch("/api/command", {
      method: "POST", headers: { "content-type": "application/json" },
      body: JSON.stringify({ command: name, args, ...extra }),
    });
    const data = await reply.json();
    message.textContent = data.ok ? `${name}: done` : `${name}: ${data.error}`;
    message.className = "message " + (data.ok ? "good" : "bad");
  } catch (error) {
    message.textContent = `${name}: the page cannot reach micam web (${error})`;
    message.className = "message bad";
  }
}

function setUpControls() {
  $("start-form").addEventListener("submit", (e) => {
    e.preventDefault();
    const poses = $("start-poses").value;
    const resume = $("start-resume").value.trim();
    command("session.start", { poses: poses ? Number(poses) : null, resume: resume || null });
  });
  for (const button of document.querySelectorAll("button[data-command]")) {
    button.addEventListener("click", () => {
      const name = button.dataset.command;
      if (name === "session.abort") {
        if (!window.confirm("Abort the session? It ends for good and cannot be continued.")) return;
        command(name, {}, { confirm: true });
      } else {
        command(name);
      }
    });
  }
}

// -- the live acoustic view ------------------------------------------------------------------
function renderLiveStream() {
  // The newest map over camera 0 while the daemon is live (micam web --geometry draws them),
  // its colour scale in dB and the array's mean spectrum, both of the settings it was drawn with.
  const live = state.status && state.status.live;
  const frame = state.live_stream;
  const img = $("live-stream");
  const showing = Boolean(live && frame && frame.jpeg_b64);
  img.classList.toggle("hidden", !showing);
  $("live-colourbar").classList.toggle("hidden", !showing);
  $("live-spectrum").classList.toggle("hidden", !(showing && frame.spectrum));
  if (showing) {
    const src = "data:image/jpeg;base64," + frame.jpeg_b64;
    if (img.getAttribute("src") !== src) img.setAttribute("src", src);
    img.dataset.sample = String(frame.sample);
    img.dataset.band = String(frame.settings.band_hz);
    img.dataset.range = String(frame.settings.range_db);
    drawColourBar(frame.settings.range_db);
    if (frame.spectrum) drawSpectrum(frame.spectrum, frame.settings);
  } else {
    img.removeAttribute("src"); // no last map stays once live mode ends
    for (const key of ["sample", "band", "range"]) delete img.dataset[key];
  }
  $("live-stream-info").textContent = live
    ? `${live.held_s.toFixed(1)} s kept, ${(1e3 * live.behind_s).toFixed(0)} ms behind` : "";
  $("live-stream-note").textContent = !live ? "not live" : frame && frame.error
    ? frame.error : frame ? `${bandName(frame.settings)}, plane at ${frame.settings.depth_m} m, ` +
      `latency ${frame.latency_ms} ms` : "no map (micam web --geometry)";
}

const bandName = (v) => `${Math.round(v.band_hz)} Hz ${v.fraction === 1 ? "octave" : "1/3 octave"}`;
const kHz = (f) => f >= 1000 ? `${+(f / 1000).toFixed(1)}k` : String(Math.round(f));
// Matplotlib's inferno (what the map is drawn with, OpenCV's COLORMAP_INFERNO) at nine stops.
const INFERNO = ["#000004", "#1f0c48", "#550f6d", "#88226a", "#ba3655", "#e35933", "#f98c0a", "#f9c932", "#fcffa4"];

function drawColourBar(rangeDb) {
  // The map's colours from its peak (0 dB, top) down to -range (bottom, drawn transparent).
  const bar = $("live-colourbar");
  if (bar.dataset.range === String(rangeDb)) return;
  bar.dataset.range = String(rangeDb);
  const ramp = el("div", { class: "ramp" });
  ramp.style.background = `linear-gradient(to bottom, ${INFERNO.slice().reverse().join(", ")})`;
  bar.replaceChildren(el("span", { class: "title" }, "dB re peak"), ramp);
  const step = rangeDb <= 12 ? 2 : rangeDb <= 30 ? 5 : 10;
  for (let db = 0; db >= -rangeDb - 1e-9; db -= step) {
    const tick = el("span", { class: "tick" }, String(db));
    tick.style.top = `calc(22px + (100% - 30px) * ${-db / rangeDb})`;
    bar.append(tick);
  }
}

function drawSpectrum(spectrum, view) {
  // Third-octave band levels, the mean of the microphones' (dB re 1 V²); the bands the map
  // shows in yellow; a click on a band maps it.
  const chart = $("live-spectrum");
  const W = 800, H = 170, left = 52, right = 8, top = 10, bottom = 40;
  const levels = spectrum.levels_db, centres = spectrum.centres_hz;
  const topDb = 10 * Math.ceil(Math.max(...levels) / 10), spanDb = 60;
  const y = (db) => top + (H - top - bottom) * Math.min(1, Math.max(0, (topDb - db) / spanDb));
  const w = (W - left - right) / centres.length;
  const half = 2 ** (1 / (2 * view.fraction));
  const nodes = [];
  for (let db = topDb; db >= topDb - spanDb; db -= 10) {
    nodes.push(svg("line", { x1: left, x2: W - right, y1: y(db), y2: y(db), class: "grid" }),
      svg("text", { x: left - 4, y: y(db) + 4, "text-anchor": "end", class: "axis" }, String(db)));
  }
  centres.forEach((c, i) => {
    const chosen = c >= view.band_hz / half * 0.999 && c <= view.band_hz * half * 1.001;
    const bar = svg("rect", { x: left + i * w + 1, y: y(levels[i]), width: w - 2, height: H - bottom - y(levels[i]),
      class: "bar" + (chosen ? " chosen" : ""), "data-centre": c });
    bar.append(svg("title", {}, `${kHz(c)} Hz: ${levels[i].toFixed(1)} dB`));
    bar.addEventListener("click", () => applyLiveView({ band_hz: c, fraction: 3 }));
    nodes.push(bar);
    if (Math.abs(Math.log2(c / 1000) % 1) < 1e-6) { // label the octave centres
      nodes.push(svg("text", { x: left + (i + 0.5) * w, y: H - bottom + 14, "text-anchor": "middle", class: "axis" }, kHz(c)));
    }
  });
  nodes.push(svg("rect", { x: left, y: top, width: W - left - right, height: H - top - bottom, class: "frame" }),
    svg("text", { x: left + (W - left - right) / 2, y: H - 6, "text-anchor": "middle", class: "axis" },
      "third-octave band centre (Hz); click a band to map it"),
    svg("text", { x: 12, y: top + (H - top - bottom) / 2, transform: `rotate(-90 12 ${top + (H - top - bottom) / 2})`,
      "text-anchor": "middle", class: "axis" }, "dB re 1 V²"));
  chart.replaceChildren(...nodes);
}

function renderLiveView() {
  // The controls of the live view, as the page's server holds them (an edit in progress stays).
  const view = state.live_view;
  $("live-view-form").classList.toggle("hidden", !view);
  if (!view) return;
  const set = (id, value) => { if (document.activeElement !== $(id)) $(id).value = String(value); };
  const band = $("live-band");
  const bands = view.bands[String(view.fraction)];
  if (band.dataset.fraction !== String(view.fraction)) {
    band.replaceChildren(...bands.map((c) => el("option", { value: String(c) }, String(Math.round(c)))));
    band.dataset.fraction = String(view.fraction);
  }
  set("live-band", view.band_hz);
  set("live-fraction", view.fraction);
  set("live-range", view.range_db);
  set("live-depth", view.depth_m);
  for (const [id, [lo, hi]] of [["live-range", view.range_db_limits], ["live-depth", view.depth_m_limits]]) {
    $(id).min = String(lo);
    $(id).max = String(hi);
  }
}

function applyLiveView(changes = {}) {
  // Send the controls' values (and `changes` over them); the server checks them.
  const view = { band_hz: Number($("live-band").value), fraction: Number($("live-fraction").value),
    range_db: Number($("live-range").value), depth_m: Number($("live-depth").value), ...changes };
  const bands = state.live_view && state.live_view.bands[String(view.fraction)];
  if (bands && !changes.band_hz) { // another width: the band of it nearest the one shown
    view.band_hz = bands.reduce((a, b) => Math.abs(Math.log(b / view.band_hz)) < Math.abs(Math.log(a / view.band_hz)) ? b : a);
  }
  command("live.view", view);
}

function setUpLiveView() {
  $("live-view-form").addEventListener("submit", (e) => { e.preventDefault(); applyLiveView(); });
  for (const id of ["live-band", "live-fraction"]) $(id).addEventListener("change", () => applyLiveView());
}

// -- cameras and the next pose ---------------------------------------------------------------

function renderCameras() {
  const d = state.describe;
  if (!d) return;
  const box = $("cameras");
  const counts = Object.fromEntries((state.cameras || []).map((c) => [c.camera, c]));
  const previews = state.previews || {};
  for (const name of d.cameras) {
    let card = box.querySelector(`[data-camera="${name}"]`);
    if (!card) {
      card = el("figure", { "data-camera": name, class: "camera" });
      const view = el("div", { class: "view" });
      view.append(el("img", { alt: `preview of ${name}`, class: "hidden" }), svg("svg", { class: "overlay" }),
        el("p", { class: "no-preview" }, ""));
      card.append(view, el("figcaption"));
      box.append(card);
    }
    const p = previews[name];
    const img = card.querySelector("img");
    const overlay = card.querySelector("svg");
    // An image only with a picture in it: never an empty frame with a broken-image icon.
    img.classList.toggle("hidden", !p);
    const live = state.status && state.status.live;
    card.querySelector(".no-preview").textContent = p ? "" : live
      ? "live mode: the cameras feed the live acoustic view" : "no preview yet";
    if (p) {
      const src = "data:image/jpeg;base64," + p.jpeg_b64;
      if (img.getAttribute("src") !== src) img.setAttribute("src", src);
      overlay.setAttribute("viewBox", `0 0 ${p.width} ${p.height}`);
      card.dataset.found = p.found ? "yes" : "no";
    } else {
      img.removeAttribute("src");
      delete card.dataset.found;
    }
    overlay.replaceChildren();
    if (p && name === d.cameras[0]) drawHint(overlay, p);
    const c = counts[name] || { poses_seen: 0, warning: null };
    const caption = card.querySelector("figcaption");
    caption.replaceChildren(
      el("strong", {}, name), " ",
      el("span", { class: "badge " + (p ? (p.found ? "good" : "bad") : "") }, p ? (p.found ? "board found" : "board NOT found") : "no preview"),
      " ", el("span", { class: "poses-seen" }, plural(c.poses_seen, "pose") + " seen"),
    );
    if (c.warning) caption.append(el("div", { class: "warning" }, c.warning));
    card.classList.toggle("uncalibrated", Boolean(c.warning));
  }
  renderHint();
}

function drawHint(overlay, preview) {
  // The poses taken (faint) and the suggested pose (dashed) on camera 0's preview.
  const w = preview.width, h = preview.height;
  const coverage = (state.status && state.status.coverage) || [];
  for (const pose of coverage) {
    overlay.append(svg("polygon", { class: "coverage", points: pose.outline.map(([x, y]) => `${x * w},${y * h}`).join(" ") }));
  }
  const live = state.live;
  const hint = live && live.suggestion;
  if (!hint || !hint.outline_px.length || !live.image_size) return;
  const sx = w / live.image_size[0], sy = h / live.image_size[1];
  overlay.append(svg("polygon", { class: "hint-outline", id: "hint-outline", points: hint.outline_px.map(([x, y]) => `${x * sx},${y * sy}`).join(" ") }));
  for (const [x, y] of hint.speakers_px) overlay.append(svg("circle", { class: "hint-speaker", cx: x * sx, cy: y * sy, r: 3 }));
}

function renderHint() {
  const box = $("hint");
  const live = state.live;
  const hint = live && live.suggestion;
  box.replaceChildren();
  if (!hint) { box.append(el("p", { class: "small" }, "the hint appears with the live calibration")); return; }
  const side = hint.azimuth_deg >= 0 ? "right" : "left", up = hint.elevation_deg >= 0 ? "up" : "down";
  box.append(el("p", { id: "hint-text" }, `Next pose: ${hint.distance_m.toFixed(2)} m, ${Math.abs(hint.azimuth_deg).toFixed(0)}° ${side}, ` +
    `${Math.abs(hint.elevation_deg).toFixed(0)}° ${up} (dashed outline on ${state.describe.cameras[0]}; predicted ${mm(hint.predicted_accuracy_m)})`));
  box.append(drawCoverage(hint, live.poses_taken || []));
}

function drawCoverage(hint, taken) {
  // Coverage in angle and distance: the poses taken (dots) and the suggestion (ring), on
  // axes with round, labelled ticks. Azimuth and elevation share one scale (a degree is as
  // long either way), wide enough for every pose: at least +-30 deg by +-20 deg, the grid the
  // suggestions come from.
  const chart = svg("svg", { viewBox: "0 0 300 150", class: "coverage-chart", "aria-label": "coverage" });
  const poses = taken.concat([hint]);
  const reach = (key, least) => Math.max(least, ...poses.map((p) => Math.ceil(Math.abs(p[key]) / 10) * 10));
  const azR = reach("azimuth_deg", 30), elR = reach("elevation_deg", 20);
  const left = 36, right = 156, top = 24, bottom = 110, cx = (left + right) / 2, cy = (top + bottom) / 2;
  const pad = 1.12;  // the frame a little beyond the outer ticks: the corner's labels apart
  const s = Math.min((right - left) / (2 * pad * azR), (bottom - top) / (2 * pad * elR));
  const ax = (a) => cx + a * s, ay = (e) => cy - e * s;
  const x0 = ax(-pad * azR), y0 = ay(pad * elR), y1 = ay(-pad * elR);
  chart.append(svg("rect", { x: x0, y: y0, width: 2 * pad * azR * s, height: y1 - y0, class: "frame", id: "coverage-angles" }));
  for (const t of niceTicks(-azR, azR, 4, 1).values) {
    chart.append(svg("line", { x1: ax(t), y1: y1, x2: ax(t), y2: y1 + 3, class: "frame tick" }));
    chart.append(svg("text", { x: ax(t), y: y1 + 13, class: "axis tick-label azimuth", "text-anchor": "middle" }, t.toFixed(0)));
  }
  for (const t of niceTicks(-elR, elR, 4, 1).values) {
    chart.append(svg("line", { x1: x0 - 3, y1: ay(t), x2: x0, y2: ay(t), class: "frame tick" }));
    chart.append(svg("text", { x: x0 - 5, y: ay(t) + 3, class: "axis tick-label elevation", "text-anchor": "end" }, t.toFixed(0)));
  }
  chart.append(svg("text", { x: cx, y: y1 + 27, class: "axis", "text-anchor": "middle" }, "azimuth (deg, right +)"));
  chart.append(svg("text", { x: 4, y: y0 - 8, class: "axis" }, "elevation (deg, up +)"));
  // Distance: one axis from 0, its ticks round metres.
  const dmax = Math.max(hint.distance_m, ...taken.map((p) => p.distance_m)) * 1.15;
  const dx = (d) => 180 + 110 * d / dmax;
  chart.append(svg("line", { x1: dx(0), y1: cy, x2: dx(dmax), y2: cy, class: "frame" }));
  const dTicks = niceTicks(0, dmax, 4);
  for (const t of dTicks.values) {
    chart.append(svg("line", { x1: dx(t), y1: cy, x2: dx(t), y2: cy + 3, class: "frame tick" }));
    chart.append(svg("text", { x: dx(t), y: cy + 14, class: "axis tick-label distance", "text-anchor": "middle" }, t.toFixed(dTicks.decimals)));
  }
  chart.append(svg("text", { x: dx(dmax / 2), y: cy + 28, class: "axis", "text-anchor": "middle" }, "distance (m)"));
  for (const p of taken) {
    chart.append(svg("circle", { cx: ax(p.azimuth_deg), cy: ay(p.elevation_deg), r: 3, class: "taken" }));
    chart.append(svg("circle", { cx: dx(p.distance_m), cy: cy, r: 3, class: "taken" }));
  }
  chart.append(svg("circle", { cx: ax(hint.azimuth_deg), cy: ay(hint.elevation_deg), r: 6, class: "suggested" }));
  chart.append(svg("circle", { cx: dx(hint.distance_m), cy: cy, r: 6, class: "suggested" }));
  return chart;
}

// -- levels ----------------------------------------------------------------------------------

const FLOOR_DBFS = -90;
function meter(ch, big = false) {
  const m = el("div", { class: "meter" + (big ? " big" : "") + (ch.listening ? "" : " idle") + ch.flags.map((f) => " " + f.replace(" ", "-")).join(""), title: `${ch.name}: rms ${fmt(ch.rms_dbfs)} dBFS, peak ${fmt(ch.peak_dbfs)} dBFS, SNR ${fmt(ch.snr_db)} dB` + (ch.flags.length ? " — " + ch.flags.join(", ") : ""), "data-column": ch.column });
  const level = el("div", { class: "level" });
  level.style.height = pct(ch.rms_dbfs) + "%";
  const peak = el("div", { class: "peak" });
  peak.style.bottom = pct(ch.peak_dbfs) + "%";
  m.append(el("div", { class: "tube" }, null), el("span", { class: "label" }, ch.label));
  m.firstChild.append(level, peak);
  return m;
}
function dbScale() {
  // The meters' scale: dBFS at the height each level reaches (0 = full scale at the top).
  const scale = el("div", { class: "db-scale", title: "dBFS (0 = full scale of the channel's range)" });
  const tube = el("div", { class: "tube" });
  for (let db = 0; db >= FLOOR_DBFS; db -= 30) {
    const tick = el("span", { class: "db-tick" }, String(db));
    tick.style.bottom = pct(db) + "%";
    tube.append(tick);
  }
  scale.append(tube, el("span", { class: "label" }, "dBFS"));
  return scale;
}
const fmt = (v) => (v === null || v === undefined) ? "n/a" : v.toFixed(1);
const pct = (db) => Math.max(0, Math.min(100, 100 * ((db ?? FLOOR_DBFS) - FLOOR_DBFS) / -FLOOR_DBFS));

function renderLevels() {
  const lv = state.levels;
  const box = $("levels");
  if (!lv) { // a new session, or none: nothing recorded in it yet
    $("levels-step").textContent = "";
    box.replaceChildren(el("p", { class: "small" }, "no recording yet"));
    $("flags").replaceChildren();
    return;
  }
  $("levels-step").textContent = `${lv.step} ${lv.file}`;
  box.replaceChildren();
  if (lv.reference) {
    const ref = el("div", { class: "board reference" });
    ref.append(el("h3", {}, "reference microphone"), meter(lv.reference, true), el("p", { class: "small" }, lv.reference.name));
    box.append(ref);
  }
  for (const group of lv.boards) {
    const b = el("div", { class: "board", "data-board": group.board });
    const row = el("div", { class: "meters" });
    row.append(dbScale());
    for (const ch of group.channels) row.append(meter(ch));
    b.append(el("h3", {}, `board ${group.board}`), row);
    box.append(b);
  }
  const flags = $("flags");
  flags.replaceChildren();
  const names = { clipped: "Clipped", dead: "Dead (no burst heard)", low_snr: "Low SNR" };
  let any = false;
  for (const [key, title] of Object.entries(names)) {
    const list = lv.flagged[key];
    if (list.length) { any = true; flags.append(el("p", { class: "flag " + key }, `${title}: ${list.join(", ")}`)); }
  }
  if (!any) flags.append(el("p", { class: "flag none" }, "no channel flagged"));
}

// -- live calibration ------------------------------------------------------------------------

function colour(u, umax) {
  // Uncertainty to colour: blue (certain) to yellow to red (uncertain), by fraction of umax.
  const t = Math.max(0, Math.min(1, u / umax));
  return `hsl(${240 - 240 * t}, 80%, ${45 + 10 * t}%)`;
}

function drawArray(target, mics, i, j, title, umax) {
  target.replaceChildren();
  target.append(svg("text", { x: 4, y: 14, class: "axis" }, title));
  if (!mics.length) return;
  const xs = mics.map((m) => m.position_m[i]), ys = mics.map((m) => m.position_m[j]);
  const cx = (Math.min(...xs) + Math.max(...xs)) / 2, cy = (Math.min(...ys) + Math.max(...ys)) / 2;
  const span = Math.max(Math.max(...xs) - Math.min(...xs), Math.max(...ys) - Math.min(...ys), 1e-3) * 1.2;
  const s = 200 / span;
  target.append(svg("circle", { cx: 120 - cx * s, cy: 128 - cy * s, r: 3, class: "origin" }));
  for (const m of mics) {
    const c = svg("circle", { cx: 120 + (m.position_m[i] - cx) * s, cy: 128 + (m.position_m[j] - cy) * s, r: 4, fill: colour(m.uncertainty_m, umax), class: "mic" });
    c.append(svg("title", {}, `mic ${m.id}: ± ${mm(m.uncertainty_m)}`));
    target.append(c);
  }
  target.append(svg("text", { x: 4, y: 236, class: "axis" }, `${(span * 1e3).toFixed(0)} mm across`));
}

function drawChart(target, points, key, scale, unit, title, target_line = null) {
  target.replaceChildren();
  target.append(svg("text", { x: 4, y: 14, class: "axis" }, title));
  if (!points.length) return;
  const xs = points.map((p) => p.poses), ys = points.map((p) => p[key] * scale);
  const lines = target_line === null ? ys : ys.concat([target_line]);
  const x0 = Math.min(...xs), x1 = Math.max(...xs, x0 + 1);
  let y0 = Math.min(...lines), y1 = Math.max(...lines);
  if (y1 - y0 < 1e-9) { y0 -= 1; y1 += 1; }
  const X = (x) => 40 + 250 * (x - x0) / (x1 - x0), Y = (y) => 140 - 110 * (y - y0) / (y1 - y0);
  target.append(svg("line", { x1: 40, y1: 140, x2: 290, y2: 140, class: "frame" }), svg("line", { x1: 40, y1: 30, x2: 40, y2: 140, class: "frame" }));
  if (target_line !== null) target.append(svg("line", { x1: 40, y1: Y(target_line), x2: 290, y2: Y(target_line), class: "target" }));
  target.append(svg("polyline", { points: points.map((p) => `${X(p.poses)},${Y(p[key] * scale)}`).join(" "), class: "series" }));
  for (const p of points) target.append(svg("circle", { cx: X(p.poses), cy: Y(p[key] * scale), r: 3, class: "point" }));
  // Round ticks, each labelled with as many decimals as its step needs (two ends that print
  // alike, "343.9" and "343.9", said nothing of the range between them).
  const yt = niceTicks(y0, y1, 4);
  for (const t of yt.values) {
    target.append(svg("line", { x1: 36, y1: Y(t), x2: 40, y2: Y(t), class: "frame tick" }));
    target.append(svg("text", { x: 34, y: Y(t) + 3, class: "axis tick-label", "text-anchor": "end" }, t.toFixed(yt.decimals)));
  }
  const xt = niceTicks(x0, x1, 5, 1);
  for (const t of xt.values) {
    target.append(svg("line", { x1: X(t), y1: 140, x2: X(t), y2: 144, class: "frame tick" }));
    target.append(svg("text", { x: X(t), y: 153, class: "axis tick-label", "text-anchor": "middle" }, t.toFixed(0)));
  }
  // the axis title below the tick labels, centred (at the right end it sat on the last one)
  target.append(svg("text", { x: 165, y: 167, class: "axis", "text-anchor": "middle" }, "poses"));
  target.append(svg("text", { x: 230, y: 14, class: "axis" }, unit));
}

function niceTicks(lo, hi, wanted, minStep = 0) {
  // Round values (1, 2 or 5 times a power of ten apart) within [lo, hi], and the decimals
  // that tell them apart.
  const raw = Math.max((hi - lo) / Math.max(1, wanted), minStep, 1e-12);
  const power = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map((m) => m * power).find((v) => v >= raw - 1e-12) * 1;
  const values = [];
  for (let v = Math.ceil(lo / step - 1e-9) * step; v <= hi + step * 1e-9; v += step) values.push(v);
  return { values, decimals: Math.max(0, -Math.floor(Math.log10(step) + 1e-9)) };
}

function renderLive() {
  const live = state.live;
  const history = state.live_history || [];
  const target = state.target_m;
  if (!live) { // a new session, or none: no calibration of it yet
    $("live-summary").textContent = "no live calibration yet";
    delete $("live-summary").dataset.poses;
    $("enough").classList.add("hidden");
    for (const id of ["view-top", "view-front", "chart-accuracy", "chart-c", "uncertainty-legend"]) $(id).replaceChildren();
    return;
  }
  const umax = Math.max(...live.microphones.map((m) => m.uncertainty_m), 1e-6);
  $("live-summary").textContent = `${live.poses} poses: mean uncertainty ${mm(live.mean_uncertainty_m)}, predicted accuracy ` +
    `${mm(live.predicted_accuracy_m)}${target ? ` (target ${mm(target, 2)})` : ""}, c ${live.speed_of_sound_m_s.toFixed(2)} m/s`;
  $("live-summary").dataset.poses = live.poses;
  $("enough").classList.toggle("hidden", !live.enough);
  drawArray($("view-top"), live.microphones, 0, 2, "top view (x right, z forward)", umax);
  drawArray($("view-front"), live.microphones, 0, 1, "front view (x right, y down)", umax);
  drawChart($("chart-accuracy"), history, "predicted_accuracy_m", 1e3, "mm", "predicted accuracy", target ? target * 1e3 : null);
  drawChart($("chart-c"), history, "speed_of_sound_m_s", 1, "m/s", "speed of sound");
  const legend = $("uncertainty-legend");
  legend.replaceChildren(el("span", {}, "uncertainty: "));
  for (const f of [0, 0.25, 0.5, 0.75, 1]) {
    const swatch = el("span", { class: "swatch" });
    swatch.style.background = colour(f * umax, umax);
    legend.append(swatch, el("span", {}, mm(f * umax, 2) + " "));
  }
}

// -- sessions and reports --------------------------------------------------------------------

function renderSessions() {
  const listing = state.sessions;
  if (!listing) return;
  const body = $("sessions").querySelector("tbody");
  body.replaceChildren();
  for (const s of [...listing.sessions].reverse()) {
    const row = el("tr", { "data-session": s.id, "data-status": s.status });
    const open = el("button", { class: "report-button" }, "report");
    open.addEventListener("click", () => showReport(s.id));
    const cell = el("td");
    cell.append(open);
    row.append(el("td", {}, s.id), el("td", { class: "status-" + s.status }, s.status), el("td", {}, `${s.poses_done}/${s.n_poses}`),
      el("td", {}, `${s.steps_done}/${s.steps_total}`), cell);
    body.append(row);
  }
}

async function showReport(id) {
  const box = $("report");
  box.classList.remove("hidden");
  delete box.dataset.calibrated;
  box.replaceChildren(el("p", {}, `reading ${id}…`));
  const reply = await fetch(`/api/sessions/${encodeURIComponent(id)}/report`);
  const r = await reply.json();
  box.replaceChildren();
  box.dataset.session = id;
  if (r.ok === false) { box.append(el("p", { class: "bad" }, r.error)); return; }
  const s = r.session;
  box.append(el("h3", {}, `Report: ${s.id}`), el("p", { id: "report-summary" }, `${s.status}: ${s.poses_done}/${s.n_poses} poses, ${s.steps_done}/${s.steps_total} steps, created ${s.created_utc}`));
  if (r.result) {
    const res = r.result;
    box.dataset.calibrated = "yes";
    box.append(el("p", { id: "report-result" }, `calibration (${res.method}): ${res.n_microphones} microphones from ${res.poses} poses; ` +
      `c ${res.speed_of_sound_m_s.toFixed(3)} ± ${(res.speed_of_sound_std_m_s || 0).toFixed(3)} m/s; median uncertainty ${mm(res.median_uncertainty_m)}` +
      (res.residual_rms_s ? `; TOF residual RMS ${(res.residual_rms_s * 1e9).toFixed(1)} ns` : "")));
    const umax = Math.max(...res.microphones.map((m) => m.uncertainty_m), 1e-6);
    const views = el("div", { class: "live" });
    const top = svg("svg", { class: "array-view", viewBox: "0 0 240 240" }), front = svg("svg", { class: "array-view", viewBox: "0 0 240 240" });
    drawArray(top, res.microphones, 0, 2, "calibrated: top view", umax);
    drawArray(front, res.microphones, 0, 1, "calibrated: front view", umax);
    views.append(top, front);
    box.append(views);
  } else if (r.result_error) {
    box.dataset.calibrated = "unreadable";
    box.append(el("p", { id: "report-result", class: "bad" }, r.result_error));
  } else {
    box.dataset.calibrated = "no";
    box.append(el("p", { class: "small" }, "no final calibration yet (a worker calibrates a complete session after it closes)"));
  }
  const table = el("table", { class: "quality" });
  table.append(el("tr", {}, null));
  table.firstChild.append(el("th", {}, "step"), el("th", {}, "board found"), el("th", {}, "warnings"));
  for (const q of r.steps) {
    const found = Object.entries(q.checkerboard_found).map(([c, f]) => `${c} ${f ? "yes" : "NO"}`).join(", ");
    const row = el("tr");
    row.append(el("td", {}, q.step), el("td", {}, found), el("td", {}, q.warnings.join("; ")));
    table.append(row);
  }
  box.append(el("h4", {}, "steps"), table);
  const pictures = r.files.filter((f) => f.path.endsWith(".png"));
  const texts = r.files.filter((f) => f.path.endsWith(".md"));
  if (pictures.length || texts.length) box.append(el("h4", {}, "report and pictures"));
  for (const f of texts) {
    const pre = el("pre", { class: "report-text" });
    box.append(pre);
    fetch(`/api/sessions/${encodeURIComponent(id)}/files/${f.path}`).then((x) => x.text()).then((t) => { pre.textContent = t; });
  }
  for (const f of pictures) {
    const fig = el("figure", { class: "picture" });
    fig.append(el("img", { src: `/api/sessions/${encodeURIComponent(id)}/files/${f.path}`, alt: f.path }), el("figcaption", {}, f.path));
    box.append(fig);
  }
  // Every file to take home, each a download link (the page serves calibration files only).
  const files = el("ul", { id: "report-files", class: "files" });
  for (const f of r.files) {
    const name = f.path.split("/").pop();
    const link = el("a", { href: `/api/sessions/${encodeURIComponent(id)}/files/${f.path}`, download: name }, f.path);
    const item = el("li");
    item.append(link, ` (${(f.bytes / 1024).toFixed(1)} kB)`);
    files.append(item);
  }
  box.append(el("h4", {}, "files"), files);
}

// -- events ----------------------------------------------------------------------------------

function renderLog() {
  const box = $("log");
  box.replaceChildren(...(state.log || []).slice(-40).reverse().map((l) => el("li", { "data-seq": l.seq }, l.line)));
}

setUpControls();
setUpLiveView();
connect();
