// hilbench scope: the page's own canvas renderer (no third-party code).
// Data arrive as frames of min/max envelopes per display bucket (see hilbench/scope/stream.py);
// each chosen column is drawn in a lane of its own with its own axis and unit, or shares another's
// lane (S.lane: column -> the column whose lane it joins; the reference joins the speed by default).
"use strict";

const COLOURS = ["#5ab0f0", "#f0a05a", "#7fd07f", "#e070c0", "#e0d060", "#60d0d0", "#b090f0", "#f07070"];
const MARK_COLOURS = { event: "#8fa0b0", param: "#6fcf7f", guard: "#e8b44c", fault: "#ef6b6b" };
const DEFAULT_COLUMNS = ["speed_rpm", "ref_speed_rpm", "ia_a", "ib_a", "ic_a", "duty_a", "hall_a", "hall_b", "hall_c", "sector"];
const KEEP_S = 120;  // live: seconds of data kept in the page
const DEFAULT_LANES = { ref_speed_rpm: "speed_rpm", measured_speed_rpm: "speed_rpm" };

const S = window.scope = {
  meta: null, units: {}, data: new Map(), selected: [], markers: [], status: {}, tLatest: 0, tFirst: null,
  frames: 0, paused: false, windowS: 2, viewEnd: null, cursors: [null, null], closed: null,
  trigger: { state: "idle", source: "ref", armedAt: 0, tTrig: null }, captures: [], showCapture: false,
  replies: [], params: {}, lastParamResult: {}, lane: { ...DEFAULT_LANES }, edited: {},
};
const $ = (id) => document.getElementById(id);
let ws = null, nextId = 1, dirty = true;
const seenMarks = new Set();

// ------------------------------------------------------------------ data
function decode(b64) {
  const bin = atob(b64), bytes = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  return new Float32Array(bytes.buffer);
}

function addFrame(f) {
  for (const [name, [lo, hi]] of Object.entries(f.cols)) {
    if (!S.data.has(name)) S.data.set(name, []);
    S.data.get(name).push({ t0: f.t0, dt: f.dt, n: f.n, lo: decode(lo), hi: decode(hi) });
  }
  const tEnd = f.t0 + f.n * f.dt;
  if (tEnd > S.tLatest) S.tLatest = tEnd;
  if (S.tFirst === null || f.t0 < S.tFirst) S.tFirst = f.t0;
  S.frames++;
}

function trim() {
  const limit = S.tLatest - KEEP_S;
  for (const segs of S.data.values()) while (segs.length && segs[0].t0 + segs[0].n * segs[0].dt < limit) segs.shift();
  while (S.markers.length && S.markers[0][0] < limit) S.markers.shift();
}

// segments of a column clipped to [ta, tb] (copies, for captures)
function clip(segs, ta, tb) {
  const out = [];
  for (const s of segs) {
    const i0 = Math.max(0, Math.floor((ta - s.t0) / s.dt)), i1 = Math.min(s.n, Math.ceil((tb - s.t0) / s.dt));
    if (i1 > i0) out.push({ t0: s.t0 + i0 * s.dt, dt: s.dt, n: i1 - i0, lo: s.lo.slice(i0, i1), hi: s.hi.slice(i0, i1) });
  }
  return out;
}

function valueAt(segs, t) {
  for (let k = segs.length - 1; k >= 0; k--) {
    const s = segs[k], i = Math.floor((t - s.t0) / s.dt);
    if (i >= 0 && i < s.n) return [s.lo[i], s.hi[i]];
  }
  return null;
}

// ------------------------------------------------------------------ messages
function onMessage(msg) {
  if (msg.type === "stream") {
    if (msg.meta) setMeta(msg.meta);
    if (msg.replace) { S.data.clear(); }
    for (const f of msg.frames) addFrame(f);
    for (const m of msg.markers || []) {
      S.markers.push(m);
      const key = m.join("|");
      if (!seenMarks.has(key)) { seenMarks.add(key); logMarker(m); }
    }
    S.markers.sort((a, b) => a[0] - b[0]);
    if (msg.status) setStatus(msg.status);
    if (S.meta && S.meta.live) trim();
    if (msg.replace && S.tFirst !== null) { S.windowS = Math.max(1e-3, S.tLatest - S.tFirst); S.viewEnd = S.tLatest; }
    checkTrigger();
    dirty = true;
  } else if (msg.type === "reply") {
    S.replies.push(msg);
    onReply(msg);
  } else if (msg.type === "closed") {
    S.closed = msg.reason;
    $("conn").textContent = "closed: " + msg.reason; $("conn").className = "fig bad";
  }
}

