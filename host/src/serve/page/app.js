// The live view: one WebSocket of updates from cms-host (the newest frame
// and every figure, as JSON), figures written on arrival, plots drawn on
// the next animation frame. The one thing it sends: an event mark
// (POST /marks), from a button or its key.
"use strict";

const $ = (id) => document.getElementById(id);
const lines = new Map(); // laser -> { root, canvas }
let latest = null;
let drawPending = false;
let updates = 0;
let firstUpdate = null;

function text(id, v) {
  const e = $(id);
  if (e.textContent !== v) e.textContent = v;
}

function fmt(v, digits, unit) {
  if (v === null || v === undefined || !Number.isFinite(v)) return "–";
  return v.toFixed(digits) + (unit ? " " + unit : "");
}

function line(k) {
  let l = lines.get(k);
  if (l) return l;
  const root = $("line").content.firstElementChild.cloneNode(true);
  root.id = "L" + k;
  root.querySelector(".k").textContent = k;
  const main = $("lines");
  const after = [...main.children].find((c) => Number(c.id.slice(1)) > k);
  main.insertBefore(root, after || null);
  l = { root, canvas: root.querySelector("canvas") };
  lines.set(k, l);
  return l;
}

function figures(u) {
  updates += 1;
  if (firstUpdate === null) firstUpdate = performance.now();
  text("updates", String(updates));
  text("phase", u.phase);
  text("port", u.port);
  const d = u.device;
  text("device", d ? `${d.board} ${d.firmware}, ${d.sensor_width}×${d.sensor_height}, ${d.calibrated ? "calibrated" : "uncalibrated (pixels)"}` : "–");
  const h = u.head;
  text("lasers", h ? (h.lasers_on === 0 ? "off" : "ON " + h.lasers_on.toString(2).padStart(3, "0")) + `, duty ${h.laser_duty_percent.toFixed(1)} %` + (h.fault ? `, fault ${h.fault}` : "") : "–");
  text("rec", u.recording ? "recording" : "not recording");
  text("fps", fmt(u.frames_per_s, 1));
  text("frames", String(u.frames));
  text("recorded", u.recorded === null ? "–" : String(u.recorded) + " messages");
  text("lost", String(u.lost_frames));
  text("headdropped", String(u.head_dropped_frames));
  text("damaged", String(u.damaged_frames));
  text("crc", String(u.crc_errors));
  text("resyncs", String(u.resyncs));
  text("reconnects", String(u.reconnects));
  text("odometer", fmt(u.odometer_m, 3, "m"));
  text("chainage", u.chainage === null ? "no survey" : u.chainage);
  const s = u.speed;
  text("speed", fmt(s.mm_s === null ? null : s.mm_s / 1000, 2, "m/s"));
  text("speedlimit", s.limit_mm_s === null ? (s.note || "–") : fmt(s.limit_mm_s / 1000, 2, "m/s"));
  text("speedwarn", s.over ? "too fast: frames no longer overlap enough to stitch" : "");
  $("speedbox").classList.toggle("over", s.over);
  text("viewdrop", String(u.view_dropped));
  text("skipped", String(u.page_skipped));
  text("pages", String(u.pages));
  const f = u.frame;
  text("seq", f ? String(f.seq) : "–");
  text("exposure", f ? f.exposure_us + " µs" : "–");
  if (f) {
    for (const l of f.lasers) {
      const r = line(l.laser).root;
      r.querySelector(".kept").textContent = String(l.kept);
      r.querySelector(".rejected").textContent = String(l.rejected);
      const why = {};
      for (const w of l.rejected_why) why[w] = (why[w] || 0) + 1;
      r.querySelector(".why").textContent = Object.entries(why).map(([w, n]) => `${n} ${w}`).join(", ");
      r.querySelector(".saturated").textContent = String(l.saturated_kept);
      r.querySelector(".strength").textContent = fmt(l.mean_strength, 0);
    }
  }
  // The one-sine fit: a diagnostic, never the rail's verdict (a rail of
  // several wavelengths does not fit one sine).
  const fits = { good: "fits", doubtful: "fits doubtfully", failed: "does not fit (several wavelengths?)", none: "none" };
  for (const c of u.corrugation) {
    const r = line(c.laser).root;
    r.querySelector(".wavelength").textContent = fmt(c.wavelength_mm, 1, "mm");
    r.querySelector(".amplitude").textContent = fmt(c.amplitude_um, 1, "µm");
    const v = r.querySelector(".verdict");
    v.textContent = "one sine " + (fits[c.verdict] || c.verdict);
    v.dataset.fit = c.verdict;
    r.querySelector(".reasons").textContent = c.reasons.join("; ");
  }
  bands(u.bands);
  iso(u.iso3095);
}

