/* friction-daq live page.
 *
 * Frames arrive over a WebSocket (daq/web/feed.py builds them): per stream, min/max envelope
 * columns on a fixed time grid, the page drops its columns from the first new one on and
 * appends. Plots (uPlot, shipped in /static) are redrawn once per animation frame; once that
 * frame is painted, the page acknowledges the newest frame it holds, which is both the server's
 * flow control (it sends the next frame only then: frames come as fast as this page can show
 * them, never queued behind its painting) and its display-latency measurement. Commands go to POST /api/command; the server and then the
 * daemon decide what this page may do (the buttons only mirror that).
 */
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const COLORS = ["#1f5fbf", "#c4161c", "#1f8a4c", "#b86e00", "#7b3fbf", "#00838f", "#5d4037"];
  const WARN = /lost|drop|gap|disconnect|reconnect|checksum|error|malformed|rejected|truncated|waiting|refused|stale|fail/;
  const BAD = /estop|died|unclean|watchdog|latched/;
  const ROUTINE = new Set(["friction_fit", "estimator_started"]);  // hidden unless asked for: they bury the drops
  const SPECIAL = { "motor": "belt", "estimator/F_est": "F", "estimator/mu_est": "mu", "cycles": "cycles" };

  // ---------------------------------------------------------------- who am I
  let token = sessionStorage.getItem("daq-token") || "";
  const m = location.hash.match(/token=([^&]+)/);
  if (m) {  // keep the token out of the address bar (screenshots, shoulders)
    token = decodeURIComponent(m[1]);
    sessionStorage.setItem("daq-token", token);
    history.replaceState(null, "", location.pathname + location.search);
  }
  const auth = () => (token ? { Authorization: "Bearer " + token } : {});
  let role = "observer";
  const commandButtons = [...document.querySelectorAll(".cmd"), $("estop")];
  function setRole(r) {
    role = r;
    const readOnly = r !== "operator";
    commandButtons.forEach((b) => { b.disabled = readOnly; });
    $("role").textContent = readOnly ? "observer: read only" : "operator";
    $("role").className = "badge" + (readOnly ? " off" : "");
  }
  setRole("observer");  // nothing commands until the server says this page may
  fetch("/api/whoami", { headers: auth() }).then((r) => r.json()).then((w) => {
    setRole(w.role);
    if (w.rig) { $("rig").textContent = w.rig + " live"; document.title = w.rig + " live"; }
  }).catch(() => {});

  // ---------------------------------------------------------------- commands
  function say(text, bad) { const el = $("cmd-msg"); el.textContent = text; el.className = "msg" + (bad ? " bad" : ""); }
  async function command(op, args) {
    if (role !== "operator") return null;
    say(op + " ...");
    try {
      const r = await fetch("/api/command", {
        method: "POST", body: JSON.stringify({ op: op, args: args || {} }),
        headers: Object.assign({ "Content-Type": "application/json", "X-Daq-Page": "1" }, auth()) });
      const rep = await r.json();
      if (rep.ok) say(op + ": " + JSON.stringify(rep.result).slice(0, 200));
      else say(op + " refused: " + rep.error, true);
      return rep;
    } catch (e) { say(op + " failed: " + e, true); return null; }
  }
  $("estop").addEventListener("click", () => command("estop"));
  $("stop").addEventListener("click", () => command("stop"));
  $("rec-start").addEventListener("click", () => command("record_start"));
  $("rec-stop").addEventListener("click", () => command("record_stop"));
  async function addNote() {
    const text = $("note-text").value;
    if (!text.trim()) return;
    const rep = await command("note", { text: text });
    if (rep && rep.ok) $("note-text").value = "";
  }
  $("note-add").addEventListener("click", addNote);
  $("note-text").addEventListener("keydown", (e) => { if (e.key === "Enter") addNote(); });

  // ---------------------------------------------------------------- plots
  const store = {};  // stream -> {dt, channels, units, k: [], lo: [[]], hi: [[]]}
  const plots = [];  // {stream, channels, el, u}
  let origin = 0, now = 0, windowS = 10, lastSeq = 0, ackedSeq = 0, scheduled = false, ws = null;
  let scatter = null, cycles = [];

  function plotWidth(el) { return Math.max(200, Math.floor(el.clientWidth || 400)); }
  const pad2 = (n) => String(n).padStart(2, "0");
  function clock(v, frac) {
    const d = new Date(v * 1000);
    const s = `${pad2(d.getHours())}:${pad2(d.getMinutes())}:${pad2(d.getSeconds())}`;
    return frac ? s + "." + String(Math.round(d.getMilliseconds() / 100) % 10) : s;
  }
  const timeAxis = { space: 90, values: (u, splits, ax, space, incr) => splits.map((v) => clock(v, incr < 1)) };
  function yRange(u, min, max) {  // uPlot's default for a constant 0 is [0, 100]: pad around the value instead
    if (min === null || max === null) return [0, 1];
    if (min === max) { const d = Math.abs(min) * 0.1 || 1; return [min - d, max + d]; }
    const pad = (max - min) * 0.05;
    return [min - pad, max + pad];
  }
  const visible = new Map();  // plot element -> on screen (off-screen plots are not redrawn: CPU)
  const watcher = new IntersectionObserver((entries) => {
    for (const e of entries) visible.set(e.target, e.isIntersecting);
  });

  function envelopePlot(el, stream, channels, units, height) {
    const series = [{}];
    const bands = [];
    channels.forEach((c, i) => {
      const color = COLORS[i % COLORS.length];
      series.push({ label: c + " max", stroke: color, width: 1 });  // uPlot shows points only where sparse
      series.push({ label: c + " min", stroke: color, width: 1 });
      bands.push({ series: [series.length - 2, series.length - 1], fill: color + "40" });
    });
    const u = new uPlot({
      width: plotWidth(el), height: height, series: series, bands: bands, legend: { show: false },
      cursor: { drag: { x: false, y: false } }, scales: { x: { time: true }, y: { range: yRange } },
      axes: [timeAxis, { size: 60, label: units.filter((v, i, a) => a.indexOf(v) === i).join(", ") }],
    }, [[], ...channels.flatMap(() => [[], []])], el);
    plots.push({ stream: stream, channels: channels, el: el, u: u });
    visible.set(el, true);
    watcher.observe(el);
  }

  function legendHtml(channels) {
    return channels.map((c, i) => `<span style="color:${COLORS[i % COLORS.length]}">&#9632; ${c}</span>`).join(" ");
  }

  function ensurePlots(name, sf) {
    if (plots.some((p) => p.stream === name) || name === "cycles") return;
    if (name === "motor") {
      $("plot-belt").insertAdjacentHTML("beforebegin", `<div class="hint">${legendHtml(
        ["vb measured", "vb_set regulator set point"])}</div>`);
      envelopePlot($("plot-belt"), name, sf.channels, sf.units, 190);
      return;
    }
    sf.channels.forEach((c, i) => {
      const special = SPECIAL[name + "/" + c];
      let el = special ? $("plot-" + special) : null;
      if (!el) {
        const box = document.createElement("div");
        box.className = "chan";
        box.innerHTML = `<h3>${name} / ${c} [${sf.units[i]}]</h3>`;
        el = document.createElement("div");
        box.appendChild(el);
        $("stream-plots").appendChild(box);
      }
      envelopePlot(el, name, [c], [sf.units[i]], special ? 150 : 120);
    });
  }

  function apply(name, sf) {
    let s = store[name];
    if (!s || sf.reset || s.dt !== sf.dt || s.channels.join() !== sf.channels.join()) {
      s = store[name] = { dt: sf.dt, channels: sf.channels, units: sf.units, k: [],
                          lo: sf.channels.map(() => []), hi: sf.channels.map(() => []) };
    }
    if (sf.k.length) {
      let i = s.k.length;
      while (i > 0 && s.k[i - 1] >= sf.k[0]) i--;  // the last column sent may have been still filling
      s.k.length = i;
      s.lo.forEach((a) => { a.length = i; });
      s.hi.forEach((a) => { a.length = i; });
      for (let j = 0; j < sf.k.length; j++) s.k.push(sf.k[j]);
      sf.lo.forEach((col, c) => { for (const v of col) s.lo[c].push(v); });
      sf.hi.forEach((col, c) => { for (const v of col) s.hi[c].push(v); });
    }
    const kMin = Math.floor((now - windowS) / s.dt) - 1;  // keep the window only
    let cut = 0;
    while (cut < s.k.length && s.k[cut] < kMin) cut++;
    if (cut) { s.k.splice(0, cut); s.lo.forEach((a) => a.splice(0, cut)); s.hi.forEach((a) => a.splice(0, cut)); }
    ensurePlots(name, sf);
  }

  const perf = { draws: 0, drawMs: 0, maxDrawMs: 0, waitMs: 0, frames: 0, parseMs: 0 };  // read by `daq bench web`
  window.daqPage = perf;
  function draw() {
    scheduled = false;
    const t0 = performance.now();
    if (perf.tRecv) { perf.waitMs += t0 - perf.tRecv; perf.tRecv = 0; }
    const xMin = origin + now - windowS, xMax = origin + now;
    for (const p of plots) {
      const s = store[p.stream];
      if (!s || !visible.get(p.el)) continue;
      const xs = s.k.map((k) => origin + k * s.dt);
      const data = [xs];
      p.channels.forEach((c) => { const i = s.channels.indexOf(c); data.push(s.hi[i], s.lo[i]); });
      p.u.batch(() => { p.u.setData(data, true); p.u.setScale("x", { min: xMin, max: xMax }); });
    }
    drawScatter();
    drawCycles();
    const ms = performance.now() - t0;
    perf.draws++; perf.drawMs += ms; perf.maxDrawMs = Math.max(perf.maxDrawMs, ms);
    if (ws && ws.readyState === 1 && lastSeq > ackedSeq) {  // acknowledged once painted: the task after the frame
      const seq = lastSeq, sock = ws;
      ackedSeq = seq;
      setTimeout(() => { if (sock.readyState === 1) sock.send(JSON.stringify({ type: "ack", seq: seq })); }, 0);
    }
  }

  let scatterPlot = null;
  function drawScatter() {
    if (!scatter) return;
    const pairs = scatter.v_rel.map((v, i) => [v, scatter.mu[i]]).filter((p) => p[0] !== null && p[1] !== null);
    pairs.sort((a, b) => a[0] - b[0]);
    const data = [pairs.map((p) => p[0]), pairs.map((p) => p[1])];
    if (!scatterPlot) {
      const el = $("plot-scatter");
      scatterPlot = new uPlot({
        width: plotWidth(el), height: 300, legend: { show: false }, cursor: { drag: { x: false, y: false } },
        scales: { x: { time: false } },
        series: [{ label: "v_rel" }, { label: "mu", stroke: COLORS[0], paths: () => null,
                                      points: { show: true, size: 3, fill: COLORS[0] } }],
        axes: [{ label: "v_rel [m/s]" }, { label: "mu", size: 60 }],
      }, data, el);
    } else scatterPlot.setData(data, true);
    $("scatter-s").textContent = scatter.seconds;
    scatter = null;
  }

  // ---------------------------------------------------------------- cycles (stick-slip, from the estimator)
  const CYCLE_PLOTS = [["breakaway_N", "break-away force [N]", 1], ["stick_s", "stick time [s]", 1],
                       ["slip_m", "slip distance [mm]", 1000], ["peak_slip_m_per_s", "peak slip velocity [m/s]", 1]];
  let cyclePlots = null, cyclesDirty = false, cyclesDrawn = 0;
  function drawCycles() {  // a few cycles a second: redrawn when one arrives, else twice a second (paint is costly)
    if (!cyclesDirty && (!cyclePlots || performance.now() - cyclesDrawn < 500)) return;
    cyclesDrawn = performance.now();
    const grid = $("plot-cycles");
    if (!cyclePlots) {
      if (!cycles.length) return;
      grid.className = "grid4";
      cyclePlots = CYCLE_PLOTS.map(([key, title], i) => {
        const box = document.createElement("div");
        box.className = "chan";
        box.innerHTML = `<h3>${title}</h3>`;
        const el = document.createElement("div");
        box.appendChild(el);
        grid.appendChild(box);
        const u = new uPlot({
          width: plotWidth(el), height: 140, legend: { show: false }, cursor: { drag: { x: false, y: false } },
          scales: { x: { time: true }, y: { range: yRange } }, axes: [timeAxis, { size: 60 }],
          series: [{}, { stroke: COLORS[i], paths: () => null, points: { show: true, size: 5, fill: COLORS[i] } }],
        }, [[], []], el);
        return { key: key, u: u, el: el };
      });
    }
    const xMin = origin + now - windowS, xMax = origin + now;
    const shown = cycles.filter((c) => c.t >= now - windowS);
    const xs = shown.map((c) => origin + c.t);
    CYCLE_PLOTS.forEach(([key, , scale], i) => {
      const p = cyclePlots[i];
      p.u.batch(() => { p.u.setData([xs, shown.map((c) => c[key] * scale)], true); p.u.setScale("x", { min: xMin, max: xMax }); });
    });
    cyclesDirty = false;
    $("cycle-count").textContent = cycles.length + " cycles";
    $("cycle-count").className = "badge" + (cycles.length ? "" : " off");
  }

  // ---------------------------------------------------------------- events and status
  function fmtTime(t) {
    const d = new Date((origin + t) * 1000);
    return d.toLocaleTimeString([], { hour12: false }) + "." + String(d.getMilliseconds()).padStart(3, "0");
  }
  function addEvents(events, dropped) {
    const body = $("events").tBodies[0];
    if (dropped) events = [{ t: now, kind: "page_missed_events", source: "web", detail: dropped + " events" }].concat(events);
    for (const e of events) {
      const tr = document.createElement("tr");
      tr.className = ROUTINE.has(e.kind) ? "routine" : BAD.test(e.kind) ? "bad" : WARN.test(e.kind) ? "warn"
        : e.kind === "note" ? "note" : "";
      for (const [cls, text] of [["t", fmtTime(e.t)], ["k", e.kind], ["s", e.source], ["d", e.detail]]) {
        const td = document.createElement("td");
        td.className = cls;
        td.textContent = text.length > 240 ? text.slice(0, 240) + " ..." : text;
        if (text.length > 240) td.title = text;
        tr.appendChild(td);
      }
      body.insertBefore(tr, body.firstChild);
    }
    while (body.rows.length > 500) body.deleteRow(-1);
  }
  const num = (x, d) => (x === null || x === undefined ? "-" : Number(x).toFixed(d));
  function kv(el, pairs) {
    el.innerHTML = "";
    for (const [k, v, bad] of pairs) {
      const a = document.createElement("span"); a.textContent = k;
      const b = document.createElement("span"); b.textContent = v; if (bad) b.className = "bad";
      el.append(a, b);
    }
  }
  function showStatus(st) {
    const belt = st.belt || {};
    $("belt-measured").textContent = num(belt.measured, 4);
    $("belt-commanded").textContent = num(belt.commanded, 4);
    $("belt-setpoint").textContent = num(belt.setpoint, 4);
    const reg = st.regulator || {};
    $("belt-regulator").textContent = reg.state ? `${reg.state}${reg.latched ? " LATCHED" : ""} (read ${
      reg.read_at ? new Date(reg.read_at).toLocaleTimeString([], { hour12: false }) : "?"}), link ${belt.regulator || "-"}`
      : (belt.regulator || "-");
    const ramp = st.ramp;
    $("ramp-state").textContent = ramp ? ramp.state : "none";
    $("ramp-progress").value = ramp ? ramp.fraction : 0;
    $("ramp-detail").textContent = ramp ? `segment ${ramp.segment ?? "-"}  t ${num(ramp.t, 1)} / ${num(ramp.duration, 1)} s  ${ramp.reason || ""}` : "";
    const rec = st.recording;
    const recEl = $("rec-state");
    if (rec) {
      recEl.textContent = "REC " + rec.path.split("/").pop() + (rec.size_bytes !== undefined ? `  ${(rec.size_bytes / 1e6).toFixed(1)} MB` : "");
      recEl.className = "badge rec";
    } else { recEl.textContent = st.recording_failure ? "recording ENDED UNEXPECTEDLY" : "recording off"; recEl.className = "badge " + (st.recording_failure ? "bad" : "off"); }
    const recRows = rec ? [["file", rec.path], ["size", rec.size_bytes !== undefined ? (rec.size_bytes / 1e6).toFixed(2) + " MB" : "-"],
                           ["recorder", rec.progress || ""]] : [["recording", "off"]];
    if (st.recording_failure) recRows.push(["last recording", st.recording_failure.exit + "; " + st.recording_failure.recovery, true]);
    if (st.motion && !st.motion.allowed) recRows.push(["motion", "REFUSED: " + st.motion.refused_because, true]);
    kv($("recording"), recRows);
    kv($("rates"), Object.entries(st.streams || {}).map(([k, s]) => [k, `${num(s.rate_hz, 1)} samples/s, ${s.samples} samples`]));
    kv($("drops"), Object.entries(st.drops || {}).map(([k, v]) => [k, String(v), v > 0]));
    const est = (st.estimator || {}).last || {};
    $("est-F").textContent = num(est.F_est, 3);
    $("est-mu").textContent = num(est.mu_est, 3);
    $("est-v").textContent = num(est.v_rel, 4);
    const fit = (st.estimator || {}).fit || {};
    $("est-fit").textContent = Object.keys(fit).length ? "fit " + Object.entries(fit).filter(([k]) => k !== "t")
      .slice(0, 4).map(([k, v]) => `${k} ${Number(v).toPrecision(3)}`).join("  ") : "";
  }
  function showRegime() {
    const s = store["estimator"];
    if (!s) return;
    const i = s.channels.indexOf("slip");
    if (i < 0 || !s.hi[i].length) return;
    const slip = s.hi[i][s.hi[i].length - 1];
    $("regime").textContent = slip === null ? "-" : slip > 0.5 ? "SLIP" : "STICK";
    $("regime").className = "badge" + (slip > 0.5 ? " warn" : "");
  }

  // ---------------------------------------------------------------- the WebSocket
  function sendView() {
    if (!ws || ws.readyState !== 1) return;
    const width = Math.max(...[...document.querySelectorAll(".plot")].map((e) => e.clientWidth), 200);
    ws.send(JSON.stringify({ type: "view", window_s: Number($("window").value), width: Math.round(width) }));
  }
  function onFrame(f) {
    origin = f.origin_wall; now = f.now; windowS = f.window_s; lastSeq = f.seq;
    for (const [name, sf] of Object.entries(f.streams)) apply(name, sf);
    if (f.events.length || f.events_dropped) addEvents(f.events, f.events_dropped);
    if (f.status) showStatus(f.status);
    if (f.scatter) scatter = f.scatter;
    if (f.cycles) { cycles = cycles.concat(f.cycles).slice(-20000); cyclesDirty = true; }
    showRegime();
    if (!scheduled) { scheduled = true; requestAnimationFrame(draw); }
  }
  function connect() {
    const proto = location.protocol === "https:" ? "wss://" : "ws://";
    // the operator's token rides as a subprotocol (a browser cannot set Authorization on a WebSocket), so
    // token-less viewers can never take the operator's place (daq/web/server.py)
    ws = new WebSocket(proto + location.host + "/ws", token ? ["daq.v1", "daq.token." + token] : ["daq.v1"]);
    ws.onopen = () => {
      $("conn").textContent = "live"; $("conn").className = "badge";
      cycles = [];  // a new connection sends every cycle the server keeps
      lastSeq = ackedSeq = 0;
      sendView();
    };
    ws.onmessage = (ev) => { const t = performance.now(); onFrame(JSON.parse(ev.data)); perf.parseMs += performance.now() - t; perf.frames++; if (!perf.tRecv) perf.tRecv = t; };
    ws.onclose = () => {
      $("conn").textContent = "disconnected"; $("conn").className = "badge bad";
      setTimeout(connect, 1000);
    };
  }
  $("show-routine").addEventListener("change", (e) => { $("events").classList.toggle("all", e.target.checked); });
  $("window").addEventListener("change", () => { for (const k in store) delete store[k]; sendView(); });
  let resizeTimer = null;
  window.addEventListener("resize", () => {
    clearTimeout(resizeTimer);
    resizeTimer = setTimeout(() => {
      for (const p of plots) p.u.setSize({ width: plotWidth(p.el), height: p.u.height });
      if (scatterPlot) scatterPlot.setSize({ width: plotWidth($("plot-scatter")), height: scatterPlot.height });
      if (cyclePlots) for (const p of cyclePlots) p.u.setSize({ width: plotWidth(p.el), height: p.u.height });
      sendView();
    }, 200);
  });
  connect();
})();