function setMeta(meta) {
  const first = S.meta === null;
  S.meta = meta;
  S.data.clear(); S.markers = []; S.tLatest = 0; S.tFirst = null;
  S.units = Object.fromEntries(meta.columns.map(([n, u]) => [n, u]));
  $("title").textContent = `${meta.target}${meta.firmware ? " · " + meta.firmware : ""} · ${meta.mode}`;
  for (const el of document.querySelectorAll(".live-only")) el.classList.toggle("hidden", !meta.live);
  if (!first) return;
  const names = meta.columns.map((c) => c[0]).filter((n) => n !== "t_s" && n !== "seq");
  S.selected = DEFAULT_COLUMNS.filter((n) => names.includes(n));
  const box = $("cols"); box.innerHTML = "";
  const analog = names.filter((n) => S.units[n] !== "bit");
  for (const n of names) {
    const row = document.createElement("div");
    const l = document.createElement("label");
    l.title = `${n} [${S.units[n] || ""}]`;
    l.innerHTML = `<input type="checkbox" data-col="${n}" ${S.selected.includes(n) ? "checked" : ""}> ${n} <span class="unit">${S.units[n] || ""}</span>`;
    row.appendChild(l);
    if (S.units[n] !== "bit") {
      const sel = document.createElement("select");
      sel.id = `lane-${n}`; sel.dataset.lane = n; sel.title = `the lane ${n} is drawn in`;
      sel.innerHTML = `<option value="">own lane</option>` + analog.filter((m) => m !== n).map((m) => `<option value="${m}">with ${m}</option>`).join("");
      sel.value = S.lane[n] && analog.includes(S.lane[n]) ? S.lane[n] : "";
      row.appendChild(sel);
    }
    box.appendChild(row);
  }
  box.addEventListener("change", (e) => {
    if (e.target.dataset.lane) { S.lane[e.target.dataset.lane] = e.target.value || undefined; dirty = true; return; }
    S.selected = [...box.querySelectorAll("input:checked")].map((el) => el.dataset.col);
    subscribe();
  });
  $("trig-col").innerHTML = analog.map((n) => `<option value="${n}">${n}</option>`).join("");
  if (analog.includes("speed_rpm")) $("trig-col").value = "speed_rpm";
  buildParams(meta);
  if (!meta.live) { S.paused = true; $("pause").textContent = "run"; }
  subscribe();
}

function buildParams(meta) {
  const box = $("params"); box.innerHTML = "";
  const names = Object.keys(meta.params).sort((a, b) => (meta.tunable.includes(b) - meta.tunable.includes(a)));
  for (const name of names) {
    const p = meta.params[name];
    if (!p.writable) continue;
    const step = p.integer ? 1 : Math.max((p.max - p.min) / 1000, 1e-5);
    const div = document.createElement("div"); div.className = "param";
    div.innerHTML = `<div><b>${name}</b> <span class="range">${fmt(p.min)} … ${fmt(p.max)}</span>
      now <span id="now-${name}">–</span></div>
      <input type="range" id="slider-${name}" min="${p.min}" max="${p.max}" step="${step}">
      <input type="number" id="param-${name}" min="${p.min}" max="${p.max}" step="${step}">
      <button id="set-${name}">set</button><div class="result" id="result-${name}"></div>`;
    box.appendChild(div);
    const slider = $(`slider-${name}`), input = $(`param-${name}`);
    slider.addEventListener("input", () => { input.value = slider.value; S.edited[name] = true; });
    input.addEventListener("input", () => { slider.value = input.value; S.edited[name] = true; });
    $(`set-${name}`).addEventListener("click", () => writeParams([name]));
  }
}

// one atomic `set` of these parameters (the firmware's constraints hold for the set as a whole)
function writeParams(names) {
  const params = Object.fromEntries(names.map((n) => [n, Number($(`param-${n}`).value)]));
  const text = names.map((n) => `${n}=${fmt(params[n])}`).join(" ");
  for (const n of names) setResult(n, "", "sending…");
  command({ cmd: "set", params }, (r) => {
    for (const n of names) {
      if (r.ok) { S.edited[n] = false; setResult(n, "ok", `${text} ${r.message}`); }
      else setResult(n, "bad", `refused: ${r.message}`);
    }
    if (names.length > 1) { const el = $("result-together"); el.className = "result " + (r.ok ? "ok" : "bad"); el.textContent = r.ok ? `${text} ${r.message}` : `refused: ${r.message}`; }
  });
}

