// The viewer of a recording: the analysis (analyze --json of the same
// inputs) as figures and tables, the stitched profile along the track
// asked of the server for the stretch shown (each bin's lowest and highest
// height per line), and the kept frames to scrub through. Read-only.
"use strict";

const $ = (id) => document.getElementById(id);
const COLOURS = ["#1f77b4", "#d62728", "#2ca02c"];
let meta = null;
let view = null; // { from, to } in mm
let profile = null;
let pending = 0;
let frameTimer = null;

function fmt(v, digits, unit) {
  if (v === null || v === undefined || !Number.isFinite(v)) return "–";
  return v.toFixed(digits) + (unit ? " " + unit : "");
}

// Chainage in km+m, as the report writes it.
function chainage(mm) {
  if (!Number.isFinite(mm)) return "–";
  const sign = mm < 0 ? "-" : "";
  const m = Math.abs(mm) / 1000;
  const km = Math.floor(m / 1000);
  return sign + km + "+" + (m - km * 1000).toFixed(3).padStart(7, "0");
}

function row(tbody, cells, cls) {
  const tr = document.createElement("tr");
  if (cls) tr.className = cls;
  for (const c of cells) {
    const td = document.createElement("td");
    td.textContent = c;
    tr.appendChild(td);
  }
  tbody.appendChild(tr);
}

// A spectrum's ISO 3095 third octaves by verdict in words, as the text
// summary writes them (reprofiling::Iso3095::words).
function isoWords(i) {
  const list = (e) => e.join(", ");
  let s = i.verdict === null ? "no ISO 3095 limit"
    : i.verdict === "EXCEEDS" ? "EXCEEDS at " + list(i.exceeded_mm) + " mm" : i.verdict;
  if (i.verdict !== null && i.not_judged_mm.length) {
    s += (i.exceeded_mm.length ? "; not judged at " : " at ") + list(i.not_judged_mm) + " mm";
  }
  return s;
}

// A block's verdict: the energy average's, and each line's whose verdict
// differs (reprofiling::block_iso3095_words).
function blockIsoWords(b) {
  if (!b.iso3095) return "no spectrum";
  let s = isoWords(b.iso3095);
  for (const l of b.lines) {
    if (l.iso3095.verdict !== b.iso3095.verdict) s += "; laser " + l.laser + " " + isoWords(l.iso3095);
  }
  return s;
}

// The rail's level and interval as the text summary writes it (detection::RailLevel).
function railText(d) {
  const v = (x) => (x === null || x === undefined ? "-" : x.toFixed(1));
  const lo = d.rail_lo_db, hi = d.rail_hi_db;
  const range = lo !== null && hi !== null ? "[" + v(lo) + ", " + v(hi) + "]"
    : hi !== null ? "[under " + v(hi) + "]" : lo !== null ? "[over " + v(lo) + "]" : "[unbounded]";
  return v(d.rail_db) + " " + range;
}

// One third octave's cell: its verdict, and the rail with its interval where not within.
function isoCell(b) {
  const d = b && b.decision;
  if (!d) return "–";
  return d.verdict === "within" ? "within" : d.verdict + ": rail " + railText(d) + " dB";
}

// Each section's third octaves with a limit: every line's verdict and the energy average's.
function isoTable(a) {
  const t = $("iso3095");
  const spectra = [];
  for (const l of a.lasers || []) {
    if (l.en15610 && l.en15610.bands) spectra.push({ section: l.section, name: "laser " + l.laser, bands: l.en15610.bands });
  }
  for (const rb of (a.noise && a.noise.running_bands) || []) {
    if (rb.en15610) spectra.push({ section: rb.section, name: "energy average", bands: rb.en15610.bands });
  }
  const names = [...new Set(spectra.map((s) => s.name))];
  const head = t.tHead.rows[0];
  for (const n of names) {
    const th = document.createElement("th");
    th.textContent = n;
    head.appendChild(th);
  }
  const sections = [...new Set(spectra.map((s) => s.section))];
  for (const sec of sections) {
    const of = spectra.filter((s) => s.section === sec);
    const waves = [...new Set(of.flatMap((s) => s.bands.filter((b) => b.decision).map((b) => b.nominal_wavelength_mm)))];
    for (const w of waves) {
      const cells = names.map((n) => {
        const s = of.find((x) => x.name === n);
        return isoCell(s && s.bands.find((b) => b.nominal_wavelength_mm === w));
      });
      const limit = of.flatMap((s) => s.bands).find((b) => b.nominal_wavelength_mm === w).iso3095_limit_db;
      row(t.tBodies[0], [String(sec), w + " mm", fmt(limit, 1, "dB"), ...cells],
        cells.some((c) => c.startsWith("EXCEEDS")) ? "fail" : "");
    }
  }
}

