// edgedsm plant dashboard. Every string from MQTT reaches the page through textContent or
// setAttribute (never innerHTML), so a region called "<img onerror=...>" is shown, not run.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const devices = new Map(); // name -> summary from the server
let selected = null;
let plot = null;
let history = { device: null, region: null, points: [], alerts: [], thresholds: null, kinetics: [], stages: [] };
let tool = null;
let drawing = null;
let lastShape = null;
let info = { read_only: true };

const $ = (id) => document.getElementById(id);

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs || {})) {
    if (key === "class") node.className = value; else node.setAttribute(key, value);
  }
  for (const child of children) node.append(child === null || child === undefined ? "" : child);
  return node;
}

function fmt(value, digits = 4) {
  if (value === null || value === undefined || typeof value !== "number" || !isFinite(value)) return "–";
  return Math.abs(value) >= 1000 ? value.toFixed(0) : value.toPrecision(digits);
}

function clock(t) {
  return typeof t === "number" ? new Date(t * 1000).toLocaleTimeString() : "–";
}

function duration(s) {
  if (typeof s !== "number" || !isFinite(s)) return "–";
  if (s < 120) return `${s.toFixed(0)} s`;
  if (s < 7200) return `${(s / 60).toFixed(0)} min`;
  return `${(s / 3600).toFixed(1)} h`;
}

function stateClass(state) {
  return ["warming_up", "wet", "drying", "dry", "fault"].includes(state) ? state : "unknown";
}

function regionStates(device) {
  // the state report is the reference; stats carry the states in between
  const out = {};
  const stats = device.stats || {};
  for (const [name, state] of Object.entries(stats.states || {})) out[name] = { state, activity: (stats.activity || {})[name] };
  const regions = (device.state && device.state.regions) || {};
  for (const [name, region] of Object.entries(regions)) {
    if (!region || typeof region !== "object") continue;
    const newer = !stats.t || !device.state.t || device.state.t >= stats.t;
    out[name] = {
      state: newer || !out[name] ? region.state : out[name].state,
      activity: out[name] && out[name].activity !== undefined ? out[name].activity : region.activity,
      time_to_dry_s: region.time_to_dry_s, since: region.since,
    };
  }
  // the signal quality: the stats carry its numbers, the state report only the verdict
  const signals = stats.signal || {};
  for (const [name, value] of Object.entries(out)) {
    const reported = regions[name] && regions[name].signal;
    value.signal = signals[name] || (typeof reported === "string" ? { signal: reported } : null);
  }
  return out;
}

function isStale(device) {
  // offline (a clean stop or the broker's last will): what the page holds is the last word, not now
  return device.availability === "offline";
}

function laserText(device) {
  // a stopped daemon vouches only for its retained last word (off at a clean stop); the stats before it are older
  const state = device.state || {};
  if (isStale(device)) return state.availability === "offline" && typeof state.laser === "string" ? state.laser : "unknown";
  return (device.stats && device.stats.laser) || state.laser || "–";
}

function staleLine(device) {
  // after the offline badge: what the daemon last said, and that nothing below is now
  return `laser ${laserText(device)} · last heard ${clock(device.last_seen)} · the figures are the last received`;
}

const SIGNALS = ["ok", "low", "dark", "saturated", "not_speckle"];

function signalBadge(signal) {
  // ok green, low grey, a light that cannot be judged amber; the reason and the light as tooltip
  if (!signal || typeof signal !== "object") return "–";
  const verdict = SIGNALS.includes(signal.signal) ? signal.signal : "unknown";
  const pct = (v) => (typeof v === "number" && isFinite(v) ? `${(100 * v).toFixed(0)} %` : "–");
  const light = `mean ${fmt(signal.mean, 3)} grey levels · dark ${pct(signal.dark_fraction)} · saturated `
    + `${pct(signal.saturated_fraction)} · speckle contrast ${fmt(signal.speckle_contrast, 2)}`;
  const title = [typeof signal.reason === "string" ? signal.reason : null, signal.mean === undefined ? null : light]
    .filter(Boolean).join("\n") || verdict;
  return el("span", { class: `badge signal sig-${verdict}`, title }, verdict.replace("_", " "));
}

function unitText(judged) {
  // " s", " grey levels"; nothing for a dimensionless value
  return judged && typeof judged.unit === "string" && judged.unit ? ` ${judged.unit}` : "";
}