function setResult(name, cls, text) {
  const el = $(`result-${name}`); if (!el) return;
  el.className = "result " + cls; el.textContent = text; S.lastParamResult[name] = { cls, text };
}

function setStatus(st) {
  S.status = st;
  $("st-t").textContent = st.t_s != null ? st.t_s.toFixed(3) : "–";
  $("st-state").textContent = st.state_name || (st.state ?? "–");
  $("st-state").className = st.state_name === "RUNNING" ? "ok" : st.state_name === "FAULT" || st.state_name === "STALLED" ? "bad" : "";
  $("st-fault").textContent = st.fault_name || (st.fault ?? "–");
  $("st-fault").className = st.fault ? "bad" : "";
  $("st-ref").textContent = st.ref_rpm != null ? fmt(st.ref_rpm) : "–";
  $("st-rate").textContent = st.periods_per_s ? Math.round(st.periods_per_s).toLocaleString("en") : "–";
  $("st-rtt").textContent = st.rtt_p50_us != null ? `${st.rtt_p50_us.toFixed(1)} / ${(st.rtt_p99_us ?? 0).toFixed(1)}` : "–";
  $("st-over").textContent = st.overruns ?? "–";
  const link = st.link || {};
  // frames received and every error counter that is not zero (a serial or socket link)
  const shown = Object.entries(link).filter(([k, v]) => k === "frames_rx" || (v && !k.startsWith("frames_") && !k.startsWith("bytes_")));
  $("st-link").textContent = Object.keys(link).length ? shown.map(([k, v]) => `${k} ${v}`).join(" · ") : "in process";
  if (!S.closed) { $("conn").textContent = st.ended ? "run ended" : "live"; $("conn").className = "fig ok"; }
  if (st.params) for (const [n, v] of Object.entries(st.params)) {
    const el = $(`now-${n}`); if (!el || v == null) continue;
    el.textContent = fmt(v);
    const box = $(`param-${n}`), slider = $(`slider-${n}`);
    if (!S.edited[n] && document.activeElement !== box && document.activeElement !== slider) {  // the value now, until edited
      box.value = Number(v.toPrecision(6)); slider.value = v;
    }
  }
  if (st.guard != null) $("guard").checked = st.guard;
}

function logLine(cls, text) {
  const div = document.createElement("div"); div.className = cls; div.textContent = text;
  const log = $("log"); log.appendChild(div);
  while (log.childNodes.length > 200) log.removeChild(log.firstChild);
  log.scrollTop = log.scrollHeight;
}

function logMarker(m) {
  const [t, kind, text] = m;
  logLine(kind === "guard" ? "guard" : kind === "fault" ? "bad" : "", `${t.toFixed(3)} s ${kind}: ${text}`);
  if (kind === "guard") {  // the guard put the previous values back: say so beside each parameter
    for (const name of Object.keys(S.meta ? S.meta.params : {})) if (text.includes(name + "=")) setResult(name, "guard", `reverted by the guard at t=${t.toFixed(3)} s: ${text}`);
  }
}

const callbacks = new Map();
function command(req, done) {
  const id = nextId++;
  if (done) callbacks.set(id, done);
  if (ws && ws.readyState === 1) ws.send(JSON.stringify({ type: "cmd", id, ...req }));
}
function onReply(r) {
  logLine(r.ok ? "ok" : "bad", `${r.cmd}: ${r.message}`);
  const cb = callbacks.get(r.id); callbacks.delete(r.id);
  if (cb) cb(r);
}
function subscribe() {
  const cols = ["t_s", ...S.selected];
  const trig = $("trig-col").value;
  if (trig && !cols.includes(trig)) cols.push(trig);  // a level trigger needs its trace, shown or not
  if (ws && ws.readyState === 1) ws.send(JSON.stringify({ type: "subscribe", columns: cols }));
  dirty = true;
}