function tables(a) {
  const v = a.verdict;
  const bands = $("bands").tBodies[0];
  let failed = 0;
  let notJudged = 0;
  for (const b of v.bands) {
    // Only a judged band fails: one whose noise floor allows a verdict.
    const verdict = b.not_evaluated ? "not evaluated"
      : b.not_judged ? b.not_judged
      : b.passes === true ? "pass" : b.passes === false ? "over the limit" : "not judged (no limit)";
    if (b.passes === false) failed += 1;
    if (b.not_judged) notJudged += 1;
    const floor = b.floor ? fmt((v.edition.endsWith("2012") ? b.floor.peak_mm : b.floor.average_mean_pp_mm) * 1000, 1, "µm") : "–";
    row(bands, [b.lo_mm + "–" + b.hi_mm + " mm", fmt(b.limit_mm * 1000, 1, "µm"), floor, fmt(b.measured_mm / 1000, 1, "m"),
      fmt(b.exceeding_mm / 1000, 1, "m"), fmt(b.exceeding_percent, 1, "%"), verdict], b.passes === false ? "fail" : "");
  }
  const zones = $("zones").tBodies[0];
  for (const z of v.zones) {
    row(zones, [z.lo_mm + "–" + z.hi_mm + " mm", z.start_chainage, z.end_chainage, fmt(z.exceeding_mm / 1000, 2, "m"),
      fmt(z.worst_pp_mm * 1000, 1, "µm")]);
  }
  const blocks = $("blocks").tBodies[0];
  for (const b of v.blocks) {
    row(blocks, [chainage(b.start_mm), chainage(b.end_mm), ...b.rms_mm.map((r) => fmt(r === null ? NaN : r * 1000, 1)),
      blockIsoWords(b)], b.iso3095 && b.iso3095.verdict === "EXCEEDS" ? "fail" : "");
  }
  isoTable(a);
  const marks = a.marks || [];
  const mt = $("marks").tBodies[0];
  for (const m of marks) row(mt, [m.chainage || chainage(m.chainage_mm), m.kind || "", m.text || ""]);
  $("markcount").textContent = String(marks.length);
  const judged = v.bands.filter((b) => b.passes === true || b.passes === false).length;
  $("verdict").textContent = failed ? "reprofile" : judged ? "within the limits" : "not judged";
  $("verdict").className = failed ? "verdict failed" : judged ? "verdict good" : "verdict";
  $("verdictwhy").textContent = failed ? failed + " band(s) over the limit"
    : judged ? "every judged band passes" + (notJudged ? "; " + notJudged + " band(s) not judged at the noise floor" : "")
    : "no band's noise floor allows a verdict";
  $("reprofile").textContent = fmt(v.reprofile_mm / 1000, 1, "m");
  $("measured").textContent = fmt(v.measured_mm / 1000, 1, "m");
  $("edition").textContent = v.edition;
  $("block").textContent = fmt(v.block_mm / 1000, 0, "m");
  $("zonecount").textContent = String(v.zones.length);
  $("blockcount").textContent = String(v.blocks.length);
}