// Each line's EN 13231-3 bands since the start (the last stretch in
// brackets), the floor, and the running band's verdict.
function bands(b) {
  const body = $("bandtable").tBodies[0];
  if (!b) { text("bandsedition", "(no calibrated frames yet)"); return; }
  text("bandsedition", `${b.edition}: ${fmt(b.since_mm / 1000, 2, "m")} judged, last stretch ${fmt(b.recent_mm / 1000, 2, "m")}`);
  const lasers = b.lines.filter((l) => l.laser !== null);
  const rb = b.lines.find((l) => l.laser === null);
  $("bandtable").querySelector("th.cols").textContent = lasers.map((l) => "L" + l.laser).join(" · ") || "lines";
  const cell = (x) => !x ? "–" : x.since ? `${fmt(x.since.mean_pp_um, 1)} ± ${fmt(x.since.mean_pp_u_um, 1)}` + (x.recent ? ` (${fmt(x.recent.mean_pp_um, 1)})` : "") : "–";
  const cls = (s) => s.replace(" ", "");
  const rows = (lasers[0] || rb).bands.map((band, i) => {
    const judged = rb ? rb.bands[i] : band;
    const tr = document.createElement("tr");
    tr.dataset.state = judged.state;
    const add = (t, c, title) => { const td = document.createElement("td"); td.textContent = t; if (c) td.className = c; if (title) td.title = title; tr.appendChild(td); };
    add(band.band);
    add(fmt(band.limit_um, 0, "µm"));
    add(fmt(band.floor_um, 1, "µm"));
    add(lasers.map((l) => cell(l.bands[i])).join(" · "));
    add(rb ? cell(rb.bands[i]) : "–");
    add(judged.state === "within" || judged.state === "over" ? judged.state : judged.why, cls(judged.state), judged.why);
    return tr;
  });
  body.replaceChildren(...rows);
  const un = b.latest_unstitched[b.latest_unstitched.length - 1];
  text("unstitched", b.unstitched === 0 ? "every frame stitched" : `${b.unstitched} frame(s) would not stitch; latest seq ${un.seq} at ${fmt(un.odometer_mm / 1000, 3, "m")}, laser ${un.laser}: ${un.kind}, overlap ${fmt(un.overlap_mm, 1, "mm")} (analyze registers a frame from 3 mm)`);
  $("unstitched").className = b.unstitched === 0 ? "" : "warn";
}