// ------------------------------------------------------------------ trigger
function checkTrigger() {
  const tr = S.trigger;
  if (tr.state === "armed") {
    const t = findTrigger(tr.source, tr.armedAt);
    if (t !== null) { tr.tTrig = t; tr.state = "triggered"; }
    else if (tr.mode === "auto" && S.tLatest >= tr.armedAt + S.windowS) {  // no trigger for a window: capture anyway
      tr.tTrig = S.tLatest - (1 - preFraction()) * S.windowS; tr.state = "triggered"; tr.forced = true;
    }
  }
  if (tr.state === "triggered") {
    const W = S.windowS, pre = preFraction();
    if (S.tLatest >= tr.tTrig + (1 - pre) * W) {
      const cap = { tTrig: tr.tTrig, W, pre, data: new Map() };
      for (const n of S.selected) cap.data.set(n, clip(S.data.get(n) || [], tr.tTrig - pre * W, tr.tTrig + (1 - pre) * W));
      S.captures.unshift(cap); S.captures.length = Math.min(S.captures.length, 2);
      tr.state = "captured"; S.showCapture = true;
      if (tr.mode !== "single") S.trigger = { ...tr, state: "armed", armedAt: tr.tTrig + (1 - pre) * W, tTrig: null, forced: false };
      $("trig-state").textContent = (tr.forced ? `auto: no trigger within ${fmt(W)} s, free capture at t = ${tr.tTrig.toFixed(4)} s`
        : `captured: trigger at t = ${tr.tTrig.toFixed(4)} s`) + ` (${S.captures.length > 1 ? "previous capture dimmed" : "first capture"})`
        + (tr.mode !== "single" ? `; re-armed (${tr.mode})` : "");
      $("trig-state").className = "result ok";
      dirty = true;
    } else {
      $("trig-state").textContent = `triggered at t = ${tr.tTrig.toFixed(4)} s, filling…`;
    }
  }
}

// the first crossing of `level` after `after` in the direction asked: the trace must first be seen
// beyond the level by the hysteresis on the other side (a whole display bucket's envelope there)
function findLevel(name, after, level, hyst, edge) {
  let below = false, above = false;
  for (const s of S.data.get(name) || []) for (let i = 0; i < s.n; i++) {
    const t = s.t0 + i * s.dt;
    if (t <= after) continue;
    const lo = s.lo[i], hi = s.hi[i];
    if (edge !== "falling" && below && hi >= level) return t;
    if (edge !== "rising" && above && lo <= level) return t;
    if (hi < level - hyst) below = true;
    if (lo > level + hyst) above = true;
  }
  return null;
}

function preFraction() { return Math.min(0.9, Math.max(0, Number($("trig-pre").value) / 100)); }

function findTrigger(source, after) {
  const edge = S.trigger.edge || "either";
  if (source === "ref") {  // a jump of the reference by at least the threshold, in the chosen direction
    const segs = S.data.get("ref_speed_rpm") || [], thr = Number($("trig-thr").value) || 1;
    let prev = null;  // the reference at the end of the previous bucket
    for (const s of segs) for (let i = 0; i < s.n; i++) {
      const t = s.t0 + i * s.dt, lo = s.lo[i], hi = s.hi[i];
      const up = hi - (prev === null ? lo : prev), down = (prev === null ? hi : prev) - lo;
      if (t > after && up >= thr && edge !== "falling") return t;
      if (t > after && down >= thr && edge !== "rising") return t;
      prev = up > down ? hi : lo;  // a bucket holding a jump ends on the side away from where it began
    }
    return null;
  }
  if (source === "level") return findLevel(S.trigger.col, after, S.trigger.level, S.trigger.hyst, edge);
  for (const [t, kind] of S.markers) if (t > after && (source === "event" || kind === source)) return t;
  return null;
}

// ------------------------------------------------------------------ drawing
const canvas = $("plot"), ctx = canvas.getContext("2d");
const AXIS_W = 84, TIME_H = 22;

// lanes of the chosen columns: a column whose S.lane names another chosen analog column joins its
// lane (one axis for both); digital columns at the bottom, a thin lane each
function lanes(names) {
  const groups = [], byHost = new Map();
  for (const n of names) {
    const host = S.lane[n];
    if (host && host !== n && names.includes(host) && !S.lane[host] && S.units[n] !== "bit") continue;  // joins below
    const g = { names: [n], bit: S.units[n] === "bit" }; groups.push(g); byHost.set(n, g);
  }
  for (const n of names) {
    const host = S.lane[n];
    if (byHost.has(n) || !byHost.has(host)) continue;
    byHost.get(host).names.push(n);
  }
  const ordered = [...groups.filter((g) => !g.bit), ...groups.filter((g) => g.bit)];
  const H = canvas.clientHeight - TIME_H, digital = ordered.filter((g) => g.bit).length;
  const dh = Math.min(30, H / Math.max(1, ordered.length));
  const ah = (H - digital * dh) / Math.max(1, ordered.length - digital);
  let y = 0; const out = [];
  for (const g of ordered) { const h = g.bit ? dh : ah; out.push({ name: g.names[0], names: g.names, bit: g.bit, y, h }); y += h; }
  return out;
}