function judgedWhat(judged) {
  // what the activity is: "S2 above the noise floor", "τc", "S2 (no noise model yet)"
  if (!judged || typeof judged.label !== "string") return "activity";
  if (judged.basis === "above_noise") return `${judged.label} above the noise floor`;
  return judged.estimator === "tau_c" ? judged.label : `${judged.label} mean (no noise floor taken off)`;
}

function aboveNoise(signal) {
  if (!signal || typeof signal.above_noise !== "number") return "–";
  return `${fmt(signal.above_noise, 3)} ± ${fmt(signal.above_noise_spread, 2)} (floor ${fmt(signal.noise_floor, 3)})`;
}

// -- device list ------------------------------------------------------------------------------

function renderCards() {
  const names = [...devices.keys()].sort();
  $("devices").replaceChildren(...names.map(card));
  if (selected === null && names.length) select(names[0]);
}

function renderCard(name) {
  // one device changed: replace its card only (16 devices at 1 update/s stay cheap)
  const old = document.querySelector(`.device-card[data-device="${CSS.escape(name)}"]`);
  if (old) old.replaceWith(card(name)); else renderCards();
}

function card(name) {
  const device = devices.get(name);
  const availability = device.availability || "unknown";
  const stale = isStale(device);
  const node = el("div", { class: "device-card" + (name === selected ? " selected" : "") + (stale ? " stale" : ""), "data-device": name },
    el("div", { class: "name" }, name, " ", el("span", { class: `badge ${availability === "online" ? "online" : availability === "offline" ? "offline" : "unknown"}` }, availability)));
  const stats = device.stats;
  node.append(el("div", { class: "muted status-line" }, stale ? `laser ${laserText(device)} · last heard ${clock(device.last_seen)}`
    : stats ? `${fmt(stats.fps, 3)} fps · laser ${stats.laser}` : "no statistics yet"));
  const regions = el("div", { class: "regions" + (stale ? " stale" : "") });
  for (const [region, value] of Object.entries(regionStates(device))) {
    regions.append(el("span", { class: `badge ${stateClass(value.state)}`, "data-region": region }, `${region}: ${value.state}`));
  }
  node.append(regions);
  if (device.rejected) node.append(el("div", { class: "muted rejected" }, `${device.rejected} unreadable message(s): ${device.last_rejection || ""}`));
  node.addEventListener("click", () => select(name));
  return node;
}

function select(name) {
  if (name !== selected) forgetDraft();
  selected = name;
  renderCards();
  renderDetail();
  loadHistory();
  loadCommissioning();
}

// -- one device ---------------------------------------------------------------------------------

function renderDetail() {
  const device = devices.get(selected);
  $("detail").hidden = !device;
  if (!device) return;
  $("detail-title").textContent = selected;
  const stats = device.stats || {};
  const drops = Object.entries(stats.drops || {}).map(([k, v]) => `${k} ${v}`).join(", ") || "none";
  const stale = isStale(device);
  $("device-stats").replaceChildren(
    el("span", { class: `badge ${device.availability === "online" ? "online" : "offline"}` }, device.availability || "unknown"), " ",
    stale ? el("span", { class: "stale-line" }, staleLine(device))
      : `laser ${laserText(device)} · ${fmt(stats.fps, 3)} fps · frames ${stats.frames ?? "–"} · drops ${drops} · ambient ${fmt(stats.ambient_level)} · estimator ${stats.estimator || "–"}`,
    !stale && stats.warning ? el("span", { class: "badge drying" }, `warning: ${stats.warning}`) : "");
  const rows = Object.entries(regionStates(device)).map(([name, value]) =>
    el("tr", { class: "region-row" + (stale ? " stale" : ""), "data-region": name },
      el("td", {}, name),
      el("td", {}, el("span", { class: `badge ${stateClass(value.state)}` }, value.state)),
      // what the thresholds judge (above the noise floor; τc in s), with its unit; the plain mean beside it
      el("td", { class: "activity", title: judgedWhat((stats.judged || {})[name]) },
        fmt(value.activity) + unitText((stats.judged || {})[name])),
      el("td", { class: "plain", title: stats.plain_label || "" }, fmt((stats.plain || {})[name])),
      el("td", {}, signalBadge(value.signal)),
      el("td", { class: "above-noise" }, aboveNoise(value.signal)),
      // a stopped daemon extrapolates nothing: no time to dry
      el("td", { class: "time-to-dry" }, stale ? "–" : duration(value.time_to_dry_s)),
      el("td", {}, clock(value.since))));
  $("regions").tBodies[0].replaceChildren(...rows);
  const regionSelect = $("region-select");
  const names = Object.keys(regionStates(device));
  const current = regionSelect.value;
  if ([...regionSelect.options].map((o) => o.value).join("\n") !== names.join("\n")) {
    regionSelect.replaceChildren(...names.map((n) => el("option", { value: n }, n)));
    if (names.includes(current)) regionSelect.value = current;
    loadHistory();
  }
  renderMapSelect(device);
  renderAlerts(device);
}