// The latest stretch's ISO 3095 third octaves: each line's and the
// energy average's verdict as the viewer words it (within, or the verdict
// with the rail and its interval), with the level and the floor.
function iso(r) {
  const t = $("isotable");
  const lines = r ? r.lines : [];
  const name = (l) => (l.laser === null ? "energy average" : "L" + l.laser);
  const th = (s) => { const e = document.createElement("th"); e.textContent = s; return e; };
  t.tHead.rows[0].replaceChildren(th("third octave"), th("limit"), ...lines.map((l) => th(name(l))));
  text("isoverdicts", lines.map((l) => name(l) + ": " + (l.error ? "not evaluated: " + l.error : l.verdict)).join("; "));
  if (!r) { text("isostretch", "(no calibrated frames yet)"); t.tBodies[0].replaceChildren(); return; }
  text("isoconfidence", r.confidence_percent + " %");
  const track = `odometer ${fmt(r.from_odometer_mm / 1000, 2)}–${fmt(r.to_odometer_mm / 1000, 2, "m")}, ${fmt(r.gapless_mm / 1000, 2, "m")} without a gap`;
  if (r.state !== "evaluated") {
    text("isostretch", `(${track})`);
    const tr = document.createElement("tr");
    tr.dataset.state = r.state;
    const td = document.createElement("td");
    td.colSpan = 2;
    td.className = "notevaluated";
    td.textContent = r.why;
    tr.appendChild(td);
    t.tBodies[0].replaceChildren(tr);
    return;
  }
  text("isostretch", `(${track}; judged in ${fmt(r.cost_ms, 0, "ms")})`);
  const cls = { within: "within", EXCEEDS: "over", "not judged": "notjudged" };
  const waves = [...new Set(lines.flatMap((l) => l.bands.map((b) => b.wavelength_mm)))];
  const rows = waves.map((w) => {
    const tr = document.createElement("tr");
    tr.dataset.state = "evaluated";
    tr.dataset.wavelength = String(w);
    const add = (s, c, title) => { const td = document.createElement("td"); td.textContent = s; if (c) td.className = c; if (title) td.title = title; tr.appendChild(td); return td; };
    const any = lines.flatMap((l) => l.bands).find((b) => b.wavelength_mm === w);
    add(w + " mm");
    add(fmt(any.limit_db, 1, "dB"));
    for (const l of lines) {
      const b = l.bands.find((x) => x.wavelength_mm === w);
      if (!b) { add("–"); continue; }
      const figures = `level ${fmt(b.level_db, 1)}, floor ${fmt(b.floor_db, 1, "dB")}`;
      const s = b.verdict === "within" ? `within (${figures})` : `${b.verdict}: rail ${b.rail} dB (${figures})`;
      add(s, cls[b.verdict], b.words).dataset.verdict = b.verdict;
    }
    return tr;
  });
  t.tBodies[0].replaceChildren(...rows);
}

function ticks(lo, hi, n) {
  const span = hi - lo;
  if (!(span > 0)) return [lo];
  const raw = span / n;
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw);
  const out = [];
  for (let t = Math.ceil(lo / step) * step; t <= hi + 1e-9 * step; t += step) out.push(t);
  return out;
}

function extent(a, b) {
  let lo = Infinity, hi = -Infinity;
  for (const arr of [a, b]) for (const v of arr) { if (v < lo) lo = v; if (v > hi) hi = v; }
  if (!Number.isFinite(lo)) return [0, 1];
  if (hi - lo < 1e-9) return [lo - 1, hi + 1];
  const pad = (hi - lo) * 0.05;
  return [lo - pad, hi + pad];
}

function plot(l, metric, fullScale) {
  const c = line(l.laser).canvas;
  const g = c.getContext("2d");
  const W = c.width, H = c.height, L = 70, R = 60, T = 12, B = 34;
  g.clearRect(0, 0, W, H);
  // Metric: µm along → mm, nm of height → µm; else row and column, px.
  const sx = metric ? 1e-3 : 1, sy = metric ? 1e-3 : 1;
  const xs = l.x.map((v) => v * sx), ys = l.y.map((v) => v * sy);
  const rx = l.rejected_x.map((v) => v * sx), ry = l.rejected_y.map((v) => v * sy);
  const [x0, x1] = extent(xs, rx), [y0, y1] = extent(ys, ry);
  const px = (x) => L + (x - x0) / (x1 - x0) * (W - L - R);
  const py = (y) => H - B - (y - y0) / (y1 - y0) * (H - T - B);
  const ps = (s) => H - B - s / fullScale * (H - T - B);
  g.font = "13px system-ui, sans-serif";
  g.strokeStyle = "#d6dde3"; g.fillStyle = "#5b6670"; g.lineWidth = 1;
  g.textAlign = "center";
  for (const t of ticks(x0, x1, 8)) { g.beginPath(); g.moveTo(px(t), T); g.lineTo(px(t), H - B); g.stroke(); g.fillText(String(+t.toFixed(6)), px(t), H - B + 15); }
  g.fillText(metric ? "along the line, mm" : "image row, px", L + (W - L - R) / 2, H - 3);
  g.textAlign = "right";
  for (const t of ticks(y0, y1, 5)) { g.beginPath(); g.moveTo(L, py(t)); g.lineTo(W - R, py(t)); g.stroke(); g.fillText(String(+t.toFixed(6)), L - 6, py(t) + 4); }
  g.save(); g.translate(14, T + (H - T - B) / 2); g.rotate(-Math.PI / 2); g.textAlign = "center";
  g.fillText(metric ? "height, µm" : "stripe column, px", 0, 0); g.restore();
  g.textAlign = "left"; g.fillStyle = "#9aa5ae";
  g.fillText("strength", W - R + 6, T + 10);
  g.fillText(String(fullScale), W - R + 6, ps(fullScale) + 24);
  // Strength (grey, to the sensor's full scale on the right).
  g.strokeStyle = "#b8c1c8"; g.beginPath();
  l.strength.forEach((s, i) => { const X = px(xs[i]), Y = ps(s); i ? g.lineTo(X, Y) : g.moveTo(X, Y); });
  g.stroke();
  // The profile (blue), saturated points (orange), rejected candidates (red ×).
  g.strokeStyle = "#1565c0"; g.lineWidth = 1.5; g.beginPath();
  xs.forEach((x, i) => { const X = px(x), Y = py(ys[i]); i ? g.lineTo(X, Y) : g.moveTo(X, Y); });
  g.stroke();
  g.fillStyle = "#ef6c00";
  l.saturated.forEach((s, i) => { if (s) g.fillRect(px(xs[i]) - 2, py(ys[i]) - 2, 4, 4); });
  g.strokeStyle = "#c62828"; g.lineWidth = 1.2;
  rx.forEach((x, i) => { const X = px(x), Y = py(ry[i]); g.beginPath(); g.moveTo(X - 3, Y - 3); g.lineTo(X + 3, Y + 3); g.moveTo(X + 3, Y - 3); g.lineTo(X - 3, Y + 3); g.stroke(); });
}