// per-pixel min/max of the buckets inside [ta, tb]
function pixels(segs, ta, tb, w, offset) {
  const lo = new Float64Array(w).fill(NaN), hi = new Float64Array(w).fill(NaN), span = tb - ta;
  for (const s of segs) {
    const t0 = s.t0 - offset;
    const i0 = Math.max(0, Math.floor((ta - t0) / s.dt)), i1 = Math.min(s.n, Math.ceil((tb - t0) / s.dt));
    for (let i = i0; i < i1; i++) {
      const px = Math.floor(((t0 + i * s.dt) - ta) / span * w);
      if (px < 0 || px >= w) continue;
      const a = s.lo[i], b = s.hi[i];
      if (!(a <= lo[px])) lo[px] = isNaN(lo[px]) ? a : Math.min(lo[px], a);
      if (!(b >= hi[px])) hi[px] = isNaN(hi[px]) ? b : Math.max(hi[px], b);
    }
  }
  return [lo, hi];
}

function drawBand(lo, hi, x0, lane, ymin, ymax, colour, alpha) {
  const y = (v) => lane.y + 3 + (1 - (v - ymin) / (ymax - ymin)) * (lane.h - 6);
  ctx.globalAlpha = alpha; ctx.strokeStyle = colour; ctx.fillStyle = colour; ctx.lineWidth = 1;
  let run = [];
  const flush = () => {
    if (!run.length) return;
    ctx.beginPath();
    run.forEach((px, k) => (k ? ctx.lineTo(x0 + px + 0.5, y(hi[px])) : ctx.moveTo(x0 + px + 0.5, y(hi[px]))));
    for (let k = run.length - 1; k >= 0; k--) ctx.lineTo(x0 + run[k] + 0.5, y(lo[run[k]]) + 0.5);
    ctx.closePath(); ctx.fill(); ctx.stroke(); run = [];
  };
  let last = -1;
  for (let px = 0; px < lo.length; px++) {
    if (isNaN(lo[px])) continue;
    if (last >= 0 && px - last > 40) flush();
    run.push(px); last = px;
  }
  flush(); ctx.globalAlpha = 1;
}

function niceTicks(a, b, n) {
  const span = b - a; if (!(span > 0)) return [a];
  const raw = span / n, mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw);
  const out = []; for (let t = Math.ceil(a / step) * step; t <= b + 1e-12; t += step) out.push(t);
  return out;
}

// a round tick's label: as many decimals as the tick spacing needs, no more
function tickText(v, span) {
  const decimals = Math.max(0, Math.min(6, -Math.floor(Math.log10(span / 4)) + 1));
  return Math.abs(v) >= 1e5 ? v.toExponential(1) : String(Number(v.toFixed(decimals)) || 0);
}

function fmt(v) {
  if (v == null || isNaN(v)) return "–";
  const a = Math.abs(v);
  return a !== 0 && (a < 1e-3 || a >= 1e5) ? v.toExponential(3) : Number(v.toPrecision(5)).toString();
}

function view() {
  if (S.showCapture && S.captures.length) {
    const c = S.captures[0];
    return { ta: -c.pre * c.W, tb: (1 - c.pre) * c.W, relative: true };
  }
  const end = S.paused && S.viewEnd !== null ? S.viewEnd : S.tLatest;
  return { ta: end - S.windowS, tb: end, relative: false };
}

