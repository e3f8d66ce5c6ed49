// The live page of `eskin listen --web`: read-only, fed by the WebSocket /ws (docs/live-page.md).
"use strict";

const MAX_POINTS = 1000;          // trace points kept (about 6 s at 10 frames/s x 16 points)
const MAX_ROWS = 500;             // decisions kept in the table
const DRAW_MS = 100;              // the canvases are drawn at most this often (10 a second)
const RAMP = ["#262626", "#4d4d4d", "#00005f", "#0000ff", "#005f00", "#00d700", "#ffff00",
              "#ff8700", "#d70000", "#ff0000"];   // the terminal view's colours
const COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
                 "#7f7f7f", "#bcbd22", "#17becf"];

const st = { grid: null, energy: null, trace: [], windows: [], info: null, stopped: false,
             selected: "all", rate: 3000, failures: 0, n: 0, ws: null, drawAt: 0,
             drawPending: false, statsKeys: "", rows: [], clearRows: false, stats: null,
             accuracy: undefined, canvases: true };

const $ = (id) => document.getElementById(id);

function setStatus(cls, text) {
  const el = $("status");
  el.className = "status " + cls;
  el.textContent = text;
}

function esc(s) {
  return String(s).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;",
    '"': "&quot;", "'": "&#39;" }[c]));
}

function decisionRow(d) {
  const tr = document.createElement("tr");
  tr.className = d.right === true ? "right" : d.right === false ? "wrong" : "";
  tr.dataset.n = d.n;
  const values = d.values.map((v) => (v === null ? "-" : (v >= 0 ? "+" : "") + v.toFixed(3)));
  tr.innerHTML = `<td>${d.n}</td><td>${esc(d.source)}</td><td>${d.onset_s.toFixed(2)} s</td>` +
    `<td>${d.duration_ms.toFixed(0)} ms</td><td class="label">${esc(d.label)}` +
    (d.dont_know ? ' <span class="dk">(don\'t know)</span>' : "") + "</td>" +
    `<td>${d.true === null ? "" : esc(d.true)}</td><td>${d.latency_ms.toFixed(2)} ms</td>` +
    `<td class="values">${esc(values.join(", "))}</td><td>${d.lost || ""}</td>`;
  return tr;
}

// A decision is kept at once (the traces' touch windows); its row is added with the next drawing.
function addDecision(d) {
  if (d.n <= st.n) return;   // numbered in order: already shown
  st.rows.push(d);
  if (st.rows.length > MAX_ROWS) st.rows.shift();
  st.windows.push(d);
  if (st.windows.length > 200) st.windows.shift();
  st.n = d.n;
}

function showRows() {
  const body = $("decision-rows");
  if (st.clearRows) body.textContent = "";
  st.clearRows = false;
  if (st.rows.length) {
    const rows = document.createDocumentFragment();
    for (let k = st.rows.length - 1; k >= 0; k--) rows.appendChild(decisionRow(st.rows[k]));
    body.insertBefore(rows, body.firstChild);
    st.rows = [];
    while (body.rows.length > MAX_ROWS) body.deleteRow(body.rows.length - 1);
  }
  const count = String(st.n);
  if ($("count").textContent !== count) $("count").textContent = count;
}

const MAIN_STATS = [["frames", "frames"], ["samples", "samples"], ["lost_samples", "lost samples"],
  ["crc_errors", "CRC errors"], ["malformed", "malformed"], ["sequence_gaps", "sequence gaps"],
  ["absurd_frames", "refused frames"], ["controller_dropped_samples", "controller dropped"],
  ["decisions_controller", "decisions (controller)"], ["decisions_host", "decisions (host)"],
  ["controller_state", "controller state"], ["elapsed_s", "elapsed (s)"]];
const BAD = new Set(["lost_samples", "crc_errors", "malformed", "controller_dropped_samples"]);

function showStats(s) {
  if (!s) return;
  st.lastStats = s;
  const keys = Object.keys(s).join(",");
  if (keys !== st.statsKeys) {   // the rows are built once; later only their numbers change
    st.statsKeys = keys;
    $("stats").tBodies[0].innerHTML = MAIN_STATS.filter(([k]) => k in s).map(([k, name]) =>
      `<tr><td>${name}</td><td data-key="${k}"></td></tr>`).join("");
    $("all-stats").tBodies[0].innerHTML = Object.keys(s).map((k) =>
      `<tr><td>${esc(k)}</td><td data-all="${esc(k)}"></td></tr>`).join("");
  }
  for (const td of $("stats").querySelectorAll("td[data-key]")) {
    const k = td.dataset.key, text = String(s[k]);
    if (td.textContent !== text) td.textContent = text;
    td.className = BAD.has(k) && s[k] > 0 ? "bad" : "";
  }
  if (!$("all-stats").closest("details").open) return;   // not shown: not filled
  for (const td of $("all-stats").querySelectorAll("td[data-all]")) {
    const text = JSON.stringify(s[td.dataset.all]);
    if (td.textContent !== text) td.textContent = text;
  }
}