async function load() {
  const r = await fetch("/api/analysis");
  if (!r.ok) throw new Error("analysis: HTTP " + r.status);
  meta = await r.json();
  const a = meta.analysis;
  $("source").textContent = (a.runs || []).map((x) => x.recording).join(", ") || a.profile || "–";
  tables(a);
  $("sections").textContent = String((a.sections || []).length);
  $("frames").textContent = String(meta.frames_total);
  $("kept").textContent = meta.frames_kept + (meta.frame_every > 1 ? " (every " + meta.frame_every + ")" : "");
  if (meta.span_mm) {
    $("span").textContent = chainage(meta.span_mm[0]) + " – " + chainage(meta.span_mm[1]);
    view = { from: meta.span_mm[0], to: meta.span_mm[1] };
  }
  const legend = $("legend");
  for (const l of meta.lines) {
    const s = document.createElement("span");
    const sw = document.createElement("span");
    sw.className = "swatch l" + (l.laser % 3);
    s.appendChild(sw);
    s.appendChild(document.createTextNode("laser " + l.laser + (meta.lines.length > 3 ? " (section " + l.section + ")" : "")));
    legend.appendChild(s);
  }
  const z = document.createElement("span");
  const zs = document.createElement("span");
  zs.className = "swatch zone";
  z.appendChild(zs);
  z.appendChild(document.createTextNode("zone over the limit"));
  legend.appendChild(z);
  const scrub = $("scrub");
  scrub.max = String(Math.max(0, meta.frames_kept - 1));
  if (meta.frames_kept === 0) $("framebox").hidden = true;
  if (meta.frames_note) $("kept").textContent = meta.frames_note;
  $("conn").textContent = "loaded";
  $("conn").className = "ok";
  document.body.dataset.loaded = "1";
  await fetchProfile();
  if (meta.frames_kept > 0) await showFrame(0);
}

async function fetchProfile() {
  if (!view) return;
  const c = $("track");
  const bins = Math.min(8000, c.width);
  const id = ++pending;
  const r = await fetch("/api/profile?from_mm=" + view.from + "&to_mm=" + view.to + "&bins=" + bins);
  if (!r.ok || id !== pending) return;
  profile = await r.json();
  $("range").textContent = chainage(view.from) + " to " + chainage(view.to);
  $("from").value = (view.from / 1000).toFixed(3);
  $("to").value = (view.to / 1000).toFixed(3);
  drawTrack();
  document.body.dataset.profiles = String(Number(document.body.dataset.profiles || 0) + 1);
}

function axes(ctx, w, h, pad, x0, x1, y0, y1, xlabel, ylabel) {
  ctx.fillStyle = "#fff";
  ctx.fillRect(0, 0, w, h);
  ctx.strokeStyle = "#c5ccd3";
  ctx.strokeRect(pad.l, pad.t, w - pad.l - pad.r, h - pad.t - pad.b);
  ctx.fillStyle = "#5b6670";
  ctx.font = "12px system-ui, sans-serif";
  for (let i = 0; i <= 4; i += 1) {
    const y = pad.t + (h - pad.t - pad.b) * i / 4;
    ctx.fillText((y1 - (y1 - y0) * i / 4).toFixed(1), 4, y + 4);
    const x = pad.l + (w - pad.l - pad.r) * i / 4;
    ctx.fillText(xlabel(x0 + (x1 - x0) * i / 4), Math.min(x, w - 90), h - 6);
  }
  ctx.fillText(ylabel, 4, 12);
}

function drawTrack() {
  const c = $("track");
  const ctx = c.getContext("2d");
  const w = c.width, h = c.height, pad = { l: 56, r: 12, t: 18, b: 26 };
  let lo = Infinity, hi = -Infinity;
  for (const l of profile.lines) {
    for (let i = 0; i < profile.bins; i += 1) {
      if (l.min_um[i] !== null) lo = Math.min(lo, l.min_um[i]);
      if (l.max_um[i] !== null) hi = Math.max(hi, l.max_um[i]);
    }
  }
  if (!(hi > lo)) { lo = -1; hi = 1; }
  const m = (hi - lo) * 0.05;
  lo -= m; hi += m;
  axes(ctx, w, h, pad, view.from, view.to, lo, hi, chainage, "µm");
  const px = (mm) => pad.l + (mm - view.from) / (view.to - view.from) * (w - pad.l - pad.r);
  const py = (um) => pad.t + (hi - um) / (hi - lo) * (h - pad.t - pad.b);
  ctx.fillStyle = "#ffd7d288";
  for (const z of meta.analysis.verdict.zones) {
    if (z.end_mm < view.from || z.start_mm > view.to) continue;
    const a = Math.max(px(z.start_mm), pad.l), b = Math.min(px(z.end_mm), w - pad.r);
    ctx.fillRect(a, pad.t, Math.max(1, b - a), h - pad.t - pad.b);
  }
  const bw = (w - pad.l - pad.r) / profile.bins;
  for (const l of profile.lines) {
    ctx.strokeStyle = COLOURS[l.laser % 3];
    ctx.beginPath();
    for (let i = 0; i < profile.bins; i += 1) {
      if (l.min_um[i] === null) continue;
      const x = pad.l + (i + 0.5) * bw;
      ctx.moveTo(x, py(l.max_um[i]));
      ctx.lineTo(x, py(l.min_um[i]) + 0.5);
    }
    ctx.stroke();
  }
  for (const mk of meta.analysis.marks || []) {
    const x = px(mk.chainage_mm);
    if (x < pad.l || x > w - pad.r) continue;
    ctx.strokeStyle = "#6a1b9a";
    ctx.beginPath(); ctx.moveTo(x, pad.t); ctx.lineTo(x, h - pad.b); ctx.stroke();
    ctx.fillStyle = "#6a1b9a";
    ctx.fillText(mk.kind || "mark", x + 3, pad.t + 12);
  }
}

