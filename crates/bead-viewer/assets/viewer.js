// bead viewer: draws what the server streams over /ws (protocol: crates/bead-viewer/src/protocol.rs).
// Plain modern JavaScript, no build step, no dependencies.
"use strict";

(function () {
  const $ = (id) => document.getElementById(id);
  const TRAIL = 120;        // trail points per particle
  const HISTORY = 900;      // chart points per panel
  // Trails are on by default up to this many particles; above, the checkbox turns them on,
  // with at most TRAIL_BUDGET trail points in all (e.g. 20 per particle for 1000).
  const TRAIL_MAX_PARTICLES = 20;
  const TRAIL_BUDGET = 20000;
  const DRAW_SAMPLES = 240; // draw times kept per panel (window.__viewer, for the tests)
  const FRAME_MAGIC = [0x62, 0x65, 0x61, 0x64]; // "bead": a binary frame (protocol.rs)
  const LITTLE_ENDIAN = new Uint8Array(new Uint16Array([1]).buffer)[0] === 1;
  const textDecoder = new TextDecoder();

  const state = {
    ws: null,
    welcome: null,
    scene: null,
    // id -> { info, frame, dom, trail, history }. `info.epoch` and `frame.epoch` change
    // whenever the panel restarts; a frame of an older epoch than `info` is stale.
    panels: new Map(),
    drags: new Map(),       // panel id -> particle being dragged
    pendingMoves: new Map(),// panel id -> latest drag_move, sent once per animation frame
    // Binary frames received, their bytes and the time spent decoding them (ms).
    stats: { frames: 0, bytes: 0, decodeMs: 0, maxDecodeMs: 0 },
  };
  window.__viewer = state;  // for the end-to-end tests

  function send(message) {
    if (state.ws && state.ws.readyState === WebSocket.OPEN) {
      state.ws.send(JSON.stringify(message));
    }
  }

  function showMessage(text) {
    const box = $("messages");
    const line = document.createElement("div");
    line.textContent = text;
    box.prepend(line);
    while (box.childElementCount > 4) box.lastElementChild.remove();
    setTimeout(() => line.remove(), 8000);
  }

  // ---------- number formatting ----------
  function fmt(v, digits = 4) {
    if (!Number.isFinite(v)) return String(v);
    const a = Math.abs(v);
    if (a !== 0 && (a < 1e-3 || a >= 1e6)) return v.toExponential(digits - 1);
    let text = v.toPrecision(digits + 2);
    if (text.includes(".") && !text.includes("e")) text = text.replace(/0+$/, "").replace(/\.$/, "");
    return text;
  }

  function niceStep(range, count) {
    const raw = range / Math.max(count, 1);
    const p = Math.pow(10, Math.floor(Math.log10(raw)));
    const m = raw / p;
    return (m < 1.5 ? 1 : m < 3.5 ? 2 : m < 7.5 ? 5 : 10) * p;
  }

  // ---------- connection ----------
  function connect() {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const ws = new WebSocket(`${proto}//${location.host}/ws`);
    state.ws = ws;
    ws.onopen = () => { $("connection").textContent = "connected"; };
    ws.onclose = () => {
      $("connection").textContent = "disconnected — reload to reconnect";
    };
    ws.binaryType = "arraybuffer";
    ws.onmessage = (event) => receive(event.data);
  }

  // One message from the server: JSON text, or an ArrayBuffer holding a binary frame.
  function receive(data) {
    let msg = null;
    if (data instanceof ArrayBuffer) {
      const start = performance.now();
      try { msg = decodeFrame(data); } catch (e) { msg = null; }
      const ms = performance.now() - start;
      const stats = state.stats;
      stats.frames += 1;
      stats.bytes += data.byteLength;
      stats.decodeMs += ms;
      stats.maxDecodeMs = Math.max(stats.maxDecodeMs, ms);
    } else {
      try { msg = JSON.parse(data); } catch (e) { msg = null; }
    }
    if (msg) handle(msg);
  }
  // For the tests: feed the page messages as the server would send them (after detaching
  // the socket), e.g. a scene the server of a test could not simulate in time.
  state.receive = receive;

  // A binary frame (protocol.rs, "Frames"): "bead", u32 header length, JSON header, zero
  // padding to a multiple of 8, then every panel's positions as little-endian f64. Each
  // panel's `x` becomes a Float64Array view of its part (no copy on little-endian machines).
  function decodeFrame(buffer) {
    const bytes = new Uint8Array(buffer);
    if (bytes.length < 8 || FRAME_MAGIC.some((b, i) => bytes[i] !== b)) return null;
    const view = new DataView(buffer);
    const headerLength = view.getUint32(4, true);
    if (8 + headerLength > bytes.length) return null;
    const msg = JSON.parse(textDecoder.decode(bytes.subarray(8, 8 + headerLength)));
    const start = Math.min(Math.ceil((8 + headerLength) / 8) * 8, bytes.length);
    const count = Math.floor((bytes.length - start) / 8);
    let numbers;
    if (LITTLE_ENDIAN) {
      numbers = new Float64Array(buffer, start, count);
    } else {
      numbers = new Float64Array(count);
      for (let i = 0; i < count; i++) numbers[i] = view.getFloat64(start + 8 * i, true);
    }
    for (const f of msg.panels) {
      if (!(f.x_offset + f.x_count <= count)) return null;
      f.x = numbers.subarray(f.x_offset, f.x_offset + f.x_count);
    }
    return msg;
  }

  function handle(msg) {
    switch (msg.type) {
      case "welcome": onWelcome(msg); break;
      case "scene": onScene(msg); break;
      case "panels": onPanels(msg.panels); break;
      case "frame": onFrame(msg); break;
      case "error":
        // msg.code is the machine-readable reason (protocol.rs, ErrorCode).
        if (msg.panel != null && state.panels.has(msg.panel)) {
          const p = state.panels.get(msg.panel);
          p.dom.configError.textContent = msg.message;
          p.dom.configError.dataset.code = msg.code;
        } else {
          showMessage(`${msg.request ? msg.request + ": " : ""}${msg.message}`);
        }
        break;
      case "scene_error":
        $("scene-error").hidden = false;
        $("scene-error").textContent = msg.message;
        break;
      case "curve_error": onCurveError(msg); break;
      default: break;
    }
  }

  function option(select, value, label, title) {
    const o = document.createElement("option");
    o.value = value;
    o.textContent = label;
    if (title) o.title = title;
    select.appendChild(o);
    return o;
  }

  function onWelcome(msg) {
    state.welcome = msg;
    const picker = $("scene-select");
    picker.innerHTML = "";
    for (const name of msg.scenes) option(picker, name, name);
    for (const sel of [$("new-integrator")]) {
      sel.innerHTML = "";
      for (const k of msg.integrators) option(sel, k.name, k.name, k.description);
      sel.value = "rk4";
    }
    $("new-method").innerHTML = "";
    for (const m of msg.methods) option($("new-method"), m, m);
    // `?scene=NAME` opens another shipped scene first.
    const wanted = new URLSearchParams(location.search).get("scene");
    if (wanted && msg.scenes.includes(wanted) && wanted !== msg.scenes[0]) {
      send({ type: "load_scene", name: wanted });
    }
  }

  function onScene(scene) {
    state.scene = scene;
    $("scene-error").hidden = true;
    $("scene-title").textContent = `${scene.title} (${scene.name})` +
      (scene.dim === 3 ? " — 3D, drawn projected onto x-y" : "");
    $("scene-warnings").textContent = scene.warnings.map((w) => "warning: " + w).join("\n");
    const picker = $("scene-select");
    if ([...picker.options].some((o) => o.value === scene.name)) picker.value = scene.name;
    buildCurveEditors(scene);
    prepareScene(scene);
    for (const p of state.panels.values()) p.dom.root.remove();
    state.panels.clear();
    state.drags.clear();
    state.pendingMoves.clear();
  }

  // What the drawing needs of a scene, once: rods between particles as pairs of indices,
  // rods to anchors, pins; trails on by default for few particles only.
  function prepareScene(scene) {
    const pairs = [], anchored = [];
    for (const rod of scene.rods) {
      if (rod.b != null) pairs.push(rod.a, rod.b);
      else if (rod.anchor) anchored.push(rod);
    }
    scene.draw = { pairs: Int32Array.from(pairs), anchored, pins: scene.pins || [] };
    $("trails").checked = scene.particles.length <= TRAIL_MAX_PARTICLES;
  }

  function trailsOn() {
    return $("trails").checked;
  }

  // Trail points kept per particle.
  function trailLength() {
    const n = state.scene ? state.scene.particles.length : 1;
    return Math.max(2, Math.min(TRAIL, Math.floor(TRAIL_BUDGET / Math.max(n, 1))));
  }

  // ---------- curve editor ----------
  function buildCurveEditors(scene) {
    const box = $("curves");
    box.innerHTML = "";
    scene.constraints.forEach((c, index) => {
      if (c.expr == null) return;
      const row = document.createElement("div");
      row.className = "curve-edit";
      row.dataset.constraint = String(index);
      const label = document.createElement("label");
      label.textContent = `${c.name}: `;
      const input = document.createElement("input");
      input.type = "text";
      input.className = "curve-expr";
      input.value = c.expr;
      input.spellcheck = false;
      const suffix = document.createElement("span");
      suffix.textContent = " = 0 ";
      const apply = document.createElement("button");
      apply.className = "curve-apply";
      apply.textContent = "Apply to implicit panels";
      const error = document.createElement("pre");
      error.className = "curve-error error";
      error.hidden = true;
      const submit = () => {
        error.hidden = true;
        send({ type: "set_curve", constraint: index, expr: input.value });
      };
      apply.onclick = submit;
      input.addEventListener("keydown", (e) => { if (e.key === "Enter") submit(); });
      label.append(input, suffix, apply);
      row.append(label, error);
      box.appendChild(row);
    });
  }

  function onCurveError(msg) {
    const row = document.querySelector(`#curves .curve-edit[data-constraint="${msg.constraint}"]`);
    if (!row) { showMessage("set_curve: " + msg.message); return; }
    const error = row.querySelector(".curve-error");
    const expr = row.querySelector(".curve-expr").value;
    let text = msg.message;
    if (msg.columns) {
      const [a, b] = msg.columns;
      text += "\n  " + expr + "\n  " + " ".repeat(a) + "^".repeat(Math.max(1, b - a));
    }
    error.textContent = text;
    error.dataset.code = msg.code;
    error.hidden = false;
  }

  // ---------- panels ----------
  function onPanels(list) {
    const seen = new Set();
    for (const info of list) {
      seen.add(info.id);
      let p = state.panels.get(info.id);
      if (!p) {
        p = {
          info, frame: null, dom: buildPanel(info), trail: [], history: [], dirty: true,
          // What the last draw drew (counts, the frame and its time in ms) and the recent
          // draw times: for the tests.
          lastDraw: null, drawTimes: [],
        };
        state.panels.set(info.id, p);
        $("panels").appendChild(p.dom.root);
      } else {
        // A new epoch: the panel restarted (configured, reset, new curve).
        if (p.info.epoch !== info.epoch) { p.trail = []; p.history = []; }
        p.info = info;
        p.dirty = true;
      }
      p.dom.root.dataset.epoch = String(info.epoch);
      fillConfig(p);
      p.dom.configError.textContent = "";
    }
    for (const [id, p] of state.panels) {
      if (!seen.has(id)) { p.dom.root.remove(); state.panels.delete(id); }
    }
    // A successful curve edit comes back as a panels message: clear curve errors.
    for (const e of document.querySelectorAll("#curves .curve-error")) e.hidden = true;
  }

  function el(tag, cls, text) {
    const e = document.createElement(tag);
    if (cls) e.className = cls;
    if (text != null) e.textContent = text;
    return e;
  }

  function buildPanel(info) {
    const root = el("div", "panel");
    root.dataset.panel = String(info.id);
    const title = el("h2");
    const name = el("span", "panel-title");
    const remove = el("button", "remove", "×");
    remove.title = "remove this panel";
    remove.onclick = () => send({ type: "remove_panel", panel: info.id });
    title.append(name, remove);
    const canvas = el("canvas", "view");
    canvas.width = 920; canvas.height = 680;
    countCalls(canvas);
    const note = el("div", "note muted");
    const readout = el("div", "readout");
    const fields = {};
    for (const key of ["t", "energy", "erel", "cerr", "sps", "status"]) {
      fields[key] = el("span", "r-" + key);
      readout.appendChild(fields[key]);
    }
    const charts = el("div", "charts");
    const chartE = el("canvas", "chart chart-energy");
    const chartC = el("canvas", "chart chart-cerr");
    for (const c of [chartE, chartC]) { c.width = 454; c.height = 180; charts.appendChild(c); }
    const config = el("div", "config");
    const method = el("select", "method");
    for (const m of state.welcome ? state.welcome.methods : ["implicit", "parametric"]) option(method, m, m);
    const integrator = el("select", "integrator");
    for (const k of state.welcome ? state.welcome.integrators : []) option(integrator, k.name, k.name, k.description);
    const dt = el("input", "dt"); dt.type = "text";
    const ks = el("input", "ks"); ks.type = "text";
    const kd = el("input", "kd"); kd.type = "text";
    const project = el("input", "project"); project.type = "checkbox";
    const apply = el("button", "apply", "Apply");
    const playOne = el("button", "play-one", "▶/❚❚");
    playOne.title = "play / pause this panel";
    const labelled = (text, input) => { const l = el("label", null, text + " "); l.appendChild(input); return l; };
    config.append(method, integrator, labelled("dt", dt), labelled("ks", ks), labelled("kd", kd),
      labelled("project", project), apply, playOne);
    const configError = el("div", "panel-error error");
    const failure = el("div", "panel-failure error");
    apply.onclick = () => {
      const isImplicit = method.value === "implicit";
      const msg = {
        type: "configure_panel", panel: info.id, method: method.value, integrator: integrator.value,
        dt: Number(dt.value), ks: isImplicit ? Number(ks.value) : 0, kd: isImplicit ? Number(kd.value) : 0,
        project: isImplicit && project.checked,
      };
      for (const k of ["dt", "ks", "kd"]) {
        if (!Number.isFinite(msg[k])) { configError.textContent = `${k} must be a number`; return; }
      }
      send(msg);
    };
    // Switching the integrator applies at once.
    integrator.onchange = () => apply.onclick();
    method.onchange = () => apply.onclick();
    playOne.onclick = () => {
      const p = state.panels.get(info.id);
      const running = p && p.frame && p.frame.status === "running";
      send({ type: running ? "pause" : "play", panel: info.id });
    };
    root.append(title, canvas, note, readout, charts, config, configError, failure);
    const dom = { root, name, canvas, note, fields, chartE, chartC, method, integrator, dt, ks, kd, project, configError, failure };
    installDrag(info.id, canvas);
    return dom;
  }

  // Count the canvas's painting calls (each stroke, fill, rect or text is one): a draw's cost
  // grows with them, so the tests can check that drawing is batched whatever the scene's size.
  function countCalls(canvas) {
    const ctx = canvas.getContext("2d");
    canvas.paintCalls = 0;
    for (const name of ["stroke", "fill", "fillRect", "strokeRect", "fillText", "strokeText"]) {
      const call = ctx[name].bind(ctx);
      ctx[name] = (...args) => { canvas.paintCalls++; return call(...args); };
    }
  }

  function fillConfig(p) {
    const { info, dom } = p;
    dom.name.textContent = `#${info.id} ${info.method} · ${info.integrator} · dt ${fmt(info.dt)}` +
      (info.ks || info.kd ? ` · ks ${fmt(info.ks)}, kd ${fmt(info.kd)}` : "") + (info.project ? " · projected" : "");
    dom.method.value = info.method;
    dom.integrator.value = info.integrator;
    dom.dt.value = String(info.dt);
    dom.ks.value = String(info.ks);
    dom.kd.value = String(info.kd);
    dom.project.checked = info.project;
    const scene = state.scene;
    const notes = [];
    if (scene && scene.dim === 3) notes.push("3D scene: projected onto x-y");
    notes.push(info.curve_source === "contour" ? "curve: zero set of C (marching squares)" :
      info.curve_source === "parametric" ? "curve: x(q) sampled" : "no curve drawn");
    notes.push("+y down; drag a particle with the mouse");
    dom.note.textContent = notes.join(" · ");
  }

  function onFrame(msg) {
    for (const f of msg.panels) {
      const p = state.panels.get(f.id);
      if (!p) continue;
      // Sent before the panel restarted: nothing of it belongs to the new epoch.
      if (f.epoch < p.info.epoch) continue;
      const previous = p.frame;
      p.frame = f;
      if (previous && f.epoch !== previous.epoch) { p.trail = []; p.history = []; }
      p.dirty = true;
      if (!previous || f.t !== previous.t || f.steps !== previous.steps || f.epoch !== previous.epoch) {
        if (trailsOn()) {
          p.trail.push(f.x.slice());
          const keep = trailLength();
          if (p.trail.length > keep) p.trail.splice(0, p.trail.length - keep);
        } else if (p.trail.length) {
          p.trail = [];
        }
        p.history.push([f.t, f.energy_error, f.constraint_error]);
        if (p.history.length > HISTORY) p.history.shift();
      }
      const r = p.dom.fields;
      r.t.textContent = `t = ${fmt(f.t)} s`;
      // What the panel conserves: T + V, or E - W when something does work on the system.
      const reasons = f.not_conserved_by.join("; ");
      r.energy.textContent = f.energy_conserved ? `E = ${fmt(f.energy, 7)}` :
        `E = ${fmt(f.energy, 7)}, W = ${fmt(f.work, 5)}`;
      r.erel.textContent = f.energy_conserved ? `|ΔE|/E_scale = ${fmt(f.energy_error)}` :
        `|Δ(E − W)|/E_scale = ${fmt(f.energy_error)}`;
      r.erel.title = f.energy_conserved ? "relative energy error, |E - E0| / E_scale with E_scale = max(|E0|, T0 + |V0|, T0 + M g L)" :
        `energy not conserved (${reasons}): the error of E − W, W the work done on the system`;
      r.erel.dataset.value = String(f.energy_error);
      r.cerr.textContent = `|C| = ${fmt(f.constraint_error)}`;
      r.cerr.dataset.value = String(f.constraint_error);
      r.sps.textContent = `steps/s = ${fmt(f.steps_per_second, 3)}`;
      r.status.textContent = f.status + (f.behind ? " (behind real time)" : "");
      p.dom.failure.textContent = f.error || "";
    }
    const anyRunning = msg.panels.some((f) => f.status === "running");
    $("play").textContent = anyRunning ? "Pause" : "Play";
  }

  // ---------- drawing ----------
  function transform(p) {
    const c = p.dom.canvas;
    const v = state.scene ? state.scene.view : [-1, -1, 1, 1];
    const margin = { l: 56, r: 12, t: 12, b: 36 };
    const w = c.width - margin.l - margin.r, h = c.height - margin.t - margin.b;
    const s = Math.min(w / (v[2] - v[0]), h / (v[3] - v[1]));
    const ox = margin.l + (w - s * (v[2] - v[0])) / 2, oy = margin.t + (h - s * (v[3] - v[1])) / 2;
    return {
      s, v, margin,
      x: (x) => ox + (x - v[0]) * s,
      y: (y) => oy + (y - v[1]) * s, // +y down, like the scenes
      ix: (px) => v[0] + (px - ox) / s,
      iy: (py) => v[1] + (py - oy) / s,
    };
  }

  function drawAxes(ctx, T, c) {
    ctx.save();
    ctx.strokeStyle = "#e6e6e2";
    ctx.fillStyle = "#6b6b70";
    ctx.lineWidth = 1;
    ctx.font = "20px system-ui, sans-serif";
    const [x0, y0, x1, y1] = T.v;
    const sx = niceStep(x1 - x0, 6), sy = niceStep(y1 - y0, 5);
    ctx.textAlign = "center";
    for (let x = Math.ceil(x0 / sx) * sx; x <= x1; x += sx) {
      const px = T.x(x);
      ctx.beginPath(); ctx.moveTo(px, T.y(y0)); ctx.lineTo(px, T.y(y1)); ctx.stroke();
      ctx.fillText(fmt(x, 3), px, c.height - 10);
    }
    ctx.textAlign = "right";
    for (let y = Math.ceil(y0 / sy) * sy; y <= y1; y += sy) {
      const py = T.y(y);
      ctx.beginPath(); ctx.moveTo(T.x(x0), py); ctx.lineTo(T.x(x1), py); ctx.stroke();
      ctx.fillText(fmt(y, 3), T.margin.l - 6, py + 6);
    }
    ctx.strokeStyle = "#9a9a96";
    if (x0 <= 0 && x1 >= 0) { ctx.beginPath(); ctx.moveTo(T.x(0), T.y(y0)); ctx.lineTo(T.x(0), T.y(y1)); ctx.stroke(); }
    if (y0 <= 0 && y1 >= 0) { ctx.beginPath(); ctx.moveTo(T.x(x0), T.y(0)); ctx.lineTo(T.x(x1), T.y(0)); ctx.stroke(); }
    ctx.restore();
  }

  function drawPanel(p) {
    const c = p.dom.canvas, ctx = c.getContext("2d");
    const scene = state.scene;
    ctx.fillStyle = "#ffffff";
    ctx.fillRect(0, 0, c.width, c.height);
    if (!scene) return null;
    const T = transform(p);
    drawAxes(ctx, T, c);
    // Curves: one path (marching squares make hundreds of short pieces).
    ctx.save();
    ctx.strokeStyle = "#1f6feb";
    ctx.lineWidth = 2.5;
    ctx.lineCap = "round";
    ctx.lineJoin = "round";
    ctx.beginPath();
    for (const line of p.info.curves) {
      for (let i = 0; i + 1 < line.length; i += 2) {
        const px = T.x(line[i]), py = T.y(line[i + 1]);
        if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
      }
    }
    ctx.stroke();
    ctx.restore();
    const f = p.frame;
    if (!f) return null;
    const dim = scene.dim;
    const n = Math.min(scene.particles.length, Math.floor(f.x.length / dim));
    const X = (k) => T.x(f.x[k * dim]), Y = (k) => T.y(f.x[k * dim + 1]);
    const failed = f.status === "failed";
    const { pairs, anchored, pins } = scene.draw;
    const size = sizes(p, T, f, n, dim);
    // Trails: one path per band of age (8 shades), not one per segment.
    if (p.trail.length > 1) {
      ctx.save();
      ctx.lineWidth = size.trail;
      ctx.lineCap = "round";
      ctx.lineJoin = "round";
      const trail = p.trail, len = trail.length, bands = Math.min(8, len - 1);
      for (let band = 0; band < bands; band++) {
        const i0 = 1 + Math.floor((band * (len - 1)) / bands);
        const i1 = 1 + Math.floor(((band + 1) * (len - 1)) / bands);
        ctx.strokeStyle = `rgba(240, 110, 0, ${(i1 / len) * 0.75})`;
        ctx.beginPath();
        for (let k = 0; k < n; k++) {
          const a = trail[i0 - 1];
          ctx.moveTo(T.x(a[k * dim]), T.y(a[k * dim + 1]));
          for (let i = i0; i < i1; i++) ctx.lineTo(T.x(trail[i][k * dim]), T.y(trail[i][k * dim + 1]));
        }
        ctx.stroke();
      }
      ctx.restore();
    }
    // Rods: one path for all of them, one for the rods to anchors.
    ctx.save();
    ctx.strokeStyle = "#333";
    ctx.fillStyle = "#333";
    ctx.lineWidth = size.rod;
    ctx.beginPath();
    let rods = 0;
    for (let i = 0; i + 1 < pairs.length; i += 2) {
      const a = pairs[i], b = pairs[i + 1];
      if (a >= n || b >= n) continue;
      ctx.moveTo(X(a), Y(a));
      ctx.lineTo(X(b), Y(b));
      rods++;
    }
    for (const rod of anchored) {
      if (rod.a >= n) continue;
      ctx.moveTo(X(rod.a), Y(rod.a));
      ctx.lineTo(T.x(rod.anchor[0]), T.y(rod.anchor[1]));
      rods++;
    }
    ctx.stroke();
    // Anchors and pins: squares at the fixed points.
    ctx.beginPath();
    for (const rod of anchored) ctx.rect(T.x(rod.anchor[0]) - 5, T.y(rod.anchor[1]) - 5, 10, 10);
    const pin = Math.max(10, 2 * size.radius + 6);
    for (const q of pins) ctx.rect(T.x(q.anchor[0]) - pin / 2, T.y(q.anchor[1]) - pin / 2, pin, pin);
    ctx.fill();
    ctx.restore();
    // Drag spring.
    if (f.drag) {
      const k = f.drag.particle;
      ctx.save();
      ctx.strokeStyle = "#b42318";
      ctx.setLineDash([8, 6]);
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.moveTo(X(k), Y(k));
      ctx.lineTo(T.x(f.drag.target[0]), T.y(f.drag.target[1]));
      ctx.stroke();
      ctx.restore();
    }
    // Particles: one path; circles with an outline when they are big enough to show one,
    // squares (far cheaper to fill) when they are a few pixels.
    ctx.save();
    ctx.fillStyle = failed ? "#b42318" : "#e67814";
    ctx.beginPath();
    const r = size.radius;
    if (r >= 3) {
      for (let k = 0; k < n; k++) {
        const px = X(k), py = Y(k);
        ctx.moveTo(px + r, py);
        ctx.arc(px, py, r, 0, 2 * Math.PI);
      }
    } else {
      for (let k = 0; k < n; k++) ctx.rect(X(k) - r, Y(k) - r, 2 * r, 2 * r);
    }
    ctx.fill();
    if (r >= 5) {
      ctx.lineWidth = 2;
      ctx.strokeStyle = "#222";
      ctx.stroke();
    }
    ctx.restore();
    if (failed) {
      ctx.fillStyle = "rgba(180, 35, 24, 0.9)";
      ctx.font = "22px system-ui, sans-serif";
      ctx.textAlign = "left";
      ctx.fillText("stopped: see the message below", 70, 40);
    }
    return { rods, particles: n, pins: pins.length, frame: f };
  }

  // Sizes in canvas pixels: particles shrink with their number and their spacing on screen
  // (a fraction of the median rod length, from the first frame drawn), from 11 down to 1.5.
  function sizes(p, T, f, n, dim) {
    if (p.sizes && p.sizes.epoch === f.epoch && p.sizes.scale === T.s) return p.sizes;
    let radius = n <= 16 ? 11 : Math.max(1.5, 11 * Math.sqrt(16 / n));
    const pairs = state.scene.draw.pairs, lengths = [];
    for (let i = 0; i + 1 < pairs.length && lengths.length < 2000; i += 2) {
      const a = pairs[i], b = pairs[i + 1];
      if (a >= n || b >= n) continue;
      const d = T.s * Math.hypot(f.x[a * dim] - f.x[b * dim], f.x[a * dim + 1] - f.x[b * dim + 1]);
      if (Number.isFinite(d)) lengths.push(d);
    }
    if (lengths.length) {
      lengths.sort((a, b) => a - b);
      radius = Math.max(1.5, Math.min(radius, 0.35 * lengths[lengths.length >> 1]));
    }
    const rod = n <= 16 ? 3 : Math.max(1, Math.min(3, radius / 2));
    const trail = n <= 16 ? 5 : Math.max(1, Math.min(5, radius));
    p.sizes = { epoch: f.epoch, scale: T.s, radius, rod, trail };
    return p.sizes;
  }

  function drawChart(canvas, history, index, label, color) {
    const ctx = canvas.getContext("2d");
    const W = canvas.width, H = canvas.height;
    ctx.fillStyle = "#fff";
    ctx.fillRect(0, 0, W, H);
    // Exact zeros (a parametric panel's |C| is often 0) are gaps: log scale has no 0.
    const pts = history.filter((h) => Number.isFinite(h[index]));
    const logs = pts.map((h) => (h[index] > 0 ? Math.log10(h[index]) : null));
    const finiteLogs = logs.filter((v) => v !== null);
    let lo = Math.floor(Math.min(-16, ...finiteLogs)), hi = Math.ceil(Math.max(-15, ...finiteLogs));
    lo = Math.max(lo, hi - 18);
    if (hi <= lo) hi = lo + 1;
    const t0 = pts.length ? pts[0][0] : 0, t1 = pts.length ? pts[pts.length - 1][0] : 1;
    const span = t1 > t0 ? t1 - t0 : 1;
    const L = 52, R = 6, Tp = 18, B = 22;
    const px = (t) => L + ((t - t0) / span) * (W - L - R);
    const py = (v) => Tp + (1 - (v - lo) / (hi - lo)) * (H - Tp - B);
    ctx.strokeStyle = "#e6e6e2";
    ctx.fillStyle = "#6b6b70";
    ctx.font = "16px system-ui, sans-serif";
    ctx.textAlign = "right";
    const step = Math.max(1, Math.ceil((hi - lo) / 4));
    for (let d = hi; d >= lo; d -= step) {
      ctx.beginPath(); ctx.moveTo(L, py(d)); ctx.lineTo(W - R, py(d)); ctx.stroke();
      ctx.fillText("1e" + d, L - 4, py(d) + 5);
    }
    ctx.textAlign = "left";
    let title = label;
    const room = W - L - R - 8;
    if (ctx.measureText(title).width > room) {
      while (title.length > 1 && ctx.measureText(title + "…").width > room) title = title.slice(0, -1);
      title += "…";
    }
    ctx.fillText(title, L + 4, 14);
    ctx.textAlign = "right";
    ctx.fillText(`t ${fmt(t0, 3)}–${fmt(t1, 3)} s`, W - R, H - 4);
    ctx.strokeStyle = color;
    ctx.lineWidth = 2;
    ctx.beginPath();
    let pen = false;
    pts.forEach((h, i) => {
      if (logs[i] === null) { pen = false; return; }
      const x = px(h[0]), y = py(Math.max(logs[i], lo));
      if (pen) ctx.lineTo(x, y); else ctx.moveTo(x, y);
      pen = true;
    });
    ctx.stroke();
  }

  // Draw panel `p` and time it; `flush` reads a pixel back so that the time includes the
  // rasterization, which the browser otherwise defers past the script.
  function draw(p, flush) {
    const start = performance.now();
    const calls = p.dom.canvas.paintCalls;
    const drawn = drawPanel(p);
    if (flush) p.dom.canvas.getContext("2d").getImageData(0, 0, 1, 1);
    const ms = performance.now() - start;
    if (drawn) {
      drawn.ms = ms;
      drawn.paintCalls = p.dom.canvas.paintCalls - calls;
      p.lastDraw = drawn;
      p.drawTimes.push(ms);
      if (p.drawTimes.length > DRAW_SAMPLES) p.drawTimes.shift();
    }
    return ms;
  }
  // For the tests: draw panel `id` `count` times, flushed; the times in ms.
  state.drawTimes = (id, count) => {
    const p = state.panels.get(id);
    const times = [];
    for (let i = 0; i < count; i++) times.push(draw(p, true));
    return times;
  };

  // Panels are drawn when something changed: a frame, the panel's settings, the scene.
  function render() {
    for (const p of state.panels.values()) {
      if (!p.dirty) continue;
      p.dirty = false;
      draw(p, false);
      const f = p.frame;
      const energyLabel = !f || f.energy_conserved ? "relative energy error" :
        `energy (not conserved: ${f.not_conserved_by.join("; ")}): error of E − W`;
      p.dom.chartE.title = energyLabel;
      drawChart(p.dom.chartE, p.history, 1, energyLabel, "#1f6feb");
      drawChart(p.dom.chartC, p.history, 2, "constraint error |C|", "#b42318");
    }
    for (const move of state.pendingMoves.values()) send(move);
    state.pendingMoves.clear();
    requestAnimationFrame(render);
  }

  // ---------- dragging ----------
  function canvasPoint(canvas, event) {
    const r = canvas.getBoundingClientRect();
    return [(event.clientX - r.left) * (canvas.width / r.width), (event.clientY - r.top) * (canvas.height / r.height)];
  }

  function installDrag(id, canvas) {
    canvas.addEventListener("pointerdown", (event) => {
      const p = state.panels.get(id);
      if (!p || !p.frame || !state.scene) return;
      const T = transform(p);
      const [cx, cy] = canvasPoint(canvas, event);
      const dim = state.scene.dim;
      let best = -1, bestD = 30;
      for (let k = 0; k < state.scene.particles.length; k++) {
        const d = Math.hypot(T.x(p.frame.x[k * dim]) - cx, T.y(p.frame.x[k * dim + 1]) - cy);
        if (d < bestD) { best = k; bestD = d; }
      }
      if (best < 0) return;
      try { canvas.setPointerCapture(event.pointerId); } catch (e) { /* synthetic events */ }
      state.drags.set(id, best);
      send({ type: "drag_start", panel: id, particle: best, target: [T.ix(cx), T.iy(cy)] });
      event.preventDefault();
    });
    canvas.addEventListener("pointermove", (event) => {
      if (!state.drags.has(id)) return;
      const p = state.panels.get(id);
      if (!p) return;
      const T = transform(p);
      const [cx, cy] = canvasPoint(canvas, event);
      state.pendingMoves.set(id, { type: "drag_move", panel: id, target: [T.ix(cx), T.iy(cy)] });
    });
    const end = () => {
      if (!state.drags.has(id)) return;
      const move = state.pendingMoves.get(id);
      if (move) { send(move); state.pendingMoves.delete(id); }
      send({ type: "drag_end", panel: id });
      state.drags.delete(id);
    };
    canvas.addEventListener("pointerup", end);
    canvas.addEventListener("pointercancel", end);
  }

  // Client coordinates of scene point (x, y) in panel `id` (for tests).
  state.clientPoint = (id, x, y) => {
    const p = state.panels.get(id);
    const T = transform(p);
    const r = p.dom.canvas.getBoundingClientRect();
    return [r.left + T.x(x) * (r.width / p.dom.canvas.width), r.top + T.y(y) * (r.height / p.dom.canvas.height)];
  };

  // Canvas pixel of scene point (x, y) in panel `id` (for tests).
  state.canvasPoint = (id, x, y) => {
    const T = transform(state.panels.get(id));
    return [T.x(x), T.y(y)];
  };

  // ---------- toolbar ----------
  $("play").onclick = () => {
    send({ type: $("play").textContent === "Pause" ? "pause" : "play" });
  };
  $("step").onclick = () => send({ type: "step" });
  $("trails").onchange = () => {
    for (const p of state.panels.values()) { p.trail = []; p.dirty = true; }
  };
  $("reset").onclick = () => send({ type: "reset" });
  $("time-scale").onchange = () => send({ type: "set_time_scale", scale: Number($("time-scale").value) });
  $("scene-select").onchange = () => send({ type: "load_scene", name: $("scene-select").value });
  $("scene-file").onchange = async () => {
    const file = $("scene-file").files[0];
    if (!file) return;
    if (file.size > 60000) { showMessage("scene file too large (limit 60 kB)"); return; }
    const text = await file.text();
    send({ type: "load_scene", toml: text, file_name: file.name });
    $("scene-file").value = "";
  };
  $("add-panel").onclick = () => {
    const method = $("new-method").value;
    const msg = { type: "add_panel", method, integrator: $("new-integrator").value };
    const dt = $("new-dt").value.trim();
    if (dt) {
      const v = Number(dt);
      if (!Number.isFinite(v)) { showMessage("dt must be a number"); return; }
      msg.dt = v;
    }
    if (method === "parametric") { msg.ks = 0; msg.kd = 0; }
    send(msg);
  };

  connect();
  requestAnimationFrame(render);
})();