function renderMapSelect(device) {
  const select = $("map-select");
  const names = Object.keys(device.maps || {}).sort();
  const current = select.value;
  if ([...select.options].map((o) => o.value).join("\n") !== names.join("\n")) {
    select.replaceChildren(...names.map((n) => el("option", { value: n }, n.toUpperCase())));
    const preferred = (device.stats && device.stats.estimator) || current;
    // the judged map first, until the operator picks one
    if (select.dataset.chosen && names.includes(select.dataset.chosen)) select.value = select.dataset.chosen;
    else if (names.includes(preferred)) select.value = preferred;
    else if (names.includes(current)) select.value = current;
  }
  renderMap();
}

function renderMap() {
  const device = devices.get(selected);
  const name = $("map-select").value;
  const map = device && device.maps && device.maps[name];
  $("no-map").hidden = !!map;
  $("map-frame").parentElement.hidden = !map;
  if (!map) return;
  const src = `/api/map.png?device=${encodeURIComponent(selected)}&name=${encodeURIComponent(name)}&seq=${encodeURIComponent(map.seq)}`;
  const img = $("map-img");
  if (img.getAttribute("src") !== src) img.setAttribute("src", src);
  $("cb-max").textContent = fmt(map.max);
  $("cb-min").textContent = fmt(map.min);
  const shape = map.source_shape || map.shape || [1, 1];
  $("map-info").textContent = `#${map.seq} at ${clock(map.t)} · ${shape[1]}×${shape[0]} px · N=${map.window} m=${map.lag}`;
  const svg = $("map-overlay");
  svg.setAttribute("viewBox", `0 0 ${shape[1]} ${shape[0]}`);
  svg.setAttribute("preserveAspectRatio", "none");
  const parts = [];
  for (const [region, meta] of Object.entries(device.regions || {})) {
    const outline = shapeElement(meta.shape, shape, "region");
    if (!outline) continue;
    parts.push(outline.node);
    const label = document.createElementNS(SVG, "text");
    label.setAttribute("x", outline.label[0]);
    label.setAttribute("y", outline.label[1]);
    label.setAttribute("font-size", Math.max(8, shape[0] / 20));
    label.textContent = region;
    parts.push(label);
  }
  if (lastShape) { const drawn = shapeElement(lastShape, shape, "drawn"); if (drawn) parts.push(drawn.node); }
  svg.replaceChildren(...parts);
}

function shapeElement(shape, frame, cls) {
  if (!shape || typeof shape !== "object") return null;
  let node;
  let label;
  const num = (v, d = 0) => (typeof v === "number" && isFinite(v) ? v : d);
  if (shape.shape === "rect") {
    node = document.createElementNS(SVG, "rect");
    for (const key of ["x", "y", "width", "height"]) node.setAttribute(key, num(shape[key]));
    label = [num(shape.x) + 2, num(shape.y) + frame[0] / 18];
  } else if (shape.shape === "circle" || shape.shape === "ring") {
    node = document.createElementNS(SVG, "circle");
    node.setAttribute("cx", num(shape.cx)); node.setAttribute("cy", num(shape.cy));
    node.setAttribute("r", num(shape.radius, num(shape.outer_radius)));
    label = [num(shape.cx) - num(shape.radius, num(shape.outer_radius)), num(shape.cy)];
  } else if (shape.shape === "polygon" && Array.isArray(shape.points)) {
    node = document.createElementNS(SVG, "polygon");
    node.setAttribute("points", shape.points.map((p) => `${num(p[0])},${num(p[1])}`).join(" "));
    label = [num(shape.points[0] && shape.points[0][0]), num(shape.points[0] && shape.points[0][1])];
  } else if (shape.shape === "full") {
    node = document.createElementNS(SVG, "rect");
    node.setAttribute("x", 1); node.setAttribute("y", 1);
    node.setAttribute("width", frame[1] - 2); node.setAttribute("height", frame[0] - 2);
    label = [4, frame[0] / 14];
  } else {
    return null;
  }
  node.setAttribute("class", cls);
  return { node, label };
}