function draw() {
  const dpr = window.devicePixelRatio || 1, W = canvas.clientWidth, H = canvas.clientHeight;
  if (canvas.width !== Math.round(W * dpr) || canvas.height !== Math.round(H * dpr)) {
    canvas.width = Math.round(W * dpr); canvas.height = Math.round(H * dpr);
  }
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = "#0b0f13"; ctx.fillRect(0, 0, W, H);
  const { ta, tb, relative } = view(), w = Math.max(10, Math.floor(W - AXIS_W - 8));
  const xOf = (t) => AXIS_W + (t - ta) / (tb - ta) * w;
  const ls = lanes(S.selected);
  ctx.font = "11px system-ui, sans-serif";
  // time grid
  ctx.strokeStyle = "#1d2630"; ctx.fillStyle = "#7d8a96"; ctx.textAlign = "center";
  for (const t of niceTicks(ta, tb, 8)) {
    const x = xOf(t); ctx.beginPath(); ctx.moveTo(x, 0); ctx.lineTo(x, H - TIME_H); ctx.stroke();
    ctx.fillText(`${Number(t.toPrecision(6))} s`, x, H - 6);
  }
  if (relative) { ctx.textAlign = "left"; ctx.fillStyle = "#e8b44c"; ctx.fillText("t − t(trigger)", 4, H - 6); }
  let colourIndex = 0;
  ls.forEach((lane) => {
    const traces = lane.names.map((name) => {
      const layers = [];
      if (relative) {
        const [cur, prev] = S.captures;
        layers.push({ segs: cur.data.get(name) || [], off: cur.tTrig, alpha: 1 });
        if (prev && $("trig-compare").checked) layers.push({ segs: prev.data.get(name) || [], off: prev.tTrig, alpha: 0.35 });
      } else layers.push({ segs: S.data.get(name) || [], off: 0, alpha: 1 });
      return { name, colour: COLOURS[colourIndex++ % COLOURS.length], layers, px: layers.map((l) => pixels(l.segs, ta, tb, w, l.off)) };
    });
    let ymin = Infinity, ymax = -Infinity;
    for (const tr of traces) for (const [lo, hi] of tr.px) for (let i = 0; i < w; i++) if (!isNaN(lo[i])) { ymin = Math.min(ymin, lo[i]); ymax = Math.max(ymax, hi[i]); }
    if (lane.bit) { ymin = 0; ymax = 1; }
    if (!isFinite(ymin)) { ymin = 0; ymax = 1; }
    if (ymax - ymin < 1e-9) { ymin -= 0.5; ymax += 0.5; }
    else if (!lane.bit) { const pad = (ymax - ymin) * 0.06; ymin -= pad; ymax += pad; }
    lane.ymin = ymin; lane.ymax = ymax;
    ctx.strokeStyle = "#2a3440"; ctx.beginPath(); ctx.moveTo(0, lane.y + lane.h); ctx.lineTo(W, lane.y + lane.h); ctx.stroke();
    ctx.textAlign = "left";
    traces.forEach((tr, k) => { ctx.fillStyle = tr.colour; ctx.fillText(tr.name, 4, lane.y + 12 + k * 12, AXIS_W - 8); });
    const yOf = (v) => lane.y + 3 + (1 - (v - ymin) / (ymax - ymin)) * (lane.h - 6);
    if (lane.h > 40 && !lane.bit) {  // round ticks with the unit, and the zero line
      const units = [...new Set(lane.names.map((n) => S.units[n] || "–"))].join(", ");
      const top = lane.y + 12 + traces.length * 12;
      ctx.fillStyle = "#7d8a96"; ctx.fillText(`[${units}]`, 4, top, AXIS_W - 8);
      ctx.textAlign = "right";
      for (const v of niceTicks(ymin, ymax, Math.max(3, Math.floor(lane.h / 30)))) {
        const yy = yOf(v);
        if (yy < top + 4 || yy > lane.y + lane.h - 2) continue;
        ctx.strokeStyle = v === 0 ? "#34404c" : "#182029"; ctx.beginPath(); ctx.moveTo(AXIS_W, yy); ctx.lineTo(AXIS_W + w, yy); ctx.stroke();
        ctx.fillStyle = "#7d8a96"; ctx.fillText(tickText(v, ymax - ymin), AXIS_W - 4, yy + 4);
      }
    }
    for (const tr of traces) for (let k = tr.layers.length - 1; k >= 0; k--) drawBand(tr.px[k][0], tr.px[k][1], AXIS_W, lane, ymin, ymax, tr.colour, tr.layers[k].alpha);
  });
  // markers
  const marks = relative ? S.markers.map(([t, k, x]) => [t - S.captures[0].tTrig, k, x]) : S.markers;
  ctx.setLineDash([3, 3]); ctx.textAlign = "left";
  const rowEnds = [];  // marker labels: each in the first row where it overlaps no other, else not written
  for (const [t, kind, text] of marks) {
    if (t < ta || t > tb) continue;
    const x = xOf(t); ctx.strokeStyle = MARK_COLOURS[kind] || "#8fa0b0";
    ctx.beginPath(); ctx.moveTo(x, 0); ctx.lineTo(x, H - TIME_H); ctx.stroke();
    const label = text.slice(0, 40), width = ctx.measureText(label).width + 6;
    let row = rowEnds.findIndex((end) => end <= x);
    if (row < 0 && rowEnds.length < 4) { row = rowEnds.length; rowEnds.push(0); }
    if (row < 0) continue;
    rowEnds[row] = x + width;
    ctx.fillStyle = ctx.strokeStyle; ctx.fillText(label, Math.min(x + 3, AXIS_W + w - width), 10 + row * 11);
  }
  ctx.setLineDash([]);
  if (relative) { const x = xOf(0); ctx.strokeStyle = "#e8b44c"; ctx.beginPath(); ctx.moveTo(x, 0); ctx.lineTo(x, H - TIME_H); ctx.stroke(); }
  // cursors
  const cursorColours = ["#60e0f0", "#f060e0"];
  S.cursors.forEach((t, i) => {
    if (t === null || t < ta || t > tb) return;
    const x = xOf(t); ctx.strokeStyle = cursorColours[i]; ctx.beginPath(); ctx.moveTo(x, 0); ctx.lineTo(x, H - TIME_H); ctx.stroke();
  });
  const why = !S.meta ? "waiting for the session…" : !S.selected.length ? "no trace chosen: tick one on the left"
    : !S.frames ? "no rows yet: the session sends them while this page watches (a run without --record too)"
    : S.closed ? `no more rows: ${S.closed}` : "";
  if (why) { ctx.textAlign = "center"; ctx.fillStyle = "#e8b44c"; ctx.font = "14px system-ui, sans-serif"; ctx.fillText(why, AXIS_W + w / 2, (H - TIME_H) / 2); }
  S.notice = why;
  S.view = { ta, tb, w, relative };
  S.lanes = ls.map((l) => ({ names: l.names, y: l.y, h: l.h, ymin: l.ymin, ymax: l.ymax }));  // for scripts and tests
  readout();
}