function draw() {
  drawPending = false;
  const u = latest;
  if (!u || !u.frame) return;
  const bits = u.device ? u.device.bits : 8;
  for (const l of u.frame.lasers) plot(l, u.frame.units === "metric", (1 << bits) - 1);
}

function connect() {
  const ws = new WebSocket(`${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws`);
  ws.onopen = () => { text("conn", "live"); $("conn").className = "ok"; };
  ws.onmessage = (ev) => {
    const u = JSON.parse(ev.data);
    latest = u;
    figures(u);
    if (!drawPending) { drawPending = true; requestAnimationFrame(draw); }
  };
  ws.onclose = () => {
    text("conn", "disconnected: retrying");
    $("conn").className = "bad";
    setTimeout(connect, 1000);
  };
}

// Event marks: a button, or its key while the text box is not being typed
// in; the answer (the mark as recorded, or why not) shown beside them.
const markKeys = { w: "weld", j: "joint", k: "kilometre_post", d: "defect", n: "note" };
let marksMade = 0;

async function mark(kind) {
  const box = $("marktext");
  const result = $("markresult");
  result.className = "";
  result.textContent = "marking…";
  try {
    const r = await fetch("/marks", {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ kind, text: box.value }),
    });
    const body = await r.text();
    if (r.status === 201) {
      const m = JSON.parse(body);
      marksMade += 1;
      const at = m.chainage ? `chainage ${m.chainage}` : `odometer ${fmt(m.odometer_mm, 1, "mm")}`;
      result.textContent = `${m.kind.replace("_", " ")}${m.text ? " “" + m.text + "”" : ""} marked at ${at}`;
      result.className = "ok";
      box.value = "";
    } else {
      result.textContent = `not marked: ${body.trim()}`;
      result.className = "bad";
    }
  } catch (e) {
    result.textContent = `not marked: ${e}`;
    result.className = "bad";
  }
}

for (const b of document.querySelectorAll("#marks button")) b.addEventListener("click", () => mark(b.dataset.kind));
document.addEventListener("keydown", (ev) => {
  if (ev.target === $("marktext")) {
    if (ev.key === "Escape") ev.target.blur();
    return;
  }
  const kind = markKeys[ev.key.toLowerCase()];
  if (kind && !ev.ctrlKey && !ev.metaKey && !ev.altKey) { ev.preventDefault(); mark(kind); }
});

// For a test or a person with the console: updates received, and since when.
window.cmsView = () => ({ updates, marks: marksMade, since_ms: firstUpdate === null ? null : performance.now() - firstUpdate });
connect();