function renderAlerts(device) {
  const items = (device.alerts || []).slice().reverse().map((a) => {
    const change = a.type === "transition" ? `${a.from} → ${a.to}` : a.type;
    return el("li", { class: ["fault", "warning"].includes(a.type) ? a.type : "" },
      `${clock(a.t)} ${a.region || "device"}: ${change}${a.reason ? " – " + a.reason : ""}`);
  });
  $("alerts").replaceChildren(...items);
}

// -- history plot ---------------------------------------------------------------------------------

async function loadHistory() {
  const region = $("region-select").value;
  if (!selected || !region) {
    history = { ...history, points: [], kinetics: [], stages: [] };
    drawPlot(); edgedsmKinetics.show(history); return 0;
  }
  const span = Number($("range-select").value);
  const to = Date.now() / 1000 + 5;
  const query = `device=${encodeURIComponent(selected)}&region=${encodeURIComponent(region)}&from=${to - span}&to=${to}`;
  $("csv-link").setAttribute("href", `/api/history?${query}&format=csv`);
  const answer = await fetch(`/api/history?${query}`).then((r) => r.json());
  if (answer.device !== selected || answer.region !== $("region-select").value) return 0;
  history = { device: selected, region, points: answer.points, alerts: answer.alerts, thresholds: answer.thresholds,
    kinetics: answer.kinetics || [], stages: answer.stages || [] };
  plotCaption();
  drawPlot();
  edgedsmKinetics.show(history); // [kinetics] on: τ or the rate on a log axis, with the drying stages
  return history.points.length;
}

function plotCaption() {
  // the curve is what the thresholds judge: say which value, in which unit
  const device = devices.get(history.device);
  const judged = device && device.stats && (device.stats.judged || {})[history.region];
  const unit = judged && judged.unit ? ` (${judged.unit})` : "";
  $("plot-caption").textContent = `${judgedWhat(judged)}${unit} against wet_above (blue) and dry_below (green)`;
}

function plotData() {
  const xs = history.points.map((p) => p[0]);
  const ys = history.points.map((p) => p[1]);
  return [xs, ys];
}

function drawMarks(u) {
  const ctx = u.ctx;
  const { left, top, width, height } = u.bbox;
  ctx.save();
  ctx.lineWidth = 1.5 * devicePixelRatio;
  const thresholds = history.thresholds || {};
  for (const [key, colour] of [["wet_above", "#2d6fd2"], ["dry_below", "#2e9e4f"]]) {
    const value = thresholds[key];
    if (typeof value !== "number") continue;
    const y = u.valToPos(value, "y", true);
    if (y < top || y > top + height) continue;
    ctx.strokeStyle = colour; ctx.setLineDash([6, 4]);
    ctx.beginPath(); ctx.moveTo(left, y); ctx.lineTo(left + width, y); ctx.stroke();
  }
  ctx.setLineDash([]);
  for (const alert of history.alerts) {
    if (alert.type !== "transition" && alert.type !== "reset") continue;
    const x = u.valToPos(alert.t, "x", true);
    if (x < left || x > left + width) continue;
    ctx.strokeStyle = alert.to === "dry" ? "#2e9e4f" : alert.to === "drying" ? "#e6a21a" : "#9aa0ad";
    ctx.beginPath(); ctx.moveTo(x, top); ctx.lineTo(x, top + height); ctx.stroke();
  }
  ctx.restore();
}

function plotWidth() {
  return Math.max(320, ($("plot").parentElement.clientWidth || 640) - 24);
}