function readout() {
  const parts = [];
  const [a, b] = S.cursors;
  const src = (n) => (S.showCapture && S.captures.length ? S.captures[0].data.get(n) || [] : S.data.get(n) || []);
  const off = S.showCapture && S.captures.length ? S.captures[0].tTrig : 0;
  if (a !== null || b !== null) {
    for (const n of S.selected) {
      const vals = [a, b].map((t) => (t === null ? null : valueAt(src(n), t + off)));
      const f = (v) => (v === null ? "–" : Math.abs(v[1] - v[0]) < 1e-9 ? fmt(v[0]) : `${fmt(v[0])}…${fmt(v[1])}`);
      parts.push(`${n}: A ${f(vals[0])}${b !== null ? ` B ${f(vals[1])}` : ""} ${S.units[n] || ""}`);
    }
    const head = `A t=${a === null ? "–" : fmt(a)} s` + (b !== null ? `  B t=${fmt(b)} s  Δt=${a !== null ? fmt(b - a) : "–"} s` : "");
    $("readout").textContent = head + "   " + parts.join("   ");
  } else $("readout").textContent = "";
}

window.scopeRedraw = () => { dirty = true; };  // for scripts and tests that move the view

function frame() {
  if (dirty || !S.paused) { draw(); dirty = false; }
  requestAnimationFrame(frame);
}

// ------------------------------------------------------------------ interaction
function tAt(clientX) {
  const r = canvas.getBoundingClientRect(), v = S.view;
  return v.ta + (clientX - r.left - AXIS_W) / v.w * (v.tb - v.ta);
}

canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  const f = e.deltaY > 0 ? 1.25 : 0.8, v = S.view, t = tAt(e.clientX);
  if (S.showCapture) return;
  const newW = Math.min(3600, Math.max(1e-4, S.windowS * f));
  if (S.paused) { const end = t + (v.tb - t) * newW / S.windowS; S.viewEnd = end; }
  S.windowS = newW; dirty = true;
}, { passive: false });