function showAccuracy(acc) {
  const parts = Object.entries(acc || {}).map(([src, a]) =>
    `<div><b>${esc(src)}</b>: ${a.right}/${a.scored} decisions right ` +
    `(${(100 * a.right / Math.max(1, a.scored)).toFixed(1)} %), ${a.dont_know} don't know</div>`);
  $("accuracy").innerHTML = parts.length ? parts.join("") : "-";
}

function showInfo(info) {
  if (!info) return;
  st.info = info;
  st.rate = info.rate;
  $("header").textContent = `${PORT} \u00b7 grid ${info.rows}x${info.cols} \u00b7 ` +
    `${info.rate} Hz \u00b7 x${info.speed} \u00b7 classes: ${info.classes.join(", ") || "-"}`;
}

function setGrid(grid) {
  if (!grid || (st.grid && st.grid[0] === grid[0] && st.grid[1] === grid[1])) return;
  st.grid = grid;
  const sel = $("taxel");
  sel.innerHTML = '<option value="all">all</option>';
  for (let k = 0; k < grid[0] * grid[1]; k++) {
    const o = document.createElement("option");
    o.value = k;
    o.textContent = `(${Math.floor(k / grid[1])}, ${k % grid[1]})`;
    sel.appendChild(o);
  }
  sel.value = st.selected;
  if (sel.value !== st.selected) { st.selected = "all"; sel.value = "all"; }
}

function drawHeat() {
  const c = $("heat"), g = c.getContext("2d");
  g.fillStyle = "#fff";
  g.fillRect(0, 0, c.width, c.height);
  if (!st.grid || !st.energy) {
    g.fillStyle = "#666";
    g.fillText("(no data yet)", 10, 20);
    return;
  }
  const [rows, cols] = st.grid, w = c.width / cols, h = c.height / rows;
  const top = Math.max(10, ...st.energy);
  g.font = "12px system-ui, sans-serif";
  g.textAlign = "center";
  for (let r = 0; r < rows; r++) {
    for (let k = 0; k < cols; k++) {
      const v = st.energy[r * cols + k];
      const level = v <= 0 ? 0 : Math.min(RAMP.length - 1, Math.max(0,
        Math.floor(Math.log10(Math.max(v, 1)) / Math.log10(top) * (RAMP.length - 1))));
      g.fillStyle = RAMP[level];
      g.fillRect(k * w + 1, r * h + 1, w - 2, h - 2);
      g.fillStyle = level >= 6 ? "#000" : "#fff";
      g.fillText(v.toFixed(0), k * w + w / 2, r * h + h / 2 + 4);
      if (String(r * cols + k) === st.selected) {
        g.strokeStyle = "#fff";
        g.lineWidth = 3;
        g.strokeRect(k * w + 2, r * h + 2, w - 4, h - 4);
      }
    }
  }
}

function drawTrace() {
  const c = $("trace");
  if (c.width !== c.clientWidth && c.clientWidth > 0) c.width = c.clientWidth;
  const g = c.getContext("2d"), W = c.width, H = c.height;
  g.fillStyle = "#fff";
  g.fillRect(0, 0, W, H);
  const pts = st.trace;
  if (pts.length < 2) return;
  const s0 = pts[0][0], s1 = pts[pts.length - 1][0], span = Math.max(1, s1 - s0);
  const x = (s) => ((s - s0) / span) * (W - 50) + 45;
  const taxels = st.selected === "all" ? [...pts[0][1].keys()] : [Number(st.selected)];
  let lim = 1;
  for (const [, v] of pts) for (const k of taxels) lim = Math.max(lim, Math.abs(v[k]));
  const y = (v) => H / 2 - (v / lim) * (H / 2 - 12);
  g.font = "11px system-ui, sans-serif";
  for (const d of st.windows) {   // touch windows, labelled
    if (d.offset < s0 || d.onset > s1) continue;
    const a = x(Math.max(d.onset, s0)), b = x(Math.min(d.offset, s1));
    g.fillStyle = d.source === "host" ? "rgba(255, 165, 0, 0.18)" : "rgba(70, 130, 180, 0.18)";
    g.fillRect(a, d.source === "host" ? H / 2 : 0, Math.max(2, b - a), H / 2);
    g.fillStyle = "#333";
    g.fillText(d.label + (d.dont_know ? "?" : ""), a + 2, d.source === "host" ? H - 4 : 12);
  }
  g.strokeStyle = "#bbb";
  g.beginPath(); g.moveTo(45, y(0)); g.lineTo(W, y(0)); g.stroke();
  g.fillStyle = "#666";
  g.fillText(`${lim.toFixed(0)}`, 2, 12);
  g.fillText(`-${lim.toFixed(0)}`, 2, H - 4);
  g.fillText(`${(s0 / st.rate).toFixed(1)} s`, 45, H / 2 - 4);
  g.fillText(`${(s1 / st.rate).toFixed(1)} s`, W - 40, H / 2 - 4);
  for (const k of taxels) {
    g.strokeStyle = COLOURS[k % COLOURS.length];
    g.lineWidth = taxels.length === 1 ? 1.5 : 1;
    g.beginPath();
    pts.forEach(([s, v], i) => (i ? g.lineTo(x(s), y(v[k])) : g.moveTo(x(s), y(v[k]))));
    g.stroke();
  }
}