function drawPlot() {
  const data = plotData();
  const box = $("plot");
  const width = plotWidth();
  if (!plot) {
    plot = new uPlot({
      width, height: 260,
      scales: { x: { time: true }, y: { range: (u, min, max) => {
        const t = history.thresholds || {};
        const values = [min, max, t.wet_above, t.dry_below].filter((v) => typeof v === "number" && isFinite(v));
        const lo = values.length ? Math.min(...values) : 0, hi = values.length ? Math.max(...values) : 1;
        const pad = (hi - lo) * 0.1 || 0.1;
        return [lo - pad, hi + pad];
      } } },
      series: [{}, { label: "activity", stroke: "#3060d0", width: 2, points: { show: false } }],
      axes: [{}, { label: "activity" }],
      hooks: { draw: [drawMarks] },
    }, data, box);
  } else {
    plot.setData(data);
    if (Math.abs(plot.width - plotWidth()) > 8) plot.setSize({ width: plotWidth(), height: 260 });
  }
}

function appendLive(device) {
  // a new statistics message extends the curve without asking the server again
  const region = $("region-select").value;
  const stats = device.stats;
  if (!plot || !stats || history.device !== device.device || history.region !== region) return;
  plotCaption();
  edgedsmKinetics.append(stats.t, (stats.kinetics || {})[region]);
  const last = history.points.length ? history.points[history.points.length - 1][0] : -Infinity;
  if (!(stats.t > last) || !(region in (stats.activity || {}) || region in (stats.states || {}))) return;
  const activity = (stats.activity || {})[region];
  history.points.push([stats.t, typeof activity === "number" ? activity : null, (stats.states || {})[region] || ""]);
  plot.setData(plotData());
}

// -- commissioning: the last `edgedsm tune` report of the device ----------------------------------

let commissioning = null; // the last answer of /api/commissioning for the selected device

const THRESHOLD_NAMES = { wet: ["wet_above", "wet_below_s"], dry: ["dry_below", "dry_above_s"] };

function threshold(thresholds, side) {
  // "0.4887" or "0.12 s" (τc); the key tells which
  for (const key of THRESHOLD_NAMES[side]) {
    if (typeof thresholds[key] === "number") return `${key} = ${thresholds[key]}${key.endsWith("_s") ? " s" : ""}`;
  }
  return "–";
}

function markDelay(delay) {
  if (typeof delay !== "number" || !isFinite(delay)) return "never";
  return delay >= 0 ? `${delay.toFixed(1)} s after` : `${(-delay).toFixed(1)} s before`;
}

async function loadCommissioning() {
  const device = selected;
  if (!device) return null;
  const answer = await fetch(`/api/commissioning?device=${encodeURIComponent(device)}`).then((r) => r.json());
  if (device !== selected) return answer;
  commissioning = answer;
  renderCommissioning(answer);
  return answer;
}

function renderCommissioning(answer) {
  // every string of the report is written by textContent: the file is another program's output
  const report = answer && answer.report;
  $("commissioning-message").hidden = !!report;
  $("commissioning-report").hidden = !report;
  if (!report) {
    $("commissioning-message").textContent = (answer && (answer.message || answer.error)) || "no commissioning report";
    return;
  }
  const choice = report.recommended;
  $("commissioning-choice").textContent = choice ? `recommended: ${choice.label}`
    : "no recommendation: no candidate separates wet from dry on every region without a false transition";
  $("commissioning-numbers").textContent = choice ? `dry ${markDelay(choice.delay_s)} the dry mark · AUC `
    + `${fmt(choice.auc, 4)} · d′ ${choice.d_prime === null ? "∞" : fmt(choice.d_prime, 3)}`
    + `${choice.robust === false ? " (not robust)" : ""} · ${fmt(choice.cost_ms_per_frame, 3)} ms per frame · `
    + `[estimator] activity = "${choice.estimator}", window = ${choice.window}, lag = ${choice.lag}, `
    + `mode = "${choice.mode}"` : "";
  $("commissioning-reason").textContent = `${report.reason}.`;
  const regions = choice ? Object.entries(choice.regions) : [];
  $("commissioning-regions").hidden = !choice;
  $("commissioning-regions").tBodies[0].replaceChildren(...regions.map(([name, region]) =>
    el("tr", { class: "commissioning-region", "data-region": name },
      el("td", {}, name),
      el("td", { class: "wet" }, threshold(region.thresholds, "wet")),
      el("td", { class: "dry" }, threshold(region.thresholds, "dry")),
      el("td", {}, `${region.thresholds.hysteresis ?? "–"}`),
      el("td", {}, `${region.thresholds.min_dwell_s ?? "–"} s`),
      el("td", {}, markDelay(region.delay_s)))));
  const when = String(report.written_at).replace("T", " ").replace(/\+00:00$/, " UTC");
  $("commissioning-run").textContent = `${when} · run ${report.run}: ${report.frames} frames, Δt ${report.dt_s} s, `
    + `wet until ${report.wet_until_s} s, dry from ${report.dry_from_s} s · ${report.candidates} candidates in `
    + `${fmt(report.seconds, 3)} s · config ${report.config}`;
  $("commissioning-command").textContent = report.command;
  for (const name of ["activity", "tradeoff"]) {
    const img = $(`commissioning-${name}`);
    const shown = report.plots.includes(`${name}.png`);
    img.hidden = !shown;
    const src = `/api/commissioning/${name}.png?device=${encodeURIComponent(answer.device)}&at=${encodeURIComponent(report.written_at)}`;
    if (shown && img.getAttribute("src") !== src) img.setAttribute("src", src);
    if (!shown) img.removeAttribute("src");
  }
}