let drag = null;
canvas.addEventListener("mousedown", (e) => { drag = { x: e.clientX, end: S.view.tb, moved: false }; });
window.addEventListener("mousemove", (e) => {
  if (!drag || S.showCapture) return;
  const dx = e.clientX - drag.x;
  if (Math.abs(dx) > 3) {
    drag.moved = true; setPaused(true);
    S.viewEnd = drag.end - dx / S.view.w * (S.view.tb - S.view.ta); dirty = true;
  }
});
window.addEventListener("mouseup", (e) => {
  if (drag && !drag.moved && e.target === canvas) {
    const t = tAt(e.clientX);
    S.cursors[e.shiftKey ? 1 : 0] = t; dirty = true;
  }
  drag = null;
});
window.addEventListener("keydown", (e) => { if (e.key === " " && e.target === document.body) { e.preventDefault(); setPaused(!S.paused); } });

function setPaused(p) {
  if (p && !S.paused) S.viewEnd = S.view ? S.view.tb : S.tLatest;
  S.paused = p; $("pause").textContent = p ? "run" : "pause"; $("pause").classList.toggle("on", p); dirty = true;
}
$("pause").addEventListener("click", () => setPaused(!S.paused));
$("window").addEventListener("change", () => { S.windowS = Number($("window").value); dirty = true; });
$("fit").addEventListener("click", () => {
  if (S.tFirst !== null) { S.windowS = Math.max(1e-3, S.tLatest - S.tFirst); S.viewEnd = S.tLatest; }
  S.showCapture = false; dirty = true;
});
$("trig-arm").addEventListener("click", () => {
  // live: the next trigger from now on; a recording: the first one after the view's start
  const from = S.meta && !S.meta.live && S.view ? S.view.ta : S.tLatest;
  S.trigger = { state: "armed", source: $("trig-source").value, armedAt: from, tTrig: null, edge: $("trig-edge").value,
    mode: $("trig-mode").value, col: $("trig-col").value, level: Number($("trig-level").value), hyst: Math.max(0, Number($("trig-hyst").value) || 0) };
  S.showCapture = false;
  const what = S.trigger.source === "level" ? `${S.trigger.col} ${S.trigger.edge} through ${fmt(S.trigger.level)} ${S.units[S.trigger.col] || ""}`
    : `${$("trig-source").selectedOptions[0].text} (${S.trigger.edge})`;
  $("trig-state").textContent = `armed at t = ${from.toFixed(3)} s on ${what}, ${S.trigger.mode}`;
  $("trig-state").className = "result"; dirty = true;
  checkTrigger();
});
$("trig-live").addEventListener("click", () => { S.showCapture = false; setPaused(false); });
$("trig-compare").addEventListener("change", () => { dirty = true; });
$("trig-col").addEventListener("change", () => subscribe());
$("set-together").addEventListener("click", () => {
  const names = Object.keys(S.edited).filter((n) => S.edited[n]);
  if (!names.length) { $("result-together").className = "result bad"; $("result-together").textContent = "nothing edited: change two or more values first"; return; }
  writeParams(names);
});
$("ref-set").addEventListener("click", () => command({ cmd: "ref", rpm: Number($("ref-input").value) }));
$("load-set").addEventListener("click", () => command({ cmd: "load", nm: Number($("load-input").value) }));
$("step-go").addEventListener("click", () => {
  const el = $("result-step");
  el.className = "result"; el.textContent = "stepping: 1 s hold, the step, 1 s after it…";
  command({ cmd: "step", from_rpm: Number($("step-from").value), to_rpm: Number($("step-to").value) }, (r) => {
    el.className = "result " + (r.ok ? "ok" : "bad"); el.textContent = r.ok ? r.message : `refused: ${r.message}`;
  });
});
$("press-s2").addEventListener("click", () => command({ cmd: "press", button: "s2" }));
$("end-run").addEventListener("click", () => { if (confirm("End the run?")) command({ cmd: "stop" }); });
$("guard").addEventListener("change", () => command({ cmd: "guard", on: $("guard").checked }));

// ------------------------------------------------------------------ connection
function connect() {
  const url = new URL("ws", window.location.href); url.protocol = url.protocol.replace("http", "ws");
  ws = new WebSocket(url);
  ws.onopen = () => { $("conn").textContent = "connected"; $("conn").className = "fig ok"; if (S.meta) subscribe(); };
  ws.onmessage = (e) => onMessage(JSON.parse(e.data));
  ws.onclose = () => { if (!S.closed) { $("conn").textContent = "disconnected"; $("conn").className = "fig bad"; } };
}
connect();
requestAnimationFrame(frame);