function zoom(factor, centre) {
  if (!view || !meta.span_mm) return;
  const c = centre === undefined ? (view.from + view.to) / 2 : centre;
  const span = Math.max(10, Math.min((view.to - view.from) * factor, meta.span_mm[1] - meta.span_mm[0]));
  let from = c - (c - view.from) / (view.to - view.from) * span;
  from = Math.max(meta.span_mm[0], Math.min(from, meta.span_mm[1] - span));
  view = { from, to: from + span };
  fetchProfile();
}

async function showFrame(i) {
  const r = await fetch("/api/frame?i=" + i);
  if (!r.ok) return;
  const f = await r.json();
  $("frameno").textContent = f.frame + " of " + meta.frames_total;
  $("frameseq").textContent = String(f.seq);
  $("frameodo").textContent = fmt(f.odometer_mm / 1000, 3, "m");
  const c = $("frame");
  const ctx = c.getContext("2d");
  const w = c.width, h = c.height, pad = { l: 56, r: 12, t: 18, b: 26 };
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const pts of f.lasers) for (const [a, z] of pts) {
    x0 = Math.min(x0, a); x1 = Math.max(x1, a); y0 = Math.min(y0, z); y1 = Math.max(y1, z);
  }
  if (!(x1 > x0)) { x0 = 0; x1 = 1; }
  if (!(y1 > y0)) { y0 -= 1; y1 += 1; }
  axes(ctx, w, h, pad, x0, x1, y0, y1, (v) => v.toFixed(1) + " mm", "µm");
  f.lasers.forEach((pts, k) => {
    ctx.fillStyle = COLOURS[k % 3];
    for (const [a, z] of pts) {
      ctx.fillRect(pad.l + (a - x0) / (x1 - x0) * (w - pad.l - pad.r) - 1,
        pad.t + (y1 - z) / (y1 - y0) * (h - pad.t - pad.b) - 1, 2, 2);
    }
  });
  document.body.dataset.frame = String(f.index);
}

function wire() {
  $("zoomin").addEventListener("click", () => zoom(0.5));
  $("zoomout").addEventListener("click", () => zoom(2));
  $("reset").addEventListener("click", () => { if (meta.span_mm) { view = { from: meta.span_mm[0], to: meta.span_mm[1] }; fetchProfile(); } });
  $("go").addEventListener("click", () => {
    const from = Number($("from").value) * 1000, to = Number($("to").value) * 1000;
    if (Number.isFinite(from) && Number.isFinite(to) && to > from) { view = { from, to }; fetchProfile(); }
  });
  const c = $("track");
  c.addEventListener("wheel", (e) => {
    e.preventDefault();
    const r = c.getBoundingClientRect();
    const frac = (e.clientX - r.left) / r.width;
    zoom(e.deltaY < 0 ? 0.8 : 1.25, view.from + frac * (view.to - view.from));
  }, { passive: false });
  let drag = null;
  c.addEventListener("mousedown", (e) => { drag = { x: e.clientX, view: { ...view } }; });
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("mousemove", (e) => {
    if (!drag || !meta.span_mm) return;
    const r = c.getBoundingClientRect();
    const span = drag.view.to - drag.view.from;
    let from = drag.view.from - (e.clientX - drag.x) / r.width * span;
    from = Math.max(meta.span_mm[0], Math.min(from, meta.span_mm[1] - span));
    view = { from, to: from + span };
    fetchProfile();
  });
  $("scrub").addEventListener("input", (e) => {
    clearTimeout(frameTimer);
    frameTimer = setTimeout(() => showFrame(Number(e.target.value)), 30);
  });
}

wire();
load().catch((e) => { $("conn").textContent = String(e); $("conn").className = "bad"; });