// -- region editor ---------------------------------------------------------------------------------

function mapPoint(event) {
  const svg = $("map-overlay");
  const point = svg.createSVGPoint();
  point.x = event.clientX; point.y = event.clientY;
  const p = point.matrixTransform(svg.getScreenCTM().inverse());
  return [Math.round(p.x * 10) / 10, Math.round(p.y * 10) / 10];
}

function startEditor() {
  const svg = $("map-overlay");
  for (const button of document.querySelectorAll("[data-tool]")) {
    button.addEventListener("click", () => { tool = button.dataset.tool; drawing = null; $("editor-hint").textContent = `drawing a ${tool}`; });
  }
  svg.addEventListener("pointerdown", (event) => {
    if (!tool) return;
    const p = mapPoint(event);
    if (tool === "polygon") {
      drawing = drawing && drawing.shape === "polygon" ? drawing : { shape: "polygon", points: [] };
      drawing.points.push(p);
      lastShape = drawing.points.length >= 3 ? drawing : null;
      renderMap();
      return;
    }
    drawing = { start: p };
  });
  svg.addEventListener("pointermove", (event) => {
    if (!drawing || !drawing.start) return;
    lastShape = shapeFrom(drawing.start, mapPoint(event));
    renderMap();
  });
  svg.addEventListener("pointerup", (event) => {
    if (!drawing || !drawing.start) return;
    lastShape = shapeFrom(drawing.start, mapPoint(event));
    drawing = null;
    renderMap();
    measure();
  });
  svg.addEventListener("dblclick", () => { if (tool === "polygon" && lastShape) { drawing = null; measure(); } });
  $("copy-toml").addEventListener("click", () => {
    const text = $("editor-toml").value;
    if (navigator.clipboard) navigator.clipboard.writeText(text).catch(() => $("editor-toml").select());
    else $("editor-toml").select();
  });
}

// a shape drawn on one device's map, its statistics, its TOML and the last command's answer belong
// to that device: another device's page starts without them
function forgetDraft() {
  drawing = null;
  lastShape = null;
  $("editor-stats").textContent = "";
  $("editor-toml").value = "";
  $("command-result").textContent = "";
}

function shapeFrom(a, b) {
  if (tool === "circle") {
    return { shape: "circle", cx: a[0], cy: a[1], radius: Math.max(1, Math.round(Math.hypot(b[0] - a[0], b[1] - a[1]) * 10) / 10) };
  }
  return { shape: "rect", x: Math.min(a[0], b[0]), y: Math.min(a[1], b[1]),
    width: Math.max(1, Math.abs(b[0] - a[0])), height: Math.max(1, Math.abs(b[1] - a[1])) };
}

async function measure(shape = lastShape) {
  if (!shape) return null;
  const body = { device: selected, map: $("map-select").value, name: $("region-name").value, shape };
  const answer = await fetch("/api/region-stats", { method: "POST", headers: { "Content-Type": "application/json" },
    body: JSON.stringify(body) }).then((r) => r.json());
  if (answer.error) { $("editor-stats").textContent = answer.error; return answer; }
  const s = answer.stats;
  $("editor-stats").textContent = `${s.pixels} px  mean ${fmt(s.mean)}  std ${fmt(s.std)}\np05 ${fmt(s.p05)}  median ${fmt(s.median)}  p95 ${fmt(s.p95)}`;
  $("editor-toml").value = answer.toml;
  return answer;
}