// What arrived since the last drawing, shown at once: the document changes (and is laid out and
// painted) at most once every DRAW_MS, however many messages came in between.
function draw() {
  showRows();
  if (st.stats) showStats(st.stats);
  st.stats = null;
  if (st.accuracy !== undefined) showAccuracy(st.accuracy);
  st.accuracy = undefined;
  if (st.canvases) { drawHeat(); drawTrace(); }
  st.canvases = false;
}

// Drawn in an animation frame at most every DRAW_MS, and only after something changed (no
// animation loop runs while nothing arrives; a hidden tab draws nothing).
function redraw() {
  if (st.drawPending) return;
  st.drawPending = true;
  setTimeout(() => requestAnimationFrame(() => {
    st.drawPending = false;
    st.drawAt = performance.now();
    draw();
  }), Math.max(0, st.drawAt + DRAW_MS - performance.now()));
}

function onMessage(m) {
  redraw();
  if (m.type !== "stats") st.canvases = true;
  switch (m.type) {
    case "hello":
      st.trace = m.trace || [];
      st.energy = m.energy;
      st.windows = [];
      setGrid(m.grid);
      showInfo(m.info);
      st.clearRows = true;
      st.rows = [];
      st.n = 0;
      for (const d of m.decisions) addDecision(d);
      st.n = m.n_decisions;
      st.stats = m.stats;
      st.accuracy = m.accuracy;
      if (m.status === "stopped") onStopped(m);
      else setStatus("live", "live");
      break;
    case "frame":
      setGrid(m.grid);
      st.energy = m.energy;
      st.trace.push(...m.trace);
      if (st.trace.length > MAX_POINTS) st.trace.splice(0, st.trace.length - MAX_POINTS);
      break;
    case "decision": addDecision(m.decision); st.accuracy = m.accuracy; break;
    case "stats": st.stats = m.stats; break;
    case "info": showInfo(m.info); break;
    case "connection":
      if (!st.stopped) setStatus(m.connection.state === "disconnected" ? "lost" : "live",
        `${m.connection.state}${m.connection.reason ? ": " + m.connection.reason : ""}`);
      break;
    case "stopped": onStopped(m); break;
  }
}

function onStopped(m) {
  st.stopped = true;
  setStatus("stopped", "stopped: the listener has ended");
  if (m.stats) st.stats = m.stats;
  if (m.accuracy) st.accuracy = m.accuracy;
  if (m.summary && m.summary.length) $("summary").textContent = m.summary.join("\n");
}

function connect() {
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
  st.ws = ws;
  ws.onopen = () => { st.failures = 0; };
  ws.onmessage = (e) => onMessage(JSON.parse(e.data));
  ws.onclose = () => {
    if (st.stopped) return;   // the listener said it stopped: nothing to reconnect to
    st.failures += 1;
    if (st.failures >= 3) setStatus("stopped", "stopped: no listener at this address");
    else setStatus("lost", "connection lost: reconnecting");
    setTimeout(connect, st.failures >= 3 ? 5000 : 1000);
  };
}

const PORT = $("header").textContent.split(" \u00b7 ")[0];
$("taxel").addEventListener("change", (e) => { st.selected = e.target.value; redraw(); });
$("heat").addEventListener("click", (e) => {
  if (!st.grid) return;
  const c = $("heat"), r = c.getBoundingClientRect();
  const col = Math.floor(((e.clientX - r.left) / r.width) * st.grid[1]);
  const row = Math.floor(((e.clientY - r.top) / r.height) * st.grid[0]);
  const k = String(row * st.grid[1] + col);
  st.selected = st.selected === k ? "all" : k;
  $("taxel").value = st.selected;
  redraw();
});
$("all-stats").closest("details").addEventListener("toggle", () => {
  st.statsKeys = "";   // filled when opened
  if (st.lastStats) showStats(st.lastStats);
});
if ($("status").classList.contains("stopped")) st.stopped = true;
else setStatus("connecting", "connecting");
connect();   // also when stopped: the final state (heat map, traces) until the server closes
redraw();