// -- commands ----------------------------------------------------------------------------------------

function startCommands() {
  for (const button of document.querySelectorAll("[data-command]")) {
    button.disabled = info.read_only;
    button.addEventListener("click", async () => {
      const answer = await fetch("/api/command", { method: "POST", headers: { "Content-Type": "application/json",
        Authorization: `Bearer ${$("token").value}` }, body: JSON.stringify({ device: selected, command: button.dataset.command }) });
      const body = await answer.json();
      $("command-result").textContent = answer.ok ? `${button.dataset.command} sent to ${selected}` : body.error;
    });
  }
  $("mode").textContent = info.read_only ? "read-only (no command token configured)" : "commands need the token";
  $("token-box").hidden = info.read_only;
}

// -- live updates ------------------------------------------------------------------------------------

function connect() {
  const source = new EventSource("/api/events");
  source.addEventListener("open", () => { $("link").textContent = "live"; $("link").className = "badge online"; });
  source.addEventListener("error", () => {
    $("link").textContent = "reconnecting…"; $("link").className = "badge offline";
    if (source.readyState !== EventSource.CLOSED) return;  // the browser retries by itself
    // refused (401: the login expired; 503: too many open pages): ask why, then log in or retry
    fetch("/api/info").then((r) => { if (r.status === 401) location.assign("/login"); }).catch(() => {});
    setTimeout(connect, 5000);
  });
  source.addEventListener("snapshot", (event) => {
    devices.clear();
    for (const device of JSON.parse(event.data)) devices.set(device.device, device);
    renderCards(); renderDetail();
  });
  source.addEventListener("device", (event) => {
    const update = JSON.parse(event.data);
    const known = devices.get(update.device);
    update.alerts = known ? known.alerts : [];
    devices.set(update.device, update);
    renderCard(update.device);
    if (update.device === selected) { renderDetail(); appendLive(update); }
  });
  source.addEventListener("alert", (event) => {
    const { device, alert } = JSON.parse(event.data);
    const known = devices.get(device);
    if (!known) return;
    known.alerts = [...(known.alerts || []), alert].slice(-50);
    if (device === selected) {
      renderAlerts(known);
      if (history.device === device && (alert.region === history.region || !alert.region)) {
        history.alerts.push(alert);
        if (plot) plot.redraw();
        edgedsmKinetics.redraw(); // a stage reached: its mark
      }
    }
  });
  source.addEventListener("map", (event) => {
    const update = JSON.parse(event.data);
    const known = devices.get(update.device);
    if (!known) return;
    known.maps = { ...(known.maps || {}), [update.map]: update };
    if (update.device === selected) renderMapSelect(known);
  });
  return source;
}

async function main() {
  const answer = await fetch("/api/info");
  if (answer.status === 401) { location.assign("/login"); return; }
  info = await answer.json();
  startCommands();
  startEditor();
  $("region-select").addEventListener("change", loadHistory);
  $("range-select").addEventListener("change", loadHistory);
  $("map-select").addEventListener("change", () => { $("map-select").dataset.chosen = $("map-select").value; renderMap(); });
  $("kinetics-view").addEventListener("change", () => edgedsmKinetics.setView($("kinetics-view").value));
  window.addEventListener("resize", () => { if (plot) plot.setSize({ width: plotWidth(), height: 260 }); edgedsmKinetics.resize(); });
  connect();
}

// for the browser tests and for curious operators (read-only views of what is drawn)
window.edgedsmDashboard = {
  select, loadHistory, measure, loadCommissioning,
  commissioning: () => commissioning,
  plotPoints: () => (plot ? plot.data[0].map((t, i) => [t, plot.data[1][i]]) : []),
  plotCaption: () => $("plot-caption").textContent,
  thresholds: () => history.thresholds,
  kinetics: () => edgedsmKinetics.state(),
  kineticsPos: (values) => edgedsmKinetics.pos(values),
  kineticsView: (name) => edgedsmKinetics.setView(name),
};

main();
