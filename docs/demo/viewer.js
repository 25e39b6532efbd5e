// bead viewer: draws what the server streams over /ws (protocol: crates/bead-viewer/src/protocol.rs),
// or, in a static page, what the engine in the page sends (engine.js, the same messages).
// Plain modern JavaScript, no build step, no dependencies.
"use strict";

(function () {
  const $ = (id) => document.getElementById(id);
  const TRAIL = 1500;       // trail points per particle (the simulation's steps)
  const SAMPLES = 400;      // states kept per panel for interpolation
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
    timeScale: 1,
    // The session's clock of the last frame: generation (restarts), sim_rate, limited_by.
    clock: null,
    // A share URL being restored: { scene, params: [[name, value]], panels: [...], ts }.
    restore: null,
    // Overlay mode: the canvas with every panel's particles, and its own view.
    overlay: { on: false, view: null, box: null, history: new Map(), lastDraw: null, dirty: true },
  };
  window.__viewer = state;  // for the end-to-end tests

  function send(message) {
    if (state.ws && state.ws.readyState === 1 /* OPEN */) {
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
  // The served page connects to its server's /ws; a static page (engine.js loaded before
  // this script) runs the session in the page, behind the same interface.
  function connect() {
    let ws;
    if (window.BeadEngine) {
      ws = new window.BeadEngine.Socket();
    } else {
      const proto = location.protocol === "https:" ? "wss:" : "ws:";
      ws = new WebSocket(`${proto}//${location.host}/ws`);
    }
    state.ws = ws;
    ws.onopen = () => { $("connection").textContent = ws.label || "connected"; };
    ws.onclose = (event) => {
      $("connection").textContent = window.BeadEngine
        ? `stopped (${(event && event.reason) || "closed"}) — reload to start again`
        : "disconnected — reload to reconnect";
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
      // The simulation's steps since the last frame: samples of t then the positions.
      const size = 1 + f.x_count;
      if (!(f.path_offset + f.path_count * size <= count)) return null;
      f.path = [];
      for (let k = 0; k < f.path_count; k++) {
        const at = f.path_offset + k * size;
        f.path.push({ t: numbers[at], x: numbers.subarray(at + 1, at + size) });
      }
      // Moving curves, at this frame's t.
      if (f.curve_counts) {
        f.curves = [];
        let at = f.curve_offset;
        for (const c of f.curve_counts) {
          if (!(at + c <= count)) return null;
          f.curves.push(numbers.subarray(at, at + c));
          at += c;
        }
      }
    }
    return msg;
  }

  function handle(msg) {
    switch (msg.type) {
      case "welcome": onWelcome(msg); break;
      case "scene": onScene(msg); restoreStep(msg); break;
      case "panels":
        // The panels a new start state started: it lasts while they run from it.
        if (state.customStart && !state.customStart.epochs) state.customStart.epochs = msg.panels.map((p) => p.epoch);
        onPanels(msg.panels); restoreStep(msg); break;
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
        // A refused parameter: the slider goes back to the scene's value.
        if (msg.request === "set_param" && state.scene) buildParams(state.scene);
        restoreStep(msg);
        break;
      case "scene_error":
        $("scene-error").hidden = false;
        $("scene-error").textContent = msg.message;
        break;
      case "curve_error": onCurveError(msg); break;
      case "equations": onEquations(msg); break;
      case "start_placed":
        if (msg.positions) noteStart(msg.positions, msg.positions.map(() => 0));
        onStartPlaced(msg); break;
      case "state_set": noteStart(msg.positions, msg.velocities); onStateSet(msg); break;
      default: break;
    }
  }

  // A drop while paused starts every panel at the point of the curve closest to it: say how
  // far that is on the screen of the panel dropped on, unless under half a pixel.
  // A typed or dragged start state was placed on the constraints: say how far it moved.
  function onStateSet(msg) {
    const parts = [];
    if (msg.position_moved > 0) parts.push(`positions moved ${fmt(msg.position_moved)} onto the constraints`);
    if (msg.velocity_moved > 0) parts.push(`velocity changed by ${fmt(msg.velocity_moved)} (its part across the constraints removed)`);
    showMessage(parts.length ? "start set: " + parts.join("; ") : "start set");
  }

  function onStartPlaced(msg) {
    const p = state.panels.get(msg.panel);
    let pixels = null;
    if (p && state.scene) {
      const T = transform(p);
      const dx = T.px(msg.placed, 0) - T.px(msg.dropped, 0);
      const dy = T.py(msg.placed, 0) - T.py(msg.dropped, 0);
      const canvas = p.dom.canvas;
      const ratio = canvas.width > 0 ? canvas.getBoundingClientRect().width / canvas.width : 1;
      pixels = Math.hypot(dx, dy) * ratio;
    }
    if (pixels !== null ? pixels < 0.5 : !(msg.moved > 0)) return;
    const where = pixels !== null ? `${Math.round(pixels)} px` : fmt(msg.moved);
    showMessage(`moved the drop ${where} onto the curve (${fmt(msg.moved)} in the scene's units), to the closest point`);
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
    // A share URL (`?scene=NAME&param.g=9.81&panel=implicit:rk4:0.01&ts=1`) opens its
    // scene, then sets its parameters, panels and time scale (see `restoreStep`).
    const restore = parseShareUrl(location.search, msg);
    if (restore) {
      state.restore = restore;
      if (restore.ts != null) {
        send({ type: "set_time_scale", scale: restore.ts });
        $("time-scale").value = String(restore.ts);
      }
      if (restore.scene !== msg.scenes[0]) send({ type: "load_scene", name: restore.scene });
    }
  }

  // ---------- share URL ----------
  // The page's state as a URL: scene, parameter values, panels (method:integrator:dt, and
  // ks, kd, projection when set) and time scale.
  function shareUrl() {
    const q = new URLSearchParams();
    if (state.scene) q.set("scene", state.scene.name);
    for (const prm of (state.scene && state.scene.params) || []) {
      if (prm.derived == null) q.append("param." + prm.name, String(prm.value));
    }
    for (const p of state.panels.values()) {
      const i = p.info;
      let spec = `${i.method}:${i.integrator}:${i.dt}`;
      if (i.ks || i.kd || i.project || i.reference) {
        spec += `:${i.ks}:${i.kd}` + (i.project ? ":project" : "") + (i.reference ? ":reference" : "");
      }
      q.append("panel", spec);
    }
    for (const [i, expr] of curveEdits()) q.append(`curve.${i}`, expr);
    const start = sharedStart();
    if (start) {
      q.set("start.x", start.positions.map(String).join(","));
      q.set("start.v", start.velocities.map(String).join(","));
    }
    q.set("ts", String(state.timeScale));
    if (state.presenting) q.set("present", "1");
    // The page's address without its query (origin + path; a file:// page has no origin).
    return `${location.href.split(/[?#]/)[0]}?${q.toString()}`;
  }

  // The curves edited in the implicit panels: [constraint index, expression] where the
  // first implicit panel's expression is not the scene's.
  function curveEdits() {
    const out = [];
    const first = [...state.panels.values()].find((p) => p.info.method === "implicit");
    if (!first || !state.scene) return out;
    state.scene.constraints.forEach((c, i) => {
      const now = first.info.exprs[i];
      if (c.expr != null && now != null && now !== c.expr) out.push([i, now]);
    });
    return out;
  }
  // A start state set by typing or dragging (state_set, start_placed), while every panel
  // still runs from it (the epochs it started); a reset, a new panel or a new scene ends it.
  function noteStart(positions, velocities) {
    state.customStart = { positions: positions.slice(), velocities: velocities.slice(), epochs: null };
  }
  function sharedStart() {
    const c = state.customStart;
    if (!c || !c.epochs) return null;
    for (const p of state.panels.values()) if (!c.epochs.includes(p.info.epoch)) return null;
    return c;
  }

  // The address bar follows the page's state (a share URL without the click), so that a
  // refresh comes back to the same scene, parameters, panels and time scale.
  function keepUrl() {
    if (state.restore || !state.scene) return;
    const url = shareUrl();
    if (url !== location.href) {
      try { history.replaceState(null, "", url); } catch (e) { /* file:// and the like */ }
    }
  }

  // What a share URL asks for, or null when it asks for nothing; bad parts are said on the
  // page and left out.
  function parseShareUrl(search, welcome) {
    const q = new URLSearchParams(search);
    if (![...q.keys()].length) return null;
    const bad = (text) => showMessage("share URL: " + text);
    const out = { scene: welcome.scenes[0], params: [], panels: [], ts: null, stage: "scene" };
    const scene = q.get("scene");
    if (scene != null) {
      if (welcome.scenes.includes(scene)) out.scene = scene;
      else bad(`unknown scene \`${scene}\`; use one of ${welcome.scenes.join(", ")}`);
    }
    for (const [key, value] of q) {
      if (!key.startsWith("param.")) continue;
      const v = Number(value);
      if (value.trim() === "" || !Number.isFinite(v)) { bad(`parameter ${key.slice(6)}: \`${value}\` is not a number`); continue; }
      out.params.push([key.slice(6), v]);
    }
    const integrators = welcome.integrators.map((k) => k.name);
    for (const spec of q.getAll("panel")) {
      const parts = spec.split(":");
      const [method, integrator, dt] = parts;
      const panel = { method, integrator, dt: Number(dt) };
      if (!welcome.methods.includes(method)) { bad(`panel \`${spec}\`: unknown method \`${method}\``); continue; }
      if (!integrators.includes(integrator)) { bad(`panel \`${spec}\`: unknown integrator \`${integrator}\``); continue; }
      if (!(dt && Number.isFinite(panel.dt) && panel.dt > 0)) { bad(`panel \`${spec}\`: dt must be a number > 0`); continue; }
      if (parts.length >= 5) {
        panel.ks = Number(parts[3]); panel.kd = Number(parts[4]);
        if (!Number.isFinite(panel.ks) || !Number.isFinite(panel.kd)) { bad(`panel \`${spec}\`: ks and kd must be numbers`); continue; }
        panel.project = parts.slice(5).includes("project");
        panel.reference = parts.slice(5).includes("reference");
      }
      out.panels.push(panel);
    }
    out.curves = [];
    for (const [key, value] of q) {
      if (!key.startsWith("curve.")) continue;
      const i = Number(key.slice(6));
      if (!Number.isInteger(i) || i < 0) { bad(`\`${key}\`: the constraint's number must be a whole number >= 0`); continue; }
      out.curves.push([i, value]);
    }
    const numbers = (key) => {
      const text = q.get(key);
      if (text == null) return null;
      const v = text.split(",").map(Number);
      if (!text.trim() || !v.every(Number.isFinite)) { bad(`\`${key}\`: \`${text}\` is not a list of numbers`); return undefined; }
      return v;
    };
    const positions = numbers("start.x"), velocities = numbers("start.v");
    if (positions !== undefined && velocities !== undefined && (positions || velocities)) {
      out.start = { positions, velocities };
    }
    const ts = q.get("ts");
    if (ts != null) {
      const v = Number(ts);
      const allowed = [...$("time-scale").options].map((o) => Number(o.value));
      if (allowed.includes(v)) out.ts = v; else bad(`time scale \`${ts}\` is not one of ${allowed.join(", ")}`);
    }
    return out;
  }

  // Restoring a share URL, one stage per server reply: the scene is loaded (stage "scene"),
  // then the parameters are set (each reloads the scene), then the panels are replaced.
  function restoreStep(msg) {
    const r = state.restore;
    if (!r) return;
    if (msg.type === "scene") {
      if (msg.name !== r.scene) return;
      if (r.stage === "scene") {
        // Each set_param is answered by a scene (and panels) or an error, in order.
        r.awaiting = 0;
        const known = new Map(msg.params.map((prm) => [prm.name, prm]));
        for (const [name, value] of r.params) {
          const prm = known.get(name);
          if (prm && (sameNumber(prm.value, value) || prm.derived != null)) continue;
          send({ type: "set_param", name, value });
          r.awaiting++;
        }
        r.stage = r.awaiting ? "params" : "panels";
      } else if (r.stage === "params") {
        r.awaiting--;
        if (r.awaiting <= 0) r.stage = "panels";
      }
    } else if (msg.type === "error" && r.stage === "params" && msg.request === "set_param") {
      // Refused (said on the page): go on with the panels as they are.
      r.awaiting--;
      if (r.awaiting <= 0) {
        r.stage = "panels";
        restoreStep({ type: "panels", panels: [...state.panels.values()].map((p) => p.info) });
      }
    } else if (msg.type === "panels" && r.stage === "panels") {
      state.restore = null;
      // The server takes requests in order: the panels, then the curve edits (for the
      // implicit panels), then the start state (placed by the first panel).
      if (r.panels.length) {
        for (const p of msg.panels) send({ type: "remove_panel", panel: p.id });
        for (const panel of r.panels) send({ type: "add_panel", ...panel });
      }
      for (const [constraint, expr] of r.curves || []) send({ type: "set_curve", constraint, expr });
      if (r.start) {
        const start = { type: "set_start_state" };
        if (r.start.positions) start.positions = r.start.positions;
        if (r.start.velocities) start.velocities = r.start.velocities;
        send(start);
      }
    }
  }
  const sameNumber = (a, b) => a === b || Math.abs(a - b) <= 1e-12 * Math.max(Math.abs(a), Math.abs(b));

  function onScene(scene) {
    state.scene = scene;
    $("scene-error").hidden = true;
    const up = sceneUp(scene);
    const upName = scene.dim === 3 ?
      ["x", "y", "z"].map((n, a) => (Math.abs(up[a]) > 0.99 ? (up[a] > 0 ? n : "−" + n) : null)).filter(Boolean)[0] : null;
    $("scene-title").textContent = `${scene.title} (${scene.name})` +
      (scene.dim === 3 ? ` — 3D view, ${upName ? upName + " up" : "up against gravity"}: drag empty space to orbit, shift-drag to pan, wheel to zoom` : "");
    $("scene-about").textContent = scene.about || "";
    $("scene-warnings").textContent = scene.warnings.map((w) => "warning: " + w).join("\n");
    const picker = $("scene-select");
    // A file loaded in the page joins the picker once (picking it again reloads the shipped
    // or command-line scene of that name only; a file is loaded again from disk).
    if (![...picker.options].some((o) => o.value === scene.name)) {
      const o = option(picker, scene.name, `${scene.name} (file)`);
      o.disabled = true;
      o.title = "loaded from a file in this page: use “load file…” to load it again";
    }
    picker.value = scene.name;
    buildCurveEditors(scene);
    buildParams(scene);
    buildStartForm(scene);
    prepareScene(scene);
    state.overlay.view = null;
    state.overlay.box = null;
    state.overlay.history.clear();
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
    // Arrows: on for scenes of a few particles (a bead, a pendulum); none come for large ones.
    const few = scene.particles.length <= ARROW_DEFAULT_PARTICLES;
    for (const kind of ARROW_KINDS) $("arrow-" + kind.key).checked = few;
    $("arrow-toggles").hidden = scene.particles.length > ARROW_MAX_PARTICLES;
  }

  // Arrows are drawn by default for scenes of at most this many particles; the server sends
  // them for at most ARROW_MAX_PARTICLES (protocol.rs).
  const ARROW_DEFAULT_PARTICLES = 4, ARROW_MAX_PARTICLES = 16;
  function trailsOn() {
    return $("trails").checked;
  }

  // Trail points kept per particle.
  function trailLength() {
    const n = state.scene ? state.scene.particles.length : 1;
    return Math.max(2, Math.min(TRAIL, Math.floor(TRAIL_BUDGET / Math.max(n, 1))));
  }

  // ---------- parameters ----------
  // One row per `[params]` value: its name, a slider over its range, a number box (a number
  // or an expression of pi and e, e.g. pi/3) and its unit; the description as the row's
  // title and below it. A change reloads the scene with that value on the server and
  // restarts every panel. Whole parameters step by 1; derived ones are shown, not set.
  const SLIDER_STEPS = 1000;
  // The slider's position k (0..SLIDER_STEPS) and its value: the ends are the range's exact
  // values (pi stays pi), the steps between a thousandth of the range.
  function sliderValue(prm, k) {
    if (prm.integer) return k;
    if (k <= 0) return prm.min;
    if (k >= SLIDER_STEPS) return prm.max;
    return prm.min + (prm.max - prm.min) * (k / SLIDER_STEPS);
  }
  function sliderPosition(prm, v) {
    if (prm.integer) return Math.round(v);
    return Math.round(((v - prm.min) / (prm.max - prm.min)) * SLIDER_STEPS);
  }
  function buildParams(scene) {
    const box = $("params");
    box.innerHTML = "";
    for (const prm of scene.params || []) {
      const row = el("div", "param");
      row.dataset.param = prm.name;
      const unit = prm.unit ? ` ${prm.unit}` : "";
      if (prm.derived != null) {
        row.classList.add("derived");
        row.title = `${prm.name} = ${prm.derived}: follows ${prm.depends_on.join(", ")}` +
          (prm.description ? `\n${prm.description}` : "");
        row.append(el("span", "param-name", prm.name), " = ",
          el("span", "value", fmt(prm.value, 5)), el("span", "unit", unit),
          el("span", "param-expr", ` (= ${prm.derived})`));
        if (prm.description) row.append(el("div", "param-desc", prm.description));
        box.appendChild(row);
        continue;
      }
      row.title = (prm.description ? prm.description + "\n" : "") +
        `${prm.name}: ${fmt(prm.min)} to ${fmt(prm.max)}${unit}` +
        (prm.bounded ? "" : " on the slider; any value can be typed") +
        (prm.integer ? ", whole numbers" : "") +
        "; the scene reloads with the new value and every panel restarts";
      const label = el("label", "param-control");
      const slider = el("input");
      slider.type = "range";
      slider.min = prm.integer ? String(prm.min) : "0";
      slider.max = prm.integer ? String(prm.max) : String(SLIDER_STEPS);
      slider.step = "1";
      slider.value = String(sliderPosition(prm, prm.value));
      slider.setAttribute("aria-label", prm.name);
      const number = el("input", "param-value");
      number.type = "text";
      number.inputMode = "decimal";
      number.size = 9;
      number.value = String(prm.value);
      number.setAttribute("aria-label", `${prm.name} value`);
      slider.oninput = () => { number.value = String(sliderValue(prm, Number(slider.value))); };
      slider.onchange = () => send({ type: "set_param", name: prm.name, value: sliderValue(prm, Number(slider.value)) });
      const submit = () => {
        const text = number.value.trim();
        if (text === "" || text === String(prm.value)) return;
        const v = Number(text);
        send(Number.isFinite(v) ? { type: "set_param", name: prm.name, value: v } :
          { type: "set_param", name: prm.name, expr: text });
      };
      number.addEventListener("keydown", (e) => { if (e.key === "Enter") submit(); });
      number.addEventListener("change", submit);
      label.append(el("span", "param-name", prm.name), " ", slider, " ", number, el("span", "unit", unit));
      row.append(label);
      if (prm.description) row.append(el("div", "param-desc", prm.description));
      box.appendChild(row);
    }
  }
  // For the tests: set parameter `name` to exactly `value` (a number, or an expression
  // string) as typing it in the number box does.
  state.setParam = (name, value) => {
    const number = document.querySelector(`#params .param[data-param="${name}"] .param-value`);
    number.value = String(value);
    number.dispatchEvent(new KeyboardEvent("keydown", { key: "Enter" }));
  };

  // ---------- start state, typed ----------
  // For scenes of a few particles: each particle's position and velocity in number boxes,
  // filled from the first panel while paused (until edited); "Set start" places them on the
  // constraints (the server says how far they moved) and restarts every panel from there.
  const START_FORM_PARTICLES = 4;
  function buildStartForm(scene) {
    const box = $("start-state");
    box.innerHTML = "";
    state.startForm = null;
    if (scene.particles.length > START_FORM_PARTICLES) return;
    const axes = scene.dim === 3 ? ["x", "y", "z"] : ["x", "y"];
    const inputs = { positions: [], velocities: [] };
    box.append(el("span", "start-title", "start (paused):"));
    scene.particles.forEach((particle, k) => {
      const group = el("span", "start-particle");
      group.dataset.particle = String(k);
      group.append(el("span", "param-name", particle.name));
      for (const [key, prefix] of [["positions", ""], ["velocities", "v"]]) {
        axes.forEach((axis) => {
          const input = el("input", "start-value");
          input.type = "text";
          input.inputMode = "decimal";
          input.size = 7;
          input.dataset.kind = key;
          input.setAttribute("aria-label", `${particle.name} ${prefix}${axis}`);
          input.addEventListener("input", () => { state.startForm.edited = true; });
          input.addEventListener("keydown", (e) => { if (e.key === "Enter") submitStart(); });
          inputs[key].push(input);
          group.append(` ${prefix}${axis} `, input);
        });
      }
      box.append(group);
    });
    const button = el("button", "start-set", "Set start");
    button.onclick = submitStart;
    box.append(button);
    state.startForm = { inputs, edited: false };
  }
  function submitStart() {
    const form = state.startForm, first = state.panels.values().next().value;
    if (!form || !first) return;
    const read = (list) => list.map((input) => Number(input.value));
    const positions = read(form.inputs.positions), velocities = read(form.inputs.velocities);
    if (![...positions, ...velocities].every(Number.isFinite)) {
      showMessage("start: every box needs a number");
      return;
    }
    form.edited = false;
    send({ type: "set_start_state", panel: first.info.id, positions, velocities });
  }
  // Fill the form from the first panel's state while it is paused and the form unedited.
  function fillStartForm() {
    const form = state.startForm, first = state.panels.values().next().value;
    if (!form || form.edited || !first || !first.frame || first.frame.status === "running") return;
    const f = first.frame, v = f.arrows ? f.arrows.velocity : null;
    form.inputs.positions.forEach((input, i) => {
      if (document.activeElement !== input) input.value = String(f.x[i]);
    });
    form.inputs.velocities.forEach((input, i) => {
      if (document.activeElement !== input && v) input.value = String(v[i]);
    });
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

  // The equations of motion typeset (MathML, rendered by the browser), and under them, on
  // request, the derived expressions as `bead check` prints them.
  function onEquations(msg) {
    const p = state.panels.get(msg.panel);
    if (!p) return;
    const box = p.dom.equations;
    box.innerHTML = msg.mathml || "";
    const details = el("details", "equations-text");
    details.append(el("summary", null, "as bead check prints them"), el("pre", null, msg.text));
    box.appendChild(details);
    box.hidden = false;
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
          info, frame: null, dom: buildPanel(info), trail: [], history: [], samples: [], dirty: true,
          chartsDirty: true, view: null, box: null, displayT: null,
          // The curves drawn and the x-y region they cover: the panel's, or the last a frame
          // carried; when the page last asked for curves over its view (ms).
          curves: info.curves, curveRegion: info.curve_region, regionAsked: null,
          // What the last draw drew (counts, the frame and its time in ms) and the recent
          // draw times: for the tests.
          lastDraw: null, drawTimes: [],
        };
        state.panels.set(info.id, p);
        $("panels").appendChild(p.dom.root);
      } else {
        // A new epoch: the panel restarted (configured, reset, new curve).
        if (p.info.epoch !== info.epoch) { p.trail = []; p.history = []; p.samples = []; p.displayT = null; }
        // New curves (a curve edit): fit the view to them again.
        if (JSON.stringify(p.info.view) !== JSON.stringify(info.view) && p.view) p.view.auto = true;
        p.info = info;
        p.curves = info.curves;
        p.curveRegion = info.curve_region;
        p.regionAsked = null;
        p.box = null;
        p.dirty = true;
        p.chartsDirty = true;
      }
      p.dom.root.dataset.epoch = String(info.epoch);
      fillConfig(p);
      p.dom.configError.textContent = "";
    }
    if (state.presenting) requestAnimationFrame(fitToWindow);
    keepUrl();
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
    for (const key of ["t", "energy", "erel", "cerr", "contact", "ref", "sps", "status"]) {
      fields[key] = el("span", "r-" + key);
      readout.appendChild(fields[key]);
    }
    const tools = el("div", "view-tools");
    const fitButton = el("button", "fit", "fit");
    fitButton.title = "fit the view to the curves, the particles and the anchors (pan: drag empty space; zoom: wheel)";
    fitButton.onclick = () => { const p = state.panels.get(info.id); if (p) fitView(p); };
    const curveNote = el("span", "curve-note");
    const csvButton = el("button", "export-csv", "CSV");
    csvButton.title = "download this panel's trace since its start: t, positions, velocities, energies, work, errors (one row per frame)";
    csvButton.onclick = () => { const p = state.panels.get(info.id); if (p) exportCsv(p); };
    const pngButton = el("button", "export-png", "PNG");
    pngButton.title = "download this panel's picture as drawn";
    pngButton.onclick = () => { const p = state.panels.get(info.id); if (p) exportPng(p); };
    tools.append(fitButton, csvButton, pngButton, curveNote);
    const bars = el("canvas", "chart chart-bars");
    bars.width = 920; bars.height = 190;
    const energyWhy = el("div", "energy-why");
    const charts = el("div", "charts");
    const chartE = el("canvas", "chart chart-energy");
    const chartC = el("canvas", "chart chart-cerr");
    for (const c of [chartE, chartC]) { c.width = 454; c.height = 240; charts.appendChild(c); }
    const logEnergy = el("input", "log-energy"); logEnergy.type = "checkbox";
    logEnergy.onchange = () => { const p = state.panels.get(info.id); if (p) { p.chartsDirty = true; p.dirty = true; } };
    const logLabel = el("label", "log-energy-label", " log |ΔE|");
    logLabel.prepend(logEnergy);
    // The live plot: any recorded quantity against any other.
    const plotRow = el("div", "plot-choice");
    const plotY = el("select", "plot-y"), plotX = el("select", "plot-x");
    const plotLog = el("input", "plot-log"); plotLog.type = "checkbox";
    const plotLogLabel = el("label", "plot-log-label", " log |y|");
    plotLogLabel.prepend(plotLog);
    plotRow.append("plot ", plotY, " against ", plotX, plotLogLabel);
    plotRow.title = "a live chart of any quantity this panel records (the CSV's columns) against any other, e.g. a phase portrait: velocity against position";
    const plotChanged = () => {
      const p = state.panels.get(info.id);
      if (!p) return;
      p.plot = { x: plotX.value, y: plotY.value, log: plotLog.checked };
      p.chartsDirty = true; p.dirty = true;
    };
    plotX.onchange = plotY.onchange = plotLog.onchange = plotChanged;
    const plot = el("canvas", "chart chart-plot");
    plot.width = 920; plot.height = 360;
    const config = el("div", "config");
    const method = el("select", "method");
    for (const m of state.welcome ? state.welcome.methods : ["implicit", "parametric"]) option(method, m, m);
    const integrator = el("select", "integrator");
    for (const k of state.welcome ? state.welcome.integrators : []) option(integrator, k.name, k.name, k.description);
    const dt = el("input", "dt"); dt.type = "text";
    const ks = el("input", "ks"); ks.type = "text";
    const kd = el("input", "kd"); kd.type = "text";
    const project = el("input", "project"); project.type = "checkbox";
    const reference = el("input", "reference"); reference.type = "checkbox";
    const apply = el("button", "apply", "Apply");
    const playOne = el("button", "play-one", "▶/❚❚");
    playOne.title = "play / pause this panel";
    const showEquations = el("button", "show-equations", "equations");
    showEquations.title = "the equations this formulation derived (as `bead check` prints them)";
    const equations = el("div", "equations");
    equations.hidden = true;
    showEquations.onclick = () => {
      if (!equations.hidden) { equations.hidden = true; return; }
      send({ type: "equations", panel: info.id });
    };
    const labelled = (text, input, cls) => { const l = el("label", cls, text + " "); l.appendChild(input); return l; };
    const ksLabel = labelled("ks", ks, "feedback"), kdLabel = labelled("kd", kd, "feedback");
    const projectLabel = labelled("project", project, "projection");
    const referenceLabel = labelled("reference", reference, "reference-toggle");
    referenceLabel.title = "draw the reference solution as a ghost (dopri5 at rtol 1e-12 from the same start) and chart the distance to it on a log axis";
    config.append(method, integrator, labelled("dt", dt), ksLabel, kdLabel, projectLabel, referenceLabel, apply, playOne, showEquations);
    const configError = el("div", "panel-error error");
    const failure = el("div", "panel-failure error");
    apply.onclick = () => {
      const isImplicit = method.value === "implicit";
      const msg = {
        type: "configure_panel", panel: info.id, method: method.value, integrator: integrator.value,
        dt: Number(dt.value), ks: isImplicit ? Number(ks.value) : 0, kd: isImplicit ? Number(kd.value) : 0,
        project: isImplicit && project.checked, reference: reference.checked,
      };
      for (const k of ["dt", "ks", "kd"]) {
        if (!Number.isFinite(msg[k])) { configError.textContent = `${k} must be a number`; return; }
      }
      send(msg);
    };
    // Switching the integrator applies at once.
    integrator.onchange = () => apply.onclick();
    method.onchange = () => apply.onclick();
    // The ghost applies at once; turning it on charts the distance to it on a log axis.
    reference.onchange = () => {
      const p = state.panels.get(info.id);
      if (p && reference.checked) p.plot = { x: "t", y: "reference_distance", log: true };
      apply.onclick();
    };
    playOne.onclick = () => {
      const p = state.panels.get(info.id);
      const running = p && p.frame && p.frame.status === "running";
      send({ type: running ? "pause" : "play", panel: info.id });
    };
    for (const c of [bars, chartE, chartC, plot]) countCalls(c);
    root.append(title, canvas, tools, note, bars, energyWhy, readout, charts, logLabel, plotRow, plot, config, configError, failure, equations);
    const dom = { root, name, canvas, note, curveNote, fields, bars, energyWhy, chartE, chartC, logEnergy, plotX, plotY, plotLog, plot, method, integrator, dt, ks, kd, project, reference, configError, failure, equations, ksLabel, kdLabel, projectLabel };
    installDrag(info.id, canvas);
    return dom;
  }

  // Count the canvas's painting calls (each stroke, fill, rect or text is one): a draw's cost
  // grows with them, so the tests can check that drawing is batched whatever the scene's size.
  // And keep the box of every text the last draw wrote (a draw starts by filling the whole
  // canvas), so the tests can check that no text is clipped or overlaps another.
  function countCalls(canvas) {
    const ctx = canvas.getContext("2d");
    canvas.paintCalls = 0;
    canvas.texts = [];
    for (const name of ["stroke", "fill", "fillRect", "strokeRect", "fillText", "strokeText"]) {
      const call = ctx[name].bind(ctx);
      ctx[name] = (...args) => { canvas.paintCalls++; return call(...args); };
    }
    const fillRect = ctx.fillRect;
    ctx.fillRect = (x, y, w, h) => {
      if (x <= 0 && y <= 0 && x + w >= canvas.width && y + h >= canvas.height) canvas.texts = [];
      return fillRect(x, y, w, h);
    };
    const fillText = ctx.fillText;
    ctx.fillText = (text, x, y, ...rest) => {
      const m = ctx.measureText(text);
      const left = x - m.actualBoundingBoxLeft, right = x + m.actualBoundingBoxRight;
      const top = y - m.actualBoundingBoxAscent, bottom = y + m.actualBoundingBoxDescent;
      const T = ctx.getTransform();
      const corners = [[left, top], [right, top], [left, bottom], [right, bottom]].map(([u, v]) => [T.a * u + T.c * v + T.e, T.b * u + T.d * v + T.f]);
      const xs = corners.map((c) => c[0]), ys = corners.map((c) => c[1]);
      if (String(text).trim()) canvas.texts.push({ text: String(text), x0: Math.min(...xs), y0: Math.min(...ys), x1: Math.max(...xs), y1: Math.max(...ys) });
      return fillText(text, x, y, ...rest);
    };
  }

  // For the tests: every text the page shows, with its box. Canvases: the texts of their
  // last draw (canvas pixels) with the canvas's size; the page: every visible text node's
  // line boxes (CSS pixels) with the panel it is in, if any.
  state.textLayout = () => {
    for (const p of state.panels.values()) { draw(p, false); drawCharts(p); }
    if (state.overlay.on) { state.overlay.dirty = true; updateOverlay(); }
    const canvases = [];
    for (const c of document.querySelectorAll("canvas")) {
      if (!c.texts || !c.getClientRects().length) continue;
      const panel = c.closest(".panel");
      canvases.push({ name: (panel ? `panel ${panel.dataset.panel} ` : "") + (c.id || c.className), width: c.width, height: c.height, texts: c.texts });
    }
    const nodes = [];
    const walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
    for (let n = walker.nextNode(); n; n = walker.nextNode()) {
      const parent = n.parentElement;
      if (!n.textContent.trim() || !parent || parent.closest("script, style, select, option")) continue;
      const range = document.createRange();
      range.selectNodeContents(n);
      const rects = [...range.getClientRects()].filter((r) => r.width > 0 && r.height > 0);
      if (!rects.length) continue;
      const panel = parent.closest(".panel");
      const box = panel ? panel.getBoundingClientRect() : null;
      nodes.push({
        text: n.textContent.trim().slice(0, 60),
        rects: rects.map((r) => [r.left, r.top, r.right, r.bottom]),
        panel: box ? [box.left, box.top, box.right, box.bottom] : null,
      });
    }
    return { canvases, nodes, width: document.documentElement.clientWidth, scrollWidth: document.documentElement.scrollWidth };
  };

  function fillConfig(p) {
    const { info, dom } = p;
    dom.name.textContent = `#${info.id} ${info.method} · ${info.integrator} · dt ${fmt(info.dt)}` +
      (info.ks || info.kd ? ` · ks ${fmt(info.ks)}, kd ${fmt(info.kd)}` : "") + (info.project ? " · projected" : "") +
      (info.reference ? " · with reference" : "");
    dom.method.value = info.method;
    dom.integrator.value = info.integrator;
    dom.dt.value = String(info.dt);
    dom.ks.value = String(info.ks);
    dom.kd.value = String(info.kd);
    dom.project.checked = info.project;
    dom.reference.checked = !!info.reference;
    // Settings that do nothing for this method and integrator are hidden: the server says
    // which apply, from the library's own legality check.
    const applies = info.applies || { feedback: true, project: true };
    dom.ksLabel.hidden = dom.kdLabel.hidden = !applies.feedback;
    dom.projectLabel.hidden = !applies.project;
    const scene = state.scene;
    const notes = [];
    if (scene && scene.dim === 3) notes.push("3D view: drag empty space to orbit");
    notes.push((info.curve_source === "contour" ? "curve: zero set of C (marching squares)" :
      info.curve_source === "parametric" ? "curve: x(q) sampled" : "no curve drawn") +
      (info.curves_move ? ", drawn at the frame's t (it moves)" : ""));
    if (scene && scene.dim === 2) notes.push(sceneUp(scene)[1] < 0 ? "+y down (gravity +y)" : "+y up");
    notes.push("drag a particle (paused: sets the start state); wheel zooms, drag pans");
    dom.note.textContent = notes.join(" · ");
    dom.curveNote.textContent = info.curve_note || "";
  }

  function onFrame(msg) {
    const scaleChanged = state.timeScale !== msg.time_scale;
    state.timeScale = msg.time_scale;
    if (scaleChanged) keepUrl();
    for (const f of msg.panels) {
      const p = state.panels.get(f.id);
      if (!p) continue;
      // Sent before the panel restarted: nothing of it belongs to the new epoch.
      if (f.epoch < p.info.epoch) continue;
      const previous = p.frame;
      p.frame = f;
      // Curves made again (moving, following the bead or the view) replace the panel's.
      if (f.curves) p.curves = f.curves;
      p.curveRegion = f.curve_region;
      if (previous && f.epoch !== previous.epoch) { p.trail = []; p.history = []; p.samples = []; p.displayT = null; }
      p.dirty = true;
      if (!previous || f.t !== previous.t || f.steps !== previous.steps || f.epoch !== previous.epoch) {
        // The states to interpolate between and to draw trails along: the simulation's steps
        // since the last frame (few particles), then the frame's state.
        const last = p.samples.length ? p.samples[p.samples.length - 1].t : -Infinity;
        const fresh = f.path.filter((s) => s.t > last);
        if (!fresh.length || fresh[fresh.length - 1].t < f.t) fresh.push({ t: f.t, x: f.x });
        if (f.t < last) { p.samples = []; p.trail = []; }
        for (const s of fresh) p.samples.push(s);
        if (p.samples.length > SAMPLES) p.samples.splice(0, p.samples.length - SAMPLES);
        if (trailsOn()) {
          for (const s of fresh) p.trail.push({ t: s.t, x: s.x.slice() });
          const keep = trailLength();
          if (p.trail.length > keep) p.trail.splice(0, p.trail.length - keep);
        } else if (p.trail.length) {
          p.trail = [];
        }
        // The trace the CSV export writes and the live plot draws: one row per new frame of
        // this epoch, one number per quantity.
        if (!p.record || p.record.epoch !== f.epoch) {
          p.record = { epoch: f.epoch, columns: quantityColumns(p, f), rows: [] };
          fillPlotChoices(p);
        }
        if (p.record.rows.length < RECORD_ROWS) p.record.rows.push(p.record.columns.map((c) => c.get(f)));
        // (E - W - E0)/E_scale, signed; W = 0 when nothing does work.
        const signed = f.energy_scale > 0 ? (f.energy - f.work - f.energy_initial) / f.energy_scale : 0;
        p.history.push([f.t, signed, f.constraint_error]);
        if (p.history.length > HISTORY) p.history.shift();
        p.chartsDirty = true;
      } else if (!p.lastBars) {
        p.chartsDirty = true;
      }
      const r = p.dom.fields;
      r.t.textContent = `t = ${fmt(f.t)} s`;
      // What the panel conserves: T + V, or E - W when something does work on the system.
      const reasons = f.not_conserved_by.join("; ");
      const eu = state.scene && state.scene.energy_unit ? " " + state.scene.energy_unit : "";
      r.energy.textContent = f.energy_conserved ? `E = ${fmt(f.energy, 7)}${eu}` :
        `E = ${fmt(f.energy, 7)}${eu}, W = ${fmt(f.work, 5)}${eu}`;
      r.erel.textContent = (f.energy_conserved ? "energy error (relative) " : "error of E − W (relative) ") +
        (f.energy_error === 0 ? "0 (exact)" : fmt(f.energy_error));
      r.erel.title = f.energy_conserved ? "relative energy error, |E - E0| / E_scale with E_scale = max(|E0|, T0 + |V0|, T0 + M g L)" :
        `energy not conserved (${reasons}): the error of E − W, W the work done on the system`;
      r.erel.dataset.value = String(f.energy_error);
      r.cerr.textContent = `|C| = ${f.constraint_error === 0 ? "0 (exact)" : fmt(f.constraint_error)}`;
      r.cerr.dataset.value = String(f.constraint_error);
      // Unilateral constraints: on the track or in flight, and the switches so far.
      if (f.contact) {
        const c = f.contact;
        const count = (n, one, many) => `${n} ${n === 1 ? one : many}`;
        r.contact.textContent = (c.detached.some((d) => d) ? "in flight" : "on the track") +
          ` · ${count(c.bounces, "bounce", "bounces")}, ${count(c.landings, "landing", "landings")}, ${count(c.detaches, "detach", "detaches")}`;
        r.contact.title = "unilateral constraints only push: the particle leaves one where it would have to pull, and lands (or bounces, with the restitution e) where it reaches it again";
        r.contact.hidden = false;
      } else {
        r.contact.textContent = "";
        r.contact.hidden = true;
      }
      // The reference ghost: the panel's distance to the true motion, or why there is none.
      if (f.reference) {
        r.ref.textContent = `distance to the reference: ${f.reference.distance === 0 ? "0 (exact)" : fmt(f.reference.distance)}`;
        r.ref.dataset.value = String(f.reference.distance);
        r.ref.title = "the ghost is the reference solution: dopri5 at rtol 1e-12 from the same start, through the same drags; the distance is the largest over particles";
      } else {
        r.ref.textContent = f.reference_note || "";
        delete r.ref.dataset.value;
      }
      r.sps.textContent = `${fmt(f.steps_per_second, 3)} steps per second of computing`;
      r.sps.title = "how fast this panel computes: integrator steps per second of compute time";
      r.status.textContent = f.status + (f.behind ? " (cannot keep up: holds every panel back)" : "");
      if (f.distance != null) {
        let h = state.overlay.history.get(f.id);
        if (!h || h.epoch !== f.epoch) { h = { epoch: f.epoch, points: [] }; state.overlay.history.set(f.id, h); }
        const last = h.points.length ? h.points[h.points.length - 1][0] : -Infinity;
        if (f.t > last) { h.points.push([f.t, f.distance]); if (h.points.length > HISTORY) h.points.shift(); }
      }
      p.dom.failure.textContent = f.error || "";
    }
    fillStartForm();
    const anyRunning = msg.panels.some((f) => f.status === "running");
    $("play").textContent = anyRunning ? "Pause" : "Play";
    // One clock for all panels: the simulation rate (simulated seconds per wall second) and
    // the panel that holds the others back, if one does.
    const clock = msg.clock || { generation: 0, sim_rate: 0, limited_by: null };
    state.clock = clock;
    // What happens at the scene's end, as the server has it (a page restored or another tab).
    if (clock.at_end && $("at-end").value !== clock.at_end) $("at-end").value = clock.at_end;
    const rate = $("rate");
    rate.textContent = clock.ended ?
      `ended at t = ${fmt(clock.end)} s, the scene's duration: Play starts again` :
      anyRunning ?
      `simulation rate ×${clock.sim_rate.toFixed(2)} real time` + (clock.limited_by != null ?
        ` — all panels slowed to panel #${clock.limited_by}'s pace (it cannot keep up)` : "") :
      "simulation rate: paused";
    rate.classList.toggle("ended", !!clock.ended);
    rate.classList.toggle("limited", clock.limited_by != null);
    rate.dataset.limitedBy = clock.limited_by == null ? "" : String(clock.limited_by);
    state.overlay.dirty = true;
  }

  // ---------- view: camera, fit, pan, zoom, orbit ----------
  // Every panel has its own view: `p.view = { auto, cx, cy, cz, s, yaw, pitch }`, a center in
  // scene coordinates, pixels per unit and (3D) the orbit angles. With `auto` the view fits the
  // panel's box (the server's view box, grown by every particle position since the epoch began,
  // and in 3D the curves); panning or zooming turns `auto` off, the "fit" button back on.
  // Canvas pixels; the canvas is shown at half size, so 26 px text is 13 px on screen.
  const PLOT_MARGIN = { l: 84, r: 14, t: 14, b: 66 };

  // The scene's "up": against gravity. 2D: screen up is -y when gravity points +y (the shipped
  // scenes, y down), else +y. 3D: a unit vector against gravity (z without gravity).
  function sceneUp(scene) {
    const g = scene.gravity || [];
    if (scene.dim === 2) return (g[1] || 0) >= 0 ? [0, -1] : [0, 1];
    const n = Math.hypot(g[0] || 0, g[1] || 0, g[2] || 0);
    return n > 0 ? [-g[0] / n, -g[1] / n, -g[2] / n] : [0, 0, 1];
  }
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + (a.length > 2 ? a[2] * b[2] : 0);
  const unit = (a) => { const n = Math.hypot(...a); return a.map((v) => v / n); };

  // The screen's right and up directions in scene coordinates. 3D: U against gravity, R0 the
  // coordinate axis least along U, F0 = U x R0 (into the screen); yaw turns R0, F0 about U,
  // pitch tilts the line of sight down by `pitch` (looking from above).
  function axes(p) {
    const scene = state.scene;
    if (scene.dim === 2) return { R: [1, 0], S: sceneUp(scene) };
    const U = sceneUp(scene);
    const candidates = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
    candidates.sort((a, b) => Math.abs(dot(a, U)) - Math.abs(dot(b, U)));
    const R0 = unit(candidates[0].map((v, i) => v - dot(candidates[0], U) * U[i]));
    const F0 = cross(U, R0);
    const { yaw, pitch } = p.view;
    const R = R0.map((v, i) => Math.cos(yaw) * v + Math.sin(yaw) * F0[i]);
    const F = F0.map((v, i) => -Math.sin(yaw) * R0[i] + Math.cos(yaw) * v);
    const S = U.map((v, i) => Math.cos(pitch) * v + Math.sin(pitch) * F[i]);
    return { R, S, U };
  }

  function plotRect(c) {
    const m = PLOT_MARGIN;
    return { x0: m.l, y0: m.t, x1: c.width - m.r, y1: c.height - m.b };
  }

  // The panel's box to fit, [min..., max...] over `dim` coordinates.
  function fitBox(p) {
    const scene = state.scene, dim = scene.dim;
    if (!p.box || p.box.epoch !== p.info.epoch || p.box.info !== p.info) {
      const v = p.info.view || scene.view;
      const lo = dim === 2 ? [v[0], v[1]] : [Infinity, Infinity, Infinity];
      const hi = dim === 2 ? [v[2], v[3]] : [-Infinity, -Infinity, -Infinity];
      const grow = (x, o) => {
        for (let a = 0; a < dim; a++) {
          const q = x[o + a];
          if (Number.isFinite(q)) { lo[a] = Math.min(lo[a], q); hi[a] = Math.max(hi[a], q); }
        }
      };
      if (dim === 3) {
        for (const line of p.info.curves) for (let i = 0; i + 2 < line.length; i += 3) grow(line, i);
        for (const q of scene.pins) grow(q.anchor.length < 3 ? [q.anchor[0], q.anchor[1], 0] : q.anchor, 0);
      }
      p.box = { epoch: p.info.epoch, info: p.info, lo, hi, grow, counted: null };
    }
    // Every particle position seen (the box only grows within an epoch: no jitter).
    const f = p.frame;
    if (f && f.epoch === p.info.epoch && p.box.counted !== f) {
      const n = Math.floor(f.x.length / dim);
      for (let k = 0; k < n; k++) p.box.grow(f.x, k * dim);
      p.box.counted = f;
    }
    return p.box;
  }

  // Fit the view to the panel's box (projected in 3D), padded by 8%.
  function fit(p) {
    const c = p.dom.canvas, r = plotRect(c), scene = state.scene, dim = scene.dim;
    const { lo, hi } = fitBox(p);
    if (!lo.every(Number.isFinite)) return;
    const { R, S } = axes(p);
    const center = lo.map((v, a) => 0.5 * (v + hi[a]));
    let w = 0, h = 0;
    const corners = dim === 2 ? 4 : 8;
    for (let k = 0; k < corners; k++) {
      const q = lo.map((v, a) => ((k >> a) & 1 ? hi[a] : v) - center[a]);
      w = Math.max(w, Math.abs(dot(q, R)));
      h = Math.max(h, Math.abs(dot(q, S)));
    }
    w = Math.max(w, 1e-9); h = Math.max(h, 1e-9);
    p.view.s = 0.92 * Math.min((r.x1 - r.x0) / (2 * w), (r.y1 - r.y0) / (2 * h));
    p.view.c = center;
  }

  // The panel's transform: scene point -> canvas pixel, and back (in 3D, in the plane
  // through `ref` facing the screen).
  function transform(p) {
    if (!p.view) p.view = { auto: true, s: 1, c: [0, 0, 0], yaw: -0.6, pitch: 0.35 };
    if (p.view.auto) fit(p);
    const c = p.dom.canvas, r = plotRect(c), { s } = p.view, center = p.view.c;
    const { R, S } = axes(p);
    const ox = 0.5 * (r.x0 + r.x1), oy = 0.5 * (r.y0 + r.y1);
    const dim = state.scene.dim;
    const px = (x, o) => {
      let u = 0;
      for (let a = 0; a < dim; a++) u += (x[o + a] - center[a]) * R[a];
      return ox + s * u;
    };
    const py = (x, o) => {
      let u = 0;
      for (let a = 0; a < dim; a++) u += (x[o + a] - center[a]) * S[a];
      return oy - s * u;
    };
    const unproject = (cx, cy, ref) => {
      const base = ref || center;
      const [bx, by] = [px(base, 0), py(base, 0)];
      return base.map((v, a) => v + ((cx - bx) / s) * R[a] - ((cy - by) / s) * S[a]);
    };
    return { s, r, R, S, px, py, unproject, center, dim };
  }

  function niceTicks(lo, hi, count) {
    const step = niceStep(hi - lo, count), out = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * step; v += step) out.push(Math.abs(v) < 1e-12 * step ? 0 : v);
    return out;
  }

  // 2D: a grid with tick labels in the margins, axis names with the units of the scene, and
  // the up direction. 3D: an axis triad in the corner, the up axis marked.
  function drawAxes(ctx, T, c) {
    ctx.save();
    const r = T.r, scene = state.scene;
    ctx.strokeStyle = "#e6e6e2";
    ctx.fillStyle = "#55555a";
    ctx.lineWidth = 1;
    ctx.font = "26px system-ui, sans-serif";
    if (scene.dim === 2) {
      const down = T.S[1] < 0;
      const xa = T.unproject(r.x0, 0)[0], xb = T.unproject(r.x1, 0)[0];
      const ya = T.unproject(0, r.y0)[1], yb = T.unproject(0, r.y1)[1];
      const [y0, y1] = [Math.min(ya, yb), Math.max(ya, yb)];
      ctx.textAlign = "center";
      ctx.beginPath();
      const xs = niceTicks(xa, xb, 6), ys = niceTicks(y0, y1, 5);
      for (const x of xs) { const px = T.px([x, 0], 0); ctx.moveTo(px, r.y0); ctx.lineTo(px, r.y1); }
      for (const y of ys) { const py = T.py([0, y], 0); ctx.moveTo(r.x0, py); ctx.lineTo(r.x1, py); }
      ctx.stroke();
      for (const x of xs) ctx.fillText(fmt(x, 3), T.px([x, 0], 0), r.y1 + 28);
      ctx.textAlign = "right";
      for (const y of ys) ctx.fillText(fmt(y, 3), r.x0 - 6, T.py([0, y], 0) + 9);
      ctx.strokeStyle = "#9a9a96";
      ctx.beginPath();
      if (xa <= 0 && xb >= 0) { const px = T.px([0, 0], 0); ctx.moveTo(px, r.y0); ctx.lineTo(px, r.y1); }
      if (y0 <= 0 && y1 >= 0) { const py = T.py([0, 0], 0); ctx.moveTo(r.x0, py); ctx.lineTo(r.x1, py); }
      ctx.stroke();
      ctx.font = "24px system-ui, sans-serif";
      ctx.textAlign = "right";
      ctx.fillText("x →", r.x1, c.height - 6);
      ctx.textAlign = "left";
      ctx.fillText(down ? "y ↓ (gravity +y)" : "y ↑", 4, c.height - 6);
    } else {
      const names = ["x", "y", "z"], L = 42, ox = r.x0 + 50, oy = r.y1 - 50;
      ctx.lineWidth = 3;
      ctx.font = "26px system-ui, sans-serif";
      const U = sceneUp(scene);
      for (let a = 0; a < 3; a++) {
        const e = [0, 0, 0]; e[a] = 1;
        const dx = L * dot(e, T.R), dy = -L * dot(e, T.S);
        ctx.strokeStyle = ["#c0392b", "#27ae60", "#2e6fd8"][a];
        ctx.beginPath(); ctx.moveTo(ox, oy); ctx.lineTo(ox + dx, oy + dy); ctx.stroke();
        ctx.fillStyle = ctx.strokeStyle;
        const up = Math.abs(U[a]) > 0.99 ? (U[a] > 0 ? " up" : " down") : "";
        ctx.fillText(names[a] + up, ox + 1.25 * dx - 6, oy + 1.25 * dy + 6);
      }
      ctx.fillStyle = "#55555a";
      ctx.font = "24px system-ui, sans-serif";
      ctx.textAlign = "right";
      ctx.fillText("orthographic; drag to orbit", r.x1, c.height - 8);
    }
    ctx.strokeStyle = "#d8d8d4";
    ctx.strokeRect(r.x0, r.y0, r.x1 - r.x0, r.y1 - r.y0);
    ctx.restore();
  }

  // The positions to draw: the state at the panel's display time, interpolated between the
  // two samples (path of steps and frames) around it; the newest state when none brackets it.
  function drawnPositions(p) {
    const f = p.frame, samples = p.samples;
    if (!samples || samples.length < 2 || p.displayT == null) return f.x;
    const t = p.displayT;
    let k = samples.length - 1;
    if (t >= samples[k].t) return samples[k].x;
    while (k > 0 && samples[k - 1].t > t) k--;
    if (k === 0) return samples[0].x;
    const a = samples[k - 1], b = samples[k];
    const u = (t - a.t) / (b.t - a.t);
    if (!(u >= 0 && u <= 1) || a.x.length !== b.x.length) return b.x;
    if (!p.lerp || p.lerp.length !== a.x.length) p.lerp = new Float64Array(a.x.length);
    for (let i = 0; i < a.x.length; i++) p.lerp[i] = a.x[i] + u * (b.x[i] - a.x[i]);
    return p.lerp;
  }

  // One colour per particle (trails and markers), for scenes with few particles.
  const PARTICLE_COLORS = ["#e67814", "#7b3fc4", "#1a9c6b", "#d6336c", "#0c7bb3", "#8c6d1f"];

  // 2D: the curves cover the panel's `curveRegion` (contours padded by 10% a side). When the
  // canvas shows more than that (a pan, a zoom out, the view growing with the motion), or
  // less than a quarter of it (a zoom in: too coarse), ask for curves over what it shows
  // padded by a quarter a side, so that a small pan does not ask again; at most every 250 ms.
  function followView(p, T) {
    const c = p.curveRegion;
    if (state.scene.dim !== 2 || !c || p.info.curve_source === "none") return;
    const r = T.r;
    const a = T.unproject(r.x0, r.y0), b = T.unproject(r.x1, r.y1);
    const shown = [Math.min(a[0], b[0]), Math.min(a[1], b[1]), Math.max(a[0], b[0]), Math.max(a[1], b[1])];
    if (!shown.every(Number.isFinite)) return;
    const w = c[2] - c[0], h = c[3] - c[1];
    const sw = shown[2] - shown[0], sh = shown[3] - shown[1];
    const inside = shown[0] >= c[0] - 0.1 * w && shown[1] >= c[1] - 0.1 * h &&
      shown[2] <= c[2] + 0.1 * w && shown[3] <= c[3] + 0.1 * h;
    if (inside && Math.max(sw / w, sh / h) >= 0.25) return;
    const now = performance.now();
    if (p.regionAsked && now - p.regionAsked < 250) return;
    p.regionAsked = now;
    const view = [shown[0] - 0.25 * sw, shown[1] - 0.25 * sh, shown[2] + 0.25 * sw, shown[3] + 0.25 * sh];
    send({ type: "set_view", panel: p.info.id, view });
  }

  const STOPPED = "stopped: see the message below";
  const NOTE_FONT = "22px system-ui, sans-serif";
  function drawPanel(p) {
    const c = p.dom.canvas, ctx = c.getContext("2d");
    const scene = state.scene;
    ctx.fillStyle = "#ffffff";
    ctx.fillRect(0, 0, c.width, c.height);
    if (!scene) return null;
    const T = transform(p);
    const r = T.r;
    drawAxes(ctx, T, c);
    const dim = scene.dim;
    ctx.save();
    ctx.beginPath();
    ctx.rect(r.x0, r.y0, r.x1 - r.x0, r.y1 - r.y0);
    ctx.clip();
    // Curves: one path (marching squares make hundreds of short pieces). The last the server
    // sent: the panel's, or a frame's (moving curves at its t, or made again to follow the
    // bead or the view).
    followView(p, T);
    const f = p.frame;
    const curves = p.curves || p.info.curves;
    ctx.save();
    ctx.strokeStyle = "#1f6feb";
    ctx.lineWidth = 2.5;
    ctx.lineCap = "round";
    ctx.lineJoin = "round";
    ctx.beginPath();
    for (const line of curves) {
      for (let i = 0; i + dim - 1 < line.length; i += dim) {
        const px = T.px(line, i), py = T.py(line, i);
        if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
      }
    }
    ctx.stroke();
    ctx.restore();
    p.drawnCurves = curves;
    if (!f) { ctx.restore(); return null; }
    const x = drawnPositions(p);
    const n = Math.min(scene.particles.length, Math.floor(x.length / dim));
    const X = (k) => T.px(x, k * dim), Y = (k) => T.py(x, k * dim);
    const failed = f.status === "failed";
    const { pairs, anchored, pins } = scene.draw;
    const size = sizes(p, T, f, n, dim);
    // Trails: the simulation's own steps (the path of each frame), up to the drawn state;
    // one colour per particle for few particles, one path per band of age (8 shades).
    const trail = p.trail;
    let trailEnd = trail.length;
    while (trailEnd > 0 && trail[trailEnd - 1].t > (p.displayT == null ? Infinity : p.displayT)) trailEnd--;
    if (trailEnd > 1) {
      ctx.save();
      ctx.lineWidth = size.trail;
      ctx.lineCap = "round";
      ctx.lineJoin = "round";
      const len = trailEnd, bands = Math.min(8, len - 1);
      const colored = n <= PARTICLE_COLORS.length;
      const groups = colored ? n : 1;
      for (let g = 0; g < groups; g++) {
        const color = colored ? PARTICLE_COLORS[g] : "#f06e00";
        for (let band = 0; band < bands; band++) {
          const i0 = 1 + Math.floor((band * (len - 1)) / bands);
          const i1 = 1 + Math.floor(((band + 1) * (len - 1)) / bands);
          ctx.strokeStyle = color;
          ctx.globalAlpha = (i1 / len) * 0.7;
          ctx.beginPath();
          for (let k = colored ? g : 0; k < (colored ? g + 1 : n); k++) {
            const a = trail[i0 - 1].x;
            ctx.moveTo(T.px(a, k * dim), T.py(a, k * dim));
            for (let i = i0; i < i1; i++) ctx.lineTo(T.px(trail[i].x, k * dim), T.py(trail[i].x, k * dim));
            if (i1 === len) ctx.lineTo(X(k), Y(k));
          }
          ctx.stroke();
        }
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
    const anchorPoint = (q) => (dim === 3 && q.length < 3 ? [q[0], q[1], 0] : q);
    for (const rod of anchored) {
      if (rod.a >= n) continue;
      const q = anchorPoint(rod.anchor);
      ctx.moveTo(X(rod.a), Y(rod.a));
      ctx.lineTo(T.px(q, 0), T.py(q, 0));
      rods++;
    }
    ctx.stroke();
    // Anchors and pins: squares at the fixed points.
    ctx.beginPath();
    for (const rod of anchored) {
      const q = anchorPoint(rod.anchor);
      ctx.rect(T.px(q, 0) - 6, T.py(q, 0) - 6, 12, 12);
    }
    const pin = Math.max(10, 2 * size.radius + 6);
    for (const q of pins) {
      const a = anchorPoint(q.anchor);
      ctx.rect(T.px(a, 0) - pin / 2, T.py(a, 0) - pin / 2, pin, pin);
    }
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
      ctx.lineTo(T.px(f.drag.target, 0), T.py(f.drag.target, 0));
      ctx.stroke();
      ctx.restore();
    }
    // A particle being placed while paused: where the new start state puts it.
    if (p.placing) {
      const q = p.placing.target;
      ctx.save();
      ctx.strokeStyle = "#1f6feb";
      ctx.setLineDash([6, 5]);
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.moveTo(X(p.placing.particle), Y(p.placing.particle));
      ctx.lineTo(T.px(q, 0), T.py(q, 0));
      ctx.stroke();
      ctx.setLineDash([]);
      ctx.lineWidth = 3;
      ctx.beginPath();
      ctx.arc(T.px(q, 0), T.py(q, 0), size.radius + 3, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.restore();
    }
    // A velocity arrow being dragged while paused: the new start velocity.
    if (p.aiming) {
      ctx.save();
      ctx.strokeStyle = "#1a7f37";
      ctx.setLineDash([8, 6]);
      ctx.lineWidth = 4;
      ctx.beginPath();
      ctx.moveTo(p.aiming.from[0], p.aiming.from[1]);
      ctx.lineTo(p.aiming.to[0], p.aiming.to[1]);
      ctx.stroke();
      ctx.restore();
    }
    // The reference solution, when the panel runs one: a faint ghost of each particle under
    // it (the frame's state: the reference stands at the frame's t).
    p.lastGhost = null;
    if (f.reference && f.reference.x.length === f.x.length) {
      const g = f.reference.x, gr = size.radius + 4;
      ctx.save();
      ctx.fillStyle = "rgba(90, 90, 90, 0.25)";
      ctx.strokeStyle = "rgba(60, 60, 60, 0.65)";
      ctx.setLineDash([3, 3]);
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      for (let k = 0; k < n; k++) {
        const px = T.px(g, k * dim), py = T.py(g, k * dim);
        ctx.moveTo(px + gr, py);
        ctx.arc(px, py, gr, 0, 2 * Math.PI);
      }
      ctx.fill();
      ctx.stroke();
      ctx.restore();
      p.lastGhost = { particles: n, x0: T.px(g, 0), y0: T.py(g, 0) };
    }
    // Particles: one path; circles with an outline when they are big enough to show one,
    // squares (far cheaper to fill) when they are a few pixels.
    ctx.save();
    ctx.fillStyle = failed ? "#b42318" : "#e67814";
    ctx.beginPath();
    const rad = size.radius;
    if (rad >= 3) {
      for (let k = 0; k < n; k++) {
        const px = X(k), py = Y(k);
        ctx.moveTo(px + rad, py);
        ctx.arc(px, py, rad, 0, 2 * Math.PI);
      }
    } else {
      for (let k = 0; k < n; k++) ctx.rect(X(k) - rad, Y(k) - rad, 2 * rad, 2 * rad);
    }
    ctx.fill();
    if (rad >= 5) {
      ctx.lineWidth = 2;
      ctx.strokeStyle = "#222";
      ctx.stroke();
    }
    ctx.restore();
    const clock = clockLayout(ctx, T, f, n <= 64 ? Array.from({ length: n }, (_, k) => [T.px(x, k * dim), T.py(x, k * dim)]) : []);
    // Particles outside the plot: a triangle at the edge pointing at each (the first 50).
    const markers = [];
    let offView = 0;
    const cx = 0.5 * (r.x0 + r.x1), cy = 0.5 * (r.y0 + r.y1);
    for (let k = 0; k < n; k++) {
      const px = X(k), py = Y(k);
      if (px >= r.x0 && px <= r.x1 && py >= r.y0 && py <= r.y1) continue;
      offView++;
      if (markers.length >= 50 || !Number.isFinite(px) || !Number.isFinite(py)) continue;
      const dx = px - cx, dy = py - cy;
      const scale = Math.min((r.x1 - r.x0 - 24) / 2 / Math.abs(dx || 1e-9), (r.y1 - r.y0 - 24) / 2 / Math.abs(dy || 1e-9));
      markers.push({ particle: k, x: cx + dx * scale, y: cy + dy * scale, angle: Math.atan2(dy, dx) });
    }
    // Notes on the plot, stacked up from its bottom left on white: clear of the clock (at
    // the top) and of the arrow labels, which avoid them.
    const notes = [];
    if (failed) notes.push({ text: STOPPED, color: "rgba(180, 35, 24, 0.95)" });
    if (markers.length) notes.push({ text: `${offView} off view — press fit`, color: "#b42318" });
    ctx.save();
    ctx.font = NOTE_FONT;
    let bottom = r.y1 - 4;
    for (const note of notes) {
      const w = ctx.measureText(note.text).width;
      note.box = { x0: r.x0 + 4, y0: bottom - 32, x1: r.x0 + 16 + w, y1: bottom };
      bottom -= 34;
    }
    ctx.restore();
    p.lastArrows = drawArrows(ctx, p, T, f, x, n, dim, [clock.box, ...notes.map((note) => note.box)]);
    p.lastClock = drawClock(ctx, clock);
    ctx.restore(); // the clip
    if (markers.length) {
      ctx.save();
      ctx.fillStyle = "#b42318";
      ctx.beginPath();
      for (const m of markers) {
        const a = m.angle, s = 13;
        ctx.moveTo(m.x + s * Math.cos(a), m.y + s * Math.sin(a));
        ctx.lineTo(m.x + s * Math.cos(a + 2.4), m.y + s * Math.sin(a + 2.4));
        ctx.lineTo(m.x + s * Math.cos(a - 2.4), m.y + s * Math.sin(a - 2.4));
        ctx.closePath();
      }
      ctx.fill();
      ctx.restore();
    }
    ctx.save();
    ctx.font = NOTE_FONT;
    ctx.textAlign = "left";
    for (const { text, color, box: b } of notes) {
      ctx.fillStyle = "rgba(255, 255, 255, 0.85)";
      ctx.fillRect(b.x0, b.y0, b.x1 - b.x0, b.y1 - b.y0);
      ctx.fillStyle = color;
      ctx.fillText(text, b.x0 + 6, b.y1 - 9);
    }
    ctx.restore();
    return { rods, particles: n, pins: pins.length, frame: f, x, markers, offView, t: p.displayT, ghost: p.lastGhost };
  }

  // ---------- quantities: what a panel records, exports and plots ----------
  // One column per quantity a frame gives, fixed for an epoch from its first frame: t, the
  // positions, the velocities and every constraint row's multiplier lambda (frames of small
  // scenes carry them with the arrows), the energies and errors, and a parametric panel's
  // q and q'. `key` is the CSV header and the share URL's word, `label` what the page says.
  function quantityColumns(p, f) {
    const scene = state.scene, dim = scene.dim, axes = ["x", "y", "z"].slice(0, dim);
    const L = scene.length_unit || "", E = scene.energy_unit || "";
    const columns = [{ key: "t", label: "time t", unit: "s", get: (g) => g.t }];
    scene.particles.forEach((part, k) => axes.forEach((a, i) => columns.push({
      key: `${part.name}.${a}`, label: `${part.name} position ${a}`, unit: L, get: (g) => g.x[k * dim + i],
    })));
    if (f.arrows) {
      scene.particles.forEach((part, k) => axes.forEach((a, i) => columns.push({
        key: `${part.name}.v${a}`, label: `${part.name} velocity v${a}`, unit: L ? L + "/s" : "",
        get: (g) => (g.arrows ? g.arrows.velocity[k * dim + i] : NaN),
      })));
    }
    columns.push(
      { key: "kinetic", label: "kinetic energy T", unit: E, get: (g) => g.kinetic },
      { key: "potential", label: "potential energy V", unit: E, get: (g) => g.potential },
      { key: "energy", label: "energy E = T + V", unit: E, get: (g) => g.energy },
      { key: "work", label: "work W done on the system", unit: E, get: (g) => g.work },
      { key: "energy_error", label: "energy error (relative)", unit: "", get: (g) => g.energy_error },
      { key: "constraint_error", label: "constraint error max |C|", unit: "", get: (g) => g.constraint_error });
    if (f.reference) {
      columns.push({
        key: "reference_distance", label: "distance to the reference", unit: L,
        get: (g) => (g.reference ? g.reference.distance : NaN),
      });
    }
    const names = p.info.coordinates || [];
    if (names.length && f.generalized && f.generalized.length === 2 * names.length) {
      names.forEach((q, i) => columns.push({
        key: q, label: `coordinate ${q}`, unit: "", get: (g) => (g.generalized ? g.generalized[i] : NaN),
      }));
      names.forEach((q, i) => columns.push({
        key: q + "'", label: `rate ${q}' = d${q}/dt`, unit: "", get: (g) => (g.generalized ? g.generalized[names.length + i] : NaN),
      }));
    }
    if (f.arrows) {
      for (const r of f.arrows.rows) {
        columns.push({
          key: `lambda${r.row}`, label: `multiplier λ of constraint row ${r.row}`, unit: "",
          get: (g) => { const row = g.arrows && g.arrows.rows.find((x) => x.row === r.row); return row ? row.lambda : NaN; },
        });
      }
    }
    return columns;
  }
  const withUnit = (c) => (c.unit ? `${c.label} (${c.unit})` : c.label);

  // ---------- the live plot: any quantity against any other ----------
  // Per panel, and in overlay mode for every panel in its colour. The choice of each is
  // `{ x, y, log }` by column key; the default is the first coordinate against time.
  const PLOT_POINTS = 4000; // the newest rows drawn per series
  function defaultPlot(columns) {
    const second = columns.length > 1 ? columns[1].key : "t";
    return { x: "t", y: second, log: false };
  }
  // The selects offer the columns; a choice that is still there is kept.
  function fillPlotChoices(p) {
    const columns = p.record.columns;
    const fallback = defaultPlot(columns);
    if (!p.plot) p.plot = fallback;
    fillSelect(p.dom.plotX, columns, p.plot.x, fallback.x);
    fillSelect(p.dom.plotY, columns, p.plot.y, fallback.y);
    p.plot.x = p.dom.plotX.value; p.plot.y = p.dom.plotY.value;
    fillOverlayChoices();
  }
  function fillSelect(select, columns, chosen, fallback) {
    const keys = columns.map((c) => c.key);
    if (select.dataset.keys !== keys.join("\n")) {
      select.innerHTML = "";
      for (const c of columns) option(select, c.key, withUnit(c));
      select.dataset.keys = keys.join("\n");
    }
    select.value = keys.includes(chosen) ? chosen : keys.includes(fallback) ? fallback : keys[0];
  }
  function fillOverlayChoices() {
    const ov = state.overlay;
    const union = [];
    for (const p of state.panels.values()) {
      for (const c of (p.record ? p.record.columns : [])) if (!union.some((u) => u.key === c.key)) union.push(c);
    }
    if (!union.length) return;
    const fallback = defaultPlot(union);
    if (!ov.plot) ov.plot = fallback;
    fillSelect($("overlay-plot-x"), union, ov.plot.x, fallback.x);
    fillSelect($("overlay-plot-y"), union, ov.plot.y, fallback.y);
    ov.plot.x = $("overlay-plot-x").value; ov.plot.y = $("overlay-plot-y").value;
    $("overlay-plot-log").checked = !!ov.plot.log;
  }
  // The points (x, y) of a panel's record for a choice; none when the panel lacks a column.
  function plotPoints(p, choice) {
    if (!p.record) return null;
    const cols = p.record.columns;
    const i = cols.findIndex((c) => c.key === choice.x), j = cols.findIndex((c) => c.key === choice.y);
    if (i < 0 || j < 0) return null;
    const rows = p.record.rows;
    const out = [];
    for (let k = Math.max(0, rows.length - PLOT_POINTS); k < rows.length; k++) out.push([rows[k][i], rows[k][j]]);
    return { points: out, x: cols[i], y: cols[j] };
  }
  function drawPanelPlot(p) {
    const got = p.plot && plotPoints(p, p.plot);
    if (!got) return null;
    return drawXY(p.dom.plot, {
      xLabel: withUnit(got.x), yLabel: withUnit(got.y),
      log: p.plot.log, series: [{ color: "#1f6feb", points: got.points }],
    });
  }
  function drawOverlayPlot() {
    const ov = state.overlay;
    if (!ov.plot) return null;
    const series = [];
    let x = null, y = null;
    const missing = [];
    [...state.panels.values()].forEach((p, k) => {
      const got = plotPoints(p, ov.plot);
      if (!got) { missing.push(`#${p.info.id}`); return; }
      x = got.x; y = got.y;
      series.push({ color: PANEL_COLORS[k % PANEL_COLORS.length], points: got.points, panel: p.info.id });
    });
    if (!x) return null;
    const drawn = drawXY($("overlay-plot"), {
      xLabel: withUnit(x) + (missing.length ? ` · not in panel ${missing.join(", ")}` : ""), yLabel: withUnit(y), log: ov.plot.log, series,
    });
    ov.lastPlot = drawn;
    return drawn;
  }

  // A chart of y against x: ticks and labels on both axes in one number format, the axes'
  // names with their units; `log`: log10 |y| (exact zeros are counted, not drawn). Returns
  // the data ranges and the pixel mapping (for the tests).
  function drawXY(canvas, options) {
    const { xLabel, yLabel, log, series } = options;
    const ctx = canvas.getContext("2d");
    const W = canvas.width, H = canvas.height;
    // The title names the vertical axis; the horizontal one is named under its ticks.
    chartFrame(ctx, W, H, log ? `log |${yLabel}|` : yLabel);
    const finite = (q) => Number.isFinite(q[0]) && Number.isFinite(q[1]) && (!log || q[1] !== 0);
    const all = series.flatMap((sr) => sr.points.filter(finite));
    const zeros = log ? series.reduce((n, sr) => n + sr.points.filter((q) => q[1] === 0).length, 0) : 0;
    const R = 16, Tp = 50, B = 92;
    let L = 130;
    if (!all.length) {
      ctx.textAlign = "center";
      ctx.fillStyle = "#55555a";
      ctx.fillText(zeros ? "0 (exact) at every point: nothing on a log axis" : "no data yet", W / 2, H / 2);
      return { points: 0 };
    }
    const ys = all.map((q) => (log ? Math.log10(Math.abs(q[1])) : q[1]));
    let x0 = Math.min(...all.map((q) => q[0])), x1 = Math.max(...all.map((q) => q[0]));
    let y0 = Math.min(...ys), y1 = Math.max(...ys);
    const pad = (a, b) => (b > a ? [a - 0.05 * (b - a), b + 0.05 * (b - a)] : [a - (Math.abs(a) || 1) * 0.5, a + (Math.abs(a) || 1) * 0.5]);
    [x0, x1] = pad(x0, x1);
    if (log) { y0 = Math.floor(y0); y1 = Math.max(Math.ceil(y1), y0 + 1); } else [y0, y1] = pad(y0, y1);
    const px = (v) => L + ((v - x0) / (x1 - x0)) * (W - L - R);
    const py = (v) => Tp + (1 - (v - y0) / (y1 - y0)) * (H - Tp - B);
    ctx.strokeStyle = "#e6e6e2";
    ctx.fillStyle = "#55555a";
    ctx.lineWidth = 1;
    const yTicks = log ? logTicks(y0, y1) : niceTicks(y0, y1, 4);
    const yText = (v) => (log ? "1e" + v : fmt(v, 3));
    // The left margin fits the widest value label.
    L = Math.max(L, 24 + Math.max(...yTicks.map((v) => ctx.measureText(yText(v)).width)));
    const xTicks = niceTicks(x0, x1, Math.max(2, Math.floor((W - L - R) / 160)));
    ctx.beginPath();
    for (const v of xTicks) { ctx.moveTo(px(v), Tp); ctx.lineTo(px(v), H - B + 8); }
    for (const v of yTicks) { ctx.moveTo(L - 8, py(v)); ctx.lineTo(W - R, py(v)); }
    ctx.stroke();
    ctx.textAlign = "center";
    for (const v of xTicks) {
      const text = fmt(v, 3), half = ctx.measureText(text).width / 2 + 2;
      ctx.fillText(text, Math.min(W - half, Math.max(half, px(v))), H - B + 36);
    }
    ctx.textAlign = "right";
    for (const v of yTicks) ctx.fillText(yText(v), L - 12, py(v) + 9);
    ctx.strokeStyle = "#9a9a96";
    ctx.strokeRect(L, Tp, W - L - R, H - Tp - B);
    ctx.textAlign = "center";
    ctx.fillStyle = "#3a3a3f";
    ctx.fillText(fitted(ctx, xLabel + (zeros ? ` · ${zeros} exact 0s not drawn` : ""), W - 12), W / 2, H - 12);
    ctx.save();
    ctx.beginPath(); ctx.rect(L, Tp, W - L - R, H - Tp - B); ctx.clip();
    ctx.lineWidth = 3;
    for (const sr of series) {
      ctx.strokeStyle = sr.color;
      ctx.beginPath();
      let pen = false;
      for (const q of sr.points) {
        if (!finite(q)) { pen = false; continue; }
        const X = px(q[0]), Y = py(log ? Math.log10(Math.abs(q[1])) : q[1]);
        if (pen) ctx.lineTo(X, Y); else ctx.moveTo(X, Y);
        pen = true;
      }
      ctx.stroke();
      // The newest point, marked: where the motion is now.
      const last = sr.points.filter(finite).pop();
      if (last) {
        ctx.fillStyle = sr.color;
        ctx.beginPath(); ctx.arc(px(last[0]), py(log ? Math.log10(Math.abs(last[1])) : last[1]), 6, 0, 2 * Math.PI); ctx.fill();
      }
    }
    ctx.restore();
    return {
      points: all.length, x: [x0, x1], y: [y0, y1], plot: { x0: L, x1: W - R, y0: Tp, y1: H - B },
      data: { x: [Math.min(...all.map((q) => q[0])), Math.max(...all.map((q) => q[0]))], y: [Math.min(...all.map((q) => q[1])), Math.max(...all.map((q) => q[1]))] },
      last: series.map((sr) => sr.points.filter(finite).pop() || null),
    };
  }
  // Decades from lo to hi (log10 values), at most 6 labels.
  function logTicks(lo, hi) {
    const step = Math.max(1, Math.ceil((hi - lo) / 5)), out = [];
    for (let d = Math.ceil(lo); d <= hi; d += step) out.push(d);
    return out;
  }
  // For the tests: a panel's plot choice, and the overlay's.
  state.setPlot = (id, choice) => {
    const p = state.panels.get(id);
    p.plot = Object.assign(p.plot || {}, choice);
    fillPlotChoices(p);
    p.chartsDirty = true; p.dirty = true;
    keepUrl();
  };
  state.setOverlayPlot = (choice) => {
    state.overlay.plot = Object.assign(state.overlay.plot || {}, choice);
    fillOverlayChoices();
    state.overlay.dirty = true;
  };

  // ---------- export: the panel's trace (CSV) and picture (PNG) ----------
  // The CSV holds one row per frame the page received in the panel's epoch (at most
  // RECORD_ROWS), each number as JSON wrote it (the server's bits); velocities for scenes
  // small enough to send them. The PNG is the panel's canvas as drawn.
  const RECORD_ROWS = 200000;
  function panelCsv(p) {
    const scene = state.scene;
    const rows = p.record ? p.record.rows : [];
    const header = p.record ? p.record.columns.map((c) => c.key) : ["t"];
    const lines = [`# ${scene.title} (${scene.name}); panel #${p.info.id} ${p.info.method} ${p.info.integrator} dt ${p.info.dt}; ` +
      scene.params.map((prm) => `${prm.name} = ${prm.value}`).join(", "), header.join(",")];
    for (const row of rows) lines.push(row.map(String).join(","));
    return lines.join("\n") + "\n";
  }
  function download(name, href) {
    const a = document.createElement("a");
    a.href = href;
    a.download = name;
    document.body.appendChild(a);
    a.click();
    a.remove();
  }
  function exportCsv(p) {
    const text = panelCsv(p);
    const url = URL.createObjectURL(new Blob([text], { type: "text/csv" }));
    download(`${state.scene.name}-panel${p.info.id}-${p.info.method}.csv`, url);
    setTimeout(() => URL.revokeObjectURL(url), 10000);
    return text;
  }
  function exportPng(p) {
    draw(p, false);
    const url = p.dom.canvas.toDataURL("image/png");
    download(`${state.scene.name}-panel${p.info.id}-${p.info.method}.png`, url);
    return url;
  }
  // For the tests: what the export buttons write.
  state.panelCsv = (id) => panelCsv(state.panels.get(id));
  state.panelPng = (id) => { const p = state.panels.get(id); draw(p, false); return p.dom.canvas.toDataURL("image/png"); };

  // ---------- the clock and readouts on the canvas ----------
  // Large, at the plot's top right, readable from the back of a room: t, then the error of
  // what the panel conserves and |C|. Returns the text's box (canvas pixels) for the tests.
  // At the plot's top right, or its top left when a particle is under the right corner.
  function clockLayout(ctx, T, f, points) {
    const r = T.r;
    const lines = [
      { text: `t = ${f.t.toFixed(2)} s`, font: "600 44px system-ui, sans-serif", height: 46 },
      { text: (f.energy_conserved ? "energy error " : "error of E − W ") + (f.energy_error === 0 ? "0" : fmt(f.energy_error, 2)), font: "26px system-ui, sans-serif", height: 30 },
    ];
    if (f.constraint_error > 0 || state.scene.constraints.length) {
      lines.push({ text: `|C| ${f.constraint_error === 0 ? "0 (exact)" : fmt(f.constraint_error, 2)}`, font: "26px system-ui, sans-serif", height: 30 });
    }
    ctx.save();
    let width = 0;
    for (const line of lines) {
      ctx.font = line.font;
      width = Math.max(width, ctx.measureText(line.text).width);
    }
    ctx.restore();
    const height = lines.reduce((h, l) => h + l.height, 0);
    const under = (b) => points.some(([px, py]) => px > b.x0 - 16 && px < b.x1 + 16 && py > b.y0 - 16 && py < b.y1 + 16);
    let right = r.x1 - 12;
    let box = { x0: right - width - 8, y0: r.y0 + 4, x1: right + 8, y1: r.y0 + 12 + height };
    if (under(box)) {
      const left = { x0: r.x0 + 4, y0: box.y0, x1: r.x0 + 20 + width, y1: box.y1 };
      if (!under(left)) { box = left; right = r.x0 + 12 + width; }
    }
    return { lines, width, height, box, right, top: r.y0 + 8 };
  }
  function drawClock(ctx, clock) {
    const { lines, width, height, right, top } = clock;
    ctx.save();
    ctx.textAlign = "right";
    ctx.textBaseline = "top";
    ctx.fillStyle = "rgba(255, 255, 255, 0.8)";
    ctx.fillRect(right - width - 8, top - 4, width + 16, height + 8);
    ctx.fillStyle = "#1d1d1f";
    let y = top;
    for (const line of lines) {
      ctx.font = line.font;
      ctx.fillText(line.text, right, y);
      y += line.height;
    }
    ctx.restore();
    return { x0: right - width, y0: top, x1: right, y1: top + height, text: lines.map((l) => l.text) };
  }


  // ---------- arrows: velocity and forces ----------
  // At each particle, from the frame's state (the server's numbers): the velocity v, the
  // weight m g, the scene's other forces F and the constraint force, per implicit row
  // lambda_i grad C_i, in the parametric form the map's reaction F_c. Forces share one scale
  // (the frame's force_ref, a typical force of the scene, is 12% of the view box's larger
  // side), velocities another (speed_ref is 25%): lengths compare within an epoch.
  const ARROW_KINDS = [
    { key: "velocity", color: "#1a7f37", label: "v" },
    { key: "gravity", color: "#57606a", label: "mg" },
    { key: "applied", color: "#8250df", label: "F" },
    { key: "constraint", color: "#cf222e", label: "λ∇C" },
  ];
  const ARROW_FRACTION = { force: 0.12, velocity: 0.25 };
  function arrowOn(key) { const box = $("arrow-" + key); return !!(box && box.checked); }
  // Scene units per unit of velocity and of force.
  function arrowScales(p, a) {
    const v = p.info.view || state.scene.view;
    const extent = Math.max(v[2] - v[0], v[3] - v[1]);
    return {
      velocity: ARROW_FRACTION.velocity * extent / a.speed_ref,
      force: ARROW_FRACTION.force * extent / a.force_ref,
    };
  }
  // `avoid`: boxes the labels must stay clear of (the clock).
  function drawArrows(ctx, p, T, f, x, n, dim, avoid) {
    const a = f.arrows;
    if (!a || !ARROW_KINDS.some((k) => arrowOn(k.key))) return [];
    const scales = arrowScales(p, a);
    const list = [];
    // `faint`: a row's share of a particle that several rows act on (drawn thin, no label;
    // their sum, the particle's constraint force, is drawn in full).
    const add = (kind, k, vec, o, scale, label, row, faint) => {
      if (!vec || vec.length < o + dim) return;
      const tip = new Array(dim);
      for (let c = 0; c < dim; c++) tip[c] = x[k * dim + c] + scale * vec[o + c];
      const x0 = T.px(x, k * dim), y0 = T.py(x, k * dim), x1 = T.px(tip, 0), y1 = T.py(tip, 0);
      let mag = 0;
      for (let c = 0; c < dim; c++) mag += vec[o + c] * vec[o + c];
      if (!(Math.hypot(x1 - x0, y1 - y0) >= 2)) return;
      list.push({ kind: kind.key, color: kind.color, label, particle: k, row, x0, y0, x1, y1, magnitude: Math.sqrt(mag), faint: !!faint });
    };
    for (const kind of ARROW_KINDS) {
      if (!arrowOn(kind.key)) continue;
      const scale = kind.key === "velocity" ? scales.velocity : scales.force;
      if (kind.key === "constraint" && a.rows.length) {
        const several = a.rows.length > 1;
        // Rows acting on each particle: where several do (a bead on two surfaces, the middle
        // of a double pendulum) their forces can nearly cancel, so the sum is what to read.
        const acting = new Array(n).fill(0);
        for (const r of a.rows) {
          for (let k = 0; k < n; k++) {
            let m = 0;
            for (let c = 0; c < dim; c++) m += r.force[k * dim + c] ** 2;
            if (m > 0) acting[k]++;
          }
        }
        for (const r of a.rows) {
          const label = several ? `λ${subscript(r.row + 1)}∇C${subscript(r.row + 1)}` : "λ∇C";
          for (let k = 0; k < n; k++) add(kind, k, r.force, k * dim, scale, label, r.row, acting[k] > 1);
        }
        for (let k = 0; k < n; k++) if (acting[k] > 1) add(kind, k, a.constraint, k * dim, scale, "Σλ∇C", null, false);
      } else {
        const label = kind.key === "constraint" ? "F_c" : kind.label;
        for (let k = 0; k < n; k++) add(kind, k, a[kind.key], k * dim, scale, label, null);
      }
    }
    ctx.save();
    ctx.lineWidth = 4;
    ctx.lineCap = "round";
    ctx.font = "24px system-ui, sans-serif";
    // Labels (a few particles only) go next to the tip, on the first side where they stay
    // inside the plot and clear of the clock and the labels already placed; else none.
    const taken = avoid.slice();
    const r = T.r;
    const place = (ar, angle) => {
      const m = ctx.measureText(ar.label), gap = 8;
      const w = m.width, up = m.actualBoundingBoxAscent + 1, down = m.actualBoundingBoxDescent + 1;
      const ux = Math.cos(angle), uy = Math.sin(angle);
      const candidates = [
        [ar.x1 + gap * ux + (ux < 0 ? -w : 0), ar.y1 + gap * uy + (uy < 0 ? 0 : up)],
        [ar.x1 + gap, ar.y1 - gap], [ar.x1 + gap, ar.y1 + gap + up],
        [ar.x1 - gap - w, ar.y1 - gap], [ar.x1 - gap - w, ar.y1 + gap + up],
      ];
      for (const [lx, ly] of candidates) {
        const box = { x0: lx, y0: ly - up, x1: lx + w, y1: ly + down };
        const inside = box.x0 >= r.x0 && box.x1 <= r.x1 && box.y0 >= r.y0 && box.y1 <= r.y1;
        if (inside && !taken.some((b) => b.x0 < box.x1 && box.x0 < b.x1 && b.y0 < box.y1 && box.y0 < b.y1)) {
          taken.push(box);
          return [lx, ly];
        }
      }
      return null;
    };
    for (const ar of list) {
      const angle = Math.atan2(ar.y1 - ar.y0, ar.x1 - ar.x0), head = Math.min(ar.faint ? 10 : 16, 0.45 * Math.hypot(ar.x1 - ar.x0, ar.y1 - ar.y0));
      ctx.globalAlpha = ar.faint ? 0.45 : 1;
      ctx.lineWidth = ar.faint ? 2 : 4;
      ctx.strokeStyle = ar.color;
      ctx.fillStyle = ar.color;
      ctx.beginPath();
      ctx.moveTo(ar.x0, ar.y0);
      ctx.lineTo(ar.x1 - 0.8 * head * Math.cos(angle), ar.y1 - 0.8 * head * Math.sin(angle));
      ctx.stroke();
      ctx.beginPath();
      ctx.moveTo(ar.x1, ar.y1);
      ctx.lineTo(ar.x1 - head * Math.cos(angle - 0.45), ar.y1 - head * Math.sin(angle - 0.45));
      ctx.lineTo(ar.x1 - head * Math.cos(angle + 0.45), ar.y1 - head * Math.sin(angle + 0.45));
      ctx.closePath();
      ctx.fill();
      const at = n <= 4 && !ar.faint ? place(ar, angle) : null;
      ar.labelled = !!at;
      if (at) { ctx.textAlign = "left"; ctx.fillText(ar.label, at[0], at[1]); }
    }
    ctx.restore();
    return list;
  }
  function subscript(k) {
    return String(k).split("").map((d) => "₀₁₂₃₄₅₆₇₈₉"[Number(d)]).join("");
  }
  // For the tests: the arrows panel `id` drew last (canvas pixels) and its scales (scene
  // units per unit of velocity and of force) and pixels per scene unit.
  state.arrowsOf = (id) => {
    const p = state.panels.get(id);
    const a = p.frame && p.frame.arrows;
    return { arrows: p.lastArrows || [], scales: a ? arrowScales(p, a) : null, pixelsPerUnit: transform(p).s };
  };

  // Sizes in canvas pixels: particles shrink with their number and their spacing on screen
  // (a fraction of the median rod length, from the first frame drawn), from 11 down to 1.5.
  function sizes(p, T, f, n, dim) {
    if (p.sizes && p.sizes.epoch === f.epoch && p.sizes.scale === T.s) return p.sizes;
    let radius = n <= 16 ? 11 : Math.max(1.5, 11 * Math.sqrt(16 / n));
    const pairs = state.scene.draw.pairs, lengths = [];
    for (let i = 0; i + 1 < pairs.length && lengths.length < 2000; i += 2) {
      const a = pairs[i], b = pairs[i + 1];
      if (a >= n || b >= n) continue;
      const d = Math.hypot(T.px(f.x, a * dim) - T.px(f.x, b * dim), T.py(f.x, a * dim) - T.py(f.x, b * dim));
      if (Number.isFinite(d)) lengths.push(d);
    }
    if (lengths.length) {
      lengths.sort((a, b) => a - b);
      radius = Math.max(1.5, Math.min(radius, 0.35 * lengths[lengths.length >> 1]));
    }
    const rod = n <= 16 ? 3 : Math.max(1, Math.min(3, radius / 2));
    const trail = n <= 16 ? 4 : Math.max(1, Math.min(4, radius));
    p.sizes = { epoch: f.epoch, scale: T.s, radius, rod, trail };
    return p.sizes;
  }

  // ---------- charts ----------
  // Signed relative energy change over time: (E - E0)/E_scale, or (E - W - E0)/E_scale when
  // something does work on the system (then E itself changes, and that is physics, not
  // error). Linear and signed by default, so that gain and loss show; log10 |.| on request.
  // Exact zeros are said in words ("0 (exact)"), never drawn as a tiny number.
  const CHART_FONT = "26px system-ui, sans-serif"; // canvas px; the canvas is shown at half size: 13 px

  function chartFrame(ctx, W, H, title) {
    ctx.fillStyle = "#fff";
    ctx.fillRect(0, 0, W, H);
    ctx.font = CHART_FONT;
    ctx.fillStyle = "#3a3a3f";
    ctx.textAlign = "left";
    ctx.fillText(fitted(ctx, title, W - 12), 6, 26);
  }
  // `text` cut to `room` canvas pixels in the context's font, with "…" where it was cut.
  function fitted(ctx, text, room) {
    if (ctx.measureText(text).width <= room) return text;
    while (text.length > 1 && ctx.measureText(text + "…").width > room) text = text.slice(0, -1);
    return text + "…";
  }

  // history: [t, value] pairs; `log`: plot log10 |value|.
  function drawSeries(canvas, history, options) {
    const { title, color, log } = options;
    const ctx = canvas.getContext("2d");
    const W = canvas.width, H = canvas.height;
    chartFrame(ctx, W, H, title);
    const pts = history.filter((h) => Number.isFinite(h[1]));
    const zeros = pts.filter((h) => h[1] === 0).length;
    // A log chart with some exact zeros says so on a line of its own under the plot.
    const R = 10, Tp = 50, B = log && zeros && zeros < pts.length ? 80 : 48;
    const t0 = pts.length ? pts[0][0] : 0, t1 = pts.length ? pts[pts.length - 1][0] : 1;
    const span = t1 > t0 ? t1 - t0 : 1;
    let L = 120;
    const px = (t) => L + ((t - t0) / span) * (W - L - R);
    const exactZeros = pts.filter((h) => h[1] === 0).length;
    let lo, hi, value, ticks, label;
    if (log) {
      const logs = pts.filter((h) => h[1] !== 0).map((h) => Math.log10(Math.abs(h[1])));
      hi = Math.ceil(Math.max(-15, ...logs));
      lo = Math.max(Math.floor(Math.min(hi - 1, ...logs)), hi - 18);
      value = (v) => (v === 0 ? null : Math.max(lo, Math.log10(Math.abs(v))));
      const step = Math.max(1, Math.ceil((hi - lo) / 4));
      ticks = [];
      for (let d = hi; d >= lo; d -= step) ticks.push(d);
      label = (d) => "1e" + d;
    } else {
      const m = Math.max(...pts.map((h) => Math.abs(h[1])), 0);
      const top = m > 0 ? m * 1.1 : 1;
      lo = -top; hi = top;
      value = (v) => v;
      ticks = m > 0 ? niceTicks(lo, hi, 4) : [0];
      label = (v) => (v === 0 ? (m === 0 ? "0 (exact)" : "0") : fmt(v, 2));
    }
    const py = (v) => Tp + (1 - (v - lo) / (hi - lo)) * (H - Tp - B);
    // The left margin fits the widest value label.
    L = Math.max(L, 18 + Math.max(...ticks.map((d) => ctx.measureText(label(d)).width)));
    ctx.strokeStyle = "#e6e6e2";
    ctx.fillStyle = "#55555a";
    ctx.textAlign = "right";
    ctx.lineWidth = 1;
    for (const d of ticks) {
      ctx.beginPath(); ctx.moveTo(L, py(d)); ctx.lineTo(W - R, py(d)); ctx.stroke();
      ctx.fillText(label(d), L - 6, py(d) + 9);
    }
    // The time axis: ticks and their labels under the plot, its name in the corner.
    const tTicks = pts.length > 1 ? niceTicks(t0, t1, Math.max(2, Math.floor((W - L - R) / 150))) : [];
    ctx.beginPath();
    for (const t of tTicks) { ctx.moveTo(px(t), Tp); ctx.lineTo(px(t), H - B + 8); }
    ctx.stroke();
    ctx.textAlign = "center";
    for (const t of tTicks) ctx.fillText(fmt(t, 3), Math.min(W - R - 30, Math.max(L + 30, px(t))), H - 8);
    ctx.textAlign = "left";
    ctx.fillText("t (s)", 6, H - 8);
    if (log && exactZeros === pts.length && pts.length) {
      // Nothing to draw on a log axis: said in the middle of the plot.
      ctx.textAlign = "center";
      ctx.fillText("0 (exact) at every step", (L + W - R) / 2, (Tp + H - B) / 2 + 9);
    } else if (log && exactZeros) {
      // Under the plot, on its own line above the time axis (a log axis has no 0).
      ctx.textAlign = "left";
      ctx.fillText(`${exactZeros} exact ${exactZeros === 1 ? "0" : "0s"} not drawn`, 6, H - 44);
    }
    ctx.strokeStyle = color;
    ctx.lineWidth = 3;
    ctx.beginPath();
    let pen = false;
    for (const h of pts) {
      const v = value(h[1]);
      if (v === null) { pen = false; continue; }
      if (pen) ctx.lineTo(px(h[0]), py(v)); else ctx.moveTo(px(h[0]), py(v));
      pen = true;
    }
    ctx.stroke();
    return { lo, hi, exactZeros };
  }

  // Kinetic, potential and total energy as bars from a common zero (V may be negative), plus
  // the work W and E - W when something does work on the system. Values are the frame's,
  // which are the core's.
  function drawBars(p) {
    const f = p.frame, canvas = p.dom.bars;
    if (!f) return null;
    const ctx = canvas.getContext("2d");
    const W = canvas.width, H = canvas.height;
    ctx.fillStyle = "#fff";
    ctx.fillRect(0, 0, W, H);
    const rows = [
      ["T kinetic", f.kinetic, "#e67814"],
      ["V potential", f.potential, "#1a9c6b"],
      ["E = T + V", f.energy, "#1f6feb"],
    ];
    if (!f.energy_conserved) {
      rows.push(["W work done", f.work, "#7b3fc4"]);
      rows.push(["E − W", f.energy - f.work, "#333"]);
    }
    rows.push(["E0 (start)", f.energy_initial, "#9a9a96"]);
    const m = Math.max(...rows.map((r) => Math.abs(r[1])), 1e-300);
    const anyNegative = rows.some((r) => r[1] < 0), anyPositive = rows.some((r) => r[1] > 0);
    // The values (with the scene's energy unit) get the room they need on the right.
    const unit = state.scene && state.scene.energy_unit ? " " + state.scene.energy_unit : "";
    const valueText = (v) => (v === 0 ? `0 (exact)${unit}` : `${fmt(v, 5)}${unit}`);
    ctx.font = CHART_FONT;
    const R = Math.max(200, ...rows.map((r) => ctx.measureText(valueText(r[1])).width + 20));
    const L = 190, row = (H - 10) / rows.length;
    const width = W - L - R;
    const zero = anyNegative && anyPositive ? L + width / 2 : anyNegative ? L + width : L;
    const scale = (anyNegative && anyPositive ? width / 2 : width) / m;
    ctx.font = CHART_FONT;
    ctx.strokeStyle = "#9a9a96";
    ctx.beginPath(); ctx.moveTo(zero, 4); ctx.lineTo(zero, H - 4); ctx.stroke();
    rows.forEach(([name, v, color], i) => {
      const y = 5 + i * row;
      ctx.fillStyle = color;
      const w = v * scale;
      ctx.fillRect(Math.min(zero, zero + w), y + 4, Math.abs(w), row - 8);
      ctx.fillStyle = "#3a3a3f";
      ctx.textAlign = "left";
      ctx.fillText(name, 6, y + row / 2 + 9);
      ctx.textAlign = "right";
      ctx.fillText(valueText(v), W - 6, y + row / 2 + 9);
    });
    return { kinetic: f.kinetic, potential: f.potential, total: f.energy, work: f.work, rows: rows.length };
  }

  function drawCharts(p) {
    const f = p.frame;
    const conserved = !f || f.energy_conserved;
    const why = f && !conserved ? f.not_conserved_by.join("; ") : "";
    const log = p.dom.logEnergy.checked;
    const quantity = conserved ? "energy change, relative" : "change of E − W, relative";
    const title = log ? `log |${quantity}|` : quantity;
    p.dom.chartE.title = conserved ?
      "relative energy change (E − E0)/E_scale, E_scale = max(|E0|, T0 + |V0|, T0 + M g L): 0 for exact conservation; its sign says gain or loss" :
      `E changes because ${why}: that is physics, not error. E − W (W the work done on the system) is conserved; the chart shows its relative change (E − W − E0)/E_scale`;
    p.dom.energyWhy.textContent = conserved ? "" : `E changes because ${why}; E − W is conserved (W: work done on the system)`;
    const values = p.history.map((h) => [h[0], h[1]]);
    p.lastChart = drawSeries(p.dom.chartE, values, { title, color: "#1f6feb", log });
    // No |C| chart for a scene without constraints (there is no C).
    const hasC = !!(state.scene && state.scene.constraints.length);
    p.dom.chartC.hidden = !hasC;
    p.dom.chartE.classList.toggle("alone", !hasC);
    const width = hasC ? 454 : 908;
    if (p.dom.chartE.width !== width) p.dom.chartE.width = width;
    if (hasC) drawSeries(p.dom.chartC, p.history.map((h) => [h[0], h[2]]), { title: "constraint error max |C|", color: "#b42318", log: true });
    p.lastBars = drawBars(p);
    if (p.plot) p.dom.plotLog.checked = !!p.plot.log;
    p.lastPlot = drawPanelPlot(p);
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

  // The display clock of a running panel: it runs at the time scale, a little behind the
  // newest state received (about two frames of simulated time plus a step), so that there is
  // always a later sample to interpolate towards; it is pulled gently towards that lag and
  // jumps when far off (a restart, a stall). Paused, stepped or failed: the newest state.
  function advanceDisplay(p, wall) {
    const samples = p.samples;
    if (!p.frame || !samples.length) { p.displayT = null; return; }
    const latest = samples[samples.length - 1].t;
    const scale = state.timeScale;
    if (p.frame.status !== "running" || scale <= 0) { p.displayT = latest; return; }
    const lag = scale * 0.035 + p.info.dt;
    const target = latest - lag;
    if (p.displayT == null || Math.abs(p.displayT - target) > 4 * lag + 0.25 * scale) {
      p.displayT = target;
    } else {
      p.displayT += scale * wall + 0.1 * (target - p.displayT);
    }
    p.displayT = Math.min(latest, Math.max(samples[0].t, p.displayT));
  }

  // Panels are drawn when something changed: a frame, the panel's settings, the scene, the
  // view, or the display clock.
  function render(now) {
    const wall = state.lastRender == null ? 0 : Math.min(0.1, (now - state.lastRender) / 1000);
    state.lastRender = now;
    for (const p of state.panels.values()) {
      const before = p.displayT;
      advanceDisplay(p, wall);
      if (p.displayT !== before) p.dirty = true;
      if (!p.dirty) continue;
      p.dirty = false;
      draw(p, false);
      if (p.chartsDirty) { p.chartsDirty = false; drawCharts(p); }
    }
    if (state.overlay.on) { for (const p of state.panels.values()) if (p.displayT != null) state.overlay.dirty = true; }
    updateOverlay();
    for (const move of state.pendingMoves.values()) send(move);
    state.pendingMoves.clear();
    requestAnimationFrame(render);
  }

  // ---------- pointer: drag a particle, pan (2D) or orbit (3D), wheel zoom ----------
  function canvasPoint(canvas, event) {
    const r = canvas.getBoundingClientRect();
    return [(event.clientX - r.left) * (canvas.width / r.width), (event.clientY - r.top) * (canvas.height / r.height)];
  }

  function positionOf(x, k, dim) {
    return Array.from(x.subarray ? x.subarray(k * dim, (k + 1) * dim) : x.slice(k * dim, (k + 1) * dim));
  }

  function installDrag(id, canvas) {
    let gesture = null; // { kind: "pan" | "orbit", x, y, view }
    canvas.addEventListener("pointerdown", (event) => {
      const p = state.panels.get(id);
      if (!p || !p.frame || !state.scene) return;
      const T = transform(p);
      const [cx, cy] = canvasPoint(canvas, event);
      const dim = state.scene.dim;
      const x = p.lastDraw ? p.lastDraw.x : p.frame.x;
      let best = -1, bestD = 30;
      for (let k = 0; k < state.scene.particles.length; k++) {
        const d = Math.hypot(T.px(x, k * dim) - cx, T.py(x, k * dim) - cy);
        if (d < bestD) { best = k; bestD = d; }
      }
      try { canvas.setPointerCapture(event.pointerId); } catch (e) { /* synthetic events */ }
      event.preventDefault();
      // Paused: the tip of a velocity arrow sets that particle's start velocity.
      if (p.frame.status !== "running") {
        const tip = (p.lastArrows || []).find((a) => a.kind === "velocity" && Math.hypot(a.x1 - cx, a.y1 - cy) < 16);
        if (tip) {
          gesture = { kind: "velocity", particle: tip.particle, ref: positionOf(x, tip.particle, dim) };
          p.aiming = { particle: tip.particle, from: [tip.x0, tip.y0], to: [cx, cy] };
          p.dirty = true;
          return;
        }
      }
      if (best < 0) {
        // Empty space: pan the view (2D, or 3D with shift) or orbit (3D).
        const orbit = dim === 3 && !event.shiftKey;
        gesture = { kind: orbit ? "orbit" : "pan", x: cx, y: cy, view: { ...p.view, c: p.view.c.slice() } };
        return;
      }
      const ref = positionOf(x, best, dim);
      if (p.frame.status !== "running") {
        // Paused: the drag sets the start state, on release (the server projects it onto
        // the constraints and restarts every panel from it).
        gesture = { kind: "place", particle: best, ref };
        p.placing = { particle: best, target: T.unproject(cx, cy, ref) };
        p.dirty = true;
        return;
      }
      state.drags.set(id, { particle: best, ref });
      send({ type: "drag_start", panel: id, particle: best, target: T.unproject(cx, cy, ref) });
    });
    canvas.addEventListener("pointermove", (event) => {
      const p = state.panels.get(id);
      if (!p) return;
      const [cx, cy] = canvasPoint(canvas, event);
      if (gesture && gesture.kind === "place") {
        p.placing = { particle: gesture.particle, target: transform(p).unproject(cx, cy, gesture.ref) };
        p.dirty = true;
        return;
      }
      if (gesture && gesture.kind === "velocity") {
        p.aiming.to = [cx, cy];
        p.dirty = true;
        return;
      }
      if (gesture) {
        const dx = cx - gesture.x, dy = cy - gesture.y, v0 = gesture.view;
        if (gesture.kind === "orbit") {
          p.view.yaw = v0.yaw - 0.008 * dx;
          p.view.pitch = Math.max(-1.5, Math.min(1.5, v0.pitch + 0.008 * dy));
        } else {
          const T = transform(p);
          p.view.auto = false;
          p.view.c = v0.c.map((c, a) => c - (dx / T.s) * T.R[a] + (dy / T.s) * T.S[a]);
        }
        p.dirty = true;
        return;
      }
      const drag = state.drags.get(id);
      if (!drag) return;
      const T = transform(p);
      state.pendingMoves.set(id, { type: "drag_move", panel: id, target: T.unproject(cx, cy, drag.ref) });
    });
    const end = () => {
      if (gesture && gesture.kind === "velocity") {
        const p = state.panels.get(id);
        const a = p && p.frame && p.frame.arrows;
        if (a && p.aiming) {
          // The new velocity: (tip - particle) in scene units over the velocity scale.
          const T = transform(p), dim = state.scene.dim, k = p.aiming.particle;
          const tip = T.unproject(p.aiming.to[0], p.aiming.to[1], gesture.ref);
          const scale = arrowScales(p, a).velocity;
          const velocities = Array.from(a.velocity);
          for (let c = 0; c < dim; c++) velocities[k * dim + c] = (tip[c] - gesture.ref[c]) / scale;
          send({ type: "set_start_state", panel: id, velocities });
        }
        if (p) { p.aiming = null; p.dirty = true; }
        gesture = null;
        return;
      }
      if (gesture && gesture.kind === "place") {
        const p = state.panels.get(id);
        if (p && p.placing) {
          send({ type: "set_start", panel: id, particle: p.placing.particle, target: p.placing.target });
          p.placing = null;
          p.dirty = true;
        }
      }
      gesture = null;
      if (!state.drags.has(id)) return;
      const move = state.pendingMoves.get(id);
      if (move) { send(move); state.pendingMoves.delete(id); }
      send({ type: "drag_end", panel: id });
      state.drags.delete(id);
    };
    canvas.addEventListener("pointerup", end);
    canvas.addEventListener("pointercancel", end);
    canvas.addEventListener("wheel", (event) => {
      const p = state.panels.get(id);
      if (!p || !state.scene) return;
      event.preventDefault();
      zoom(p, canvasPoint(canvas, event), Math.exp(-0.0015 * event.deltaY));
    }, { passive: false });
  }

  // Zoom panel `p` by `factor` about canvas point `at` (the scene point there stays put).
  function zoom(p, at, factor) {
    const T = transform(p);
    const q = T.unproject(at[0], at[1], T.center);
    p.view.auto = false;
    p.view.s = T.s * factor;
    p.view.c = q.map((v, a) => v - (v - T.center[a]) / factor);
    p.dirty = true;
  }
  function fitView(p) {
    p.view.auto = true;
    p.box = null;
    p.dirty = true;
  }
  // For the tests: zoom panel `id` by `factor` about its center, pan it by (dx, dy) canvas
  // pixels, or fit it again.
  state.zoom = (id, factor) => {
    const p = state.panels.get(id), r = plotRect(p.dom.canvas);
    zoom(p, [0.5 * (r.x0 + r.x1), 0.5 * (r.y0 + r.y1)], factor);
    draw(p, false);
  };
  state.fit = (id) => { const p = state.panels.get(id); fitView(p); draw(p, false); };

  // The panel's view as the tests read it: scale (px per unit), center, auto, plot rectangle.
  state.viewOf = (id) => {
    const p = state.panels.get(id), T = transform(p);
    return { s: T.s, center: T.center, auto: p.view.auto, rect: T.r, yaw: p.view.yaw, pitch: p.view.pitch, R: T.R, S: T.S };
  };

  // Client coordinates of scene point `point` (dim numbers; a missing z is 0) in panel `id`.
  state.clientPoint = (id, ...point) => {
    const p = state.panels.get(id);
    const [px, py] = state.canvasPoint(id, ...point);
    const r = p.dom.canvas.getBoundingClientRect();
    return [r.left + px * (r.width / p.dom.canvas.width), r.top + py * (r.height / p.dom.canvas.height)];
  };

  // Canvas pixel of scene point `point` in panel `id` (for tests).
  state.canvasPoint = (id, ...point) => {
    const T = transform(state.panels.get(id));
    while (point.length < T.dim) point.push(0);
    return [T.px(point, 0), T.py(point, 0)];
  };

  // ---------- overlay mode ----------
  // Every panel's particles in one canvas, each panel in its own colour (legend beside it),
  // drawn in the first panel's view; and the distance between each panel and the first
  // over time, as the server computed it at the same t (`frame.distance`).
  const PANEL_COLORS = ["#e67814", "#1f6feb", "#1a9c6b", "#d6336c", "#7b3fc4", "#8c6d1f", "#0c7bb3", "#333333"];

  function drawOverlay() {
    const ov = state.overlay, canvas = $("overlay-canvas"), ctx = canvas.getContext("2d");
    const panels = [...state.panels.values()];
    const first = panels[0];
    ctx.fillStyle = "#fff";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    if (!first || !first.frame || !state.scene) return null;
    // A stand-in panel for the view: the first panel's box, the overlay canvas.
    ov.info = first.info; ov.frame = first.frame; ov.dom = { canvas };
    const T = transform(ov), r = T.r, dim = state.scene.dim;
    drawAxes(ctx, T, canvas);
    ctx.save();
    ctx.beginPath();
    ctx.rect(r.x0, r.y0, r.x1 - r.x0, r.y1 - r.y0);
    ctx.clip();
    const curves = first.curves || first.info.curves;
    ctx.strokeStyle = "#9db9e8";
    ctx.lineWidth = 2;
    ctx.beginPath();
    for (const line of curves) {
      for (let i = 0; i + dim - 1 < line.length; i += dim) {
        if (i === 0) ctx.moveTo(T.px(line, i), T.py(line, i)); else ctx.lineTo(T.px(line, i), T.py(line, i));
      }
    }
    ctx.stroke();
    const drawn = [];
    const { pairs, anchored } = state.scene.draw;
    panels.forEach((p, k) => {
      if (!p.frame) return;
      const x = drawnPositions(p), n = Math.min(state.scene.particles.length, Math.floor(x.length / dim));
      const color = PANEL_COLORS[k % PANEL_COLORS.length];
      ctx.strokeStyle = color;
      ctx.fillStyle = color;
      ctx.lineWidth = 3;
      ctx.beginPath();
      for (let i = 0; i + 1 < pairs.length; i += 2) {
        if (pairs[i] >= n || pairs[i + 1] >= n) continue;
        ctx.moveTo(T.px(x, pairs[i] * dim), T.py(x, pairs[i] * dim));
        ctx.lineTo(T.px(x, pairs[i + 1] * dim), T.py(x, pairs[i + 1] * dim));
      }
      for (const rod of anchored) {
        if (rod.a >= n) continue;
        const q = dim === 3 && rod.anchor.length < 3 ? [rod.anchor[0], rod.anchor[1], 0] : rod.anchor;
        ctx.moveTo(T.px(x, rod.a * dim), T.py(x, rod.a * dim));
        ctx.lineTo(T.px(q, 0), T.py(q, 0));
      }
      ctx.stroke();
      const rad = n <= 16 ? 11 - 2 * k : Math.max(1.5, 6 * Math.sqrt(16 / n));
      const points = [];
      ctx.beginPath();
      for (let i = 0; i < n; i++) {
        const px = T.px(x, i * dim), py = T.py(x, i * dim);
        ctx.moveTo(px + Math.max(rad, 3), py);
        ctx.arc(px, py, Math.max(rad, 3), 0, 2 * Math.PI);
        points.push([px, py]);
      }
      ctx.fill();
      drawn.push({ id: p.info.id, color, points, t: p.displayT, epoch: p.frame.epoch });
    });
    ctx.restore();
    // Legend, also in the canvas (so that a screenshot says which colour is which).
    ctx.font = "24px system-ui, sans-serif";
    ctx.textAlign = "left";
    panels.forEach((p, k) => {
      const y = r.y0 + 30 + 30 * k;
      ctx.fillStyle = PANEL_COLORS[k % PANEL_COLORS.length];
      ctx.beginPath(); ctx.arc(r.x0 + 20, y - 8, 9, 0, 2 * Math.PI); ctx.fill();
      ctx.fillStyle = "#222";
      ctx.fillText(`#${p.info.id} ${p.info.method} · ${p.info.integrator} · dt ${fmt(p.info.dt)}`, r.x0 + 36, y);
    });
    ov.lastDraw = { panels: drawn };
    return ov.lastDraw;
  }

  // The distance between the formulations: every other panel's particles to the first
  // panel's at the same t, over time (the server computes it).
  function drawDistance() {
    const canvas = $("distance-chart");
    const panels = [...state.panels.values()];
    const series = [];
    panels.forEach((p, k) => {
      const h = state.overlay.history.get(p.info.id);
      if (k > 0 && h && h.epoch === p.info.epoch && h.points.length) series.push({ color: PANEL_COLORS[k % PANEL_COLORS.length], points: h.points });
    });
    if (panels.length < 2) {
      const ctx = canvas.getContext("2d");
      chartFrame(ctx, canvas.width, canvas.height, "distance between formulations: add a second panel");
      return null;
    }
    const L = state.scene && state.scene.length_unit;
    const drawn = drawXY(canvas, {
      xLabel: "time t (s)", series,
      yLabel: `distance to panel #${panels[0].info.id}, largest over particles` + (L ? ` (${L})` : ""),
    });
    return { series: series.length, max: drawn.points ? drawn.data.y[1] : 0 };
  }

  function updateOverlay() {
    const ov = state.overlay;
    if (!ov.on || !ov.dirty) return;
    ov.dirty = false;
    drawOverlay();
    drawDistance();
    fillOverlayChoices();
    drawOverlayPlot();
    const panels = [...state.panels.values()];
    const legend = $("overlay-legend");
    legend.innerHTML = "";
    panels.forEach((p, k) => {
      const item = el("div", "legend-item");
      item.dataset.panel = String(p.info.id);
      const sw = el("span", "swatch");
      sw.style.background = PANEL_COLORS[k % PANEL_COLORS.length];
      item.append(sw, `#${p.info.id} ${p.info.method} · ${p.info.integrator} · dt ${fmt(p.info.dt)}`);
      legend.appendChild(item);
    });
    // The latest distances the server sent, as numbers (the chart's last points).
    const readout = $("distance-readout");
    readout.innerHTML = "";
    panels.slice(1).forEach((p) => {
      const f = p.frame;
      const line = el("div", "distance");
      line.dataset.panel = String(p.info.id);
      if (f && f.distance != null) {
        line.dataset.value = String(f.distance);
        line.dataset.t = String(f.t);
        line.textContent = `panel #${p.info.id} − panel #${panels[0].info.id} at t = ${fmt(f.t)} s: ${f.distance === 0 ? "0 (exact)" : fmt(f.distance)}`;
      } else {
        line.textContent = `panel #${p.info.id}: not at the same t as panel #${panels[0].info.id} (a different dt)`;
      }
      readout.appendChild(line);
    });
  }

  function setOverlay(on) {
    state.overlay.on = on;
    $("overlay").checked = on;
    $("overlay-view").hidden = !on;
    state.overlay.dirty = true;
  }
  // For the tests.
  state.setOverlay = setOverlay;
  state.overlayPixel = (x, y) => Array.from($("overlay-canvas").getContext("2d").getImageData(Math.round(x), Math.round(y), 1, 1).data);

  // ---------- keyboard ----------
  // space: play / pause, s: one step, r: reset (not while typing in a field).
  document.addEventListener("keydown", (event) => {
    const t = event.target;
    if (event.ctrlKey || event.metaKey || event.altKey) return;
    if (t && (t.tagName === "INPUT" || t.tagName === "SELECT" || t.tagName === "TEXTAREA" || t.isContentEditable)) return;
    // A focused button would click itself on the space's release: take the focus away.
    if (event.key === " ") { event.preventDefault(); if (t && t.blur && t.tagName === "BUTTON") t.blur(); $("play").click(); }
    else if (event.key === "s") { event.preventDefault(); $("step").click(); }
    else if (event.key === "r") { event.preventDefault(); $("reset").click(); }
    else if (event.key === "p") { event.preventDefault(); setPresenting(!state.presenting); }
  });

  // ---------- presentation mode ----------
  // For a projector: the settings, notes and the second chart are hidden, each panel shows
  // its canvas (with the clock and readouts drawn large on it), the energy bars and the
  // energy chart, and the canvases shrink until all of it fits the window without scrolling.
  // Full screen when the browser allows it. Key p or the toolbar's "present".
  function setPresenting(on) {
    state.presenting = on;
    document.body.classList.toggle("presenting", on);
    $("present").textContent = on ? "exit presentation" : "present";
    const fullscreen = document.fullscreenElement;
    if (on && !fullscreen && document.documentElement.requestFullscreen) {
      document.documentElement.requestFullscreen().catch(() => {});
    } else if (!on && fullscreen && document.exitFullscreen) {
      document.exitFullscreen().catch(() => {});
    }
    fitToWindow();
  }
  // Presenting: each canvas as wide as fits the height left under it for the bars and the
  // chart (the canvas keeps its 920 x 680 shape). Otherwise: the column's width.
  function fitToWindow() {
    for (const p of state.panels.values()) {
      const canvas = p.dom.canvas;
      if (!state.presenting) { canvas.style.maxWidth = ""; continue; }
      canvas.style.maxWidth = "";
      const top = canvas.getBoundingClientRect().top + window.scrollY;
      const root = p.dom.root.getBoundingClientRect();
      const below = root.bottom - canvas.getBoundingClientRect().bottom;
      // Below the panel: the panels' bottom padding (12 px) and a margin.
      const height = window.innerHeight - top - below - 20;
      canvas.style.maxWidth = `${Math.max(160, Math.floor(height * 920 / 680))}px`;
      p.dirty = true;
    }
  }
  window.addEventListener("resize", fitToWindow);
  state.setPresenting = setPresenting;
  // `?present=1` (the share URL of a page presenting; the static page's embed snippet): open
  // in presentation mode, which fits the canvases to the window (or the post's iframe).
  if (new URLSearchParams(location.search).get("present") === "1") setPresenting(true);

  // ---------- toolbar ----------
  $("overlay").onchange = () => setOverlay($("overlay").checked);
  for (const id of ["overlay-canvas", "distance-chart", "overlay-plot"]) countCalls($(id));
  const overlayPlotChanged = () => {
    state.overlay.plot = { x: $("overlay-plot-x").value, y: $("overlay-plot-y").value, log: $("overlay-plot-log").checked };
    state.overlay.dirty = true;
  };
  for (const id of ["overlay-plot-x", "overlay-plot-y", "overlay-plot-log"]) $(id).onchange = overlayPlotChanged;
  $("present").onclick = () => setPresenting(!state.presenting);
  $("share").onclick = () => {
    const url = shareUrl();
    $("share-box").hidden = false;
    $("share-url").value = url;
    $("share-url").select();
    history.replaceState(null, "", url);
    if (navigator.clipboard && window.isSecureContext) navigator.clipboard.writeText(url).catch(() => {});
  };
  state.shareUrl = shareUrl;
  $("play").onclick = () => {
    send({ type: $("play").textContent === "Pause" ? "pause" : "play" });
  };
  $("step").onclick = () => send({ type: "step" });
  for (const kind of ARROW_KINDS) {
    $("arrow-" + kind.key).onchange = () => { for (const p of state.panels.values()) p.dirty = true; };
  }
  $("trails").onchange = () => {
    for (const p of state.panels.values()) { p.trail = []; p.dirty = true; }
  };
  $("reset").onclick = () => send({ type: "reset" });
  $("time-scale").onchange = () => send({ type: "set_time_scale", scale: Number($("time-scale").value) });
  $("at-end").onchange = () => send({ type: "set_at_end", at_end: $("at-end").value });
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

  // For the tests: the page's helpers for the scene's up direction.
  state.sceneUp = () => sceneUp(state.scene);

  connect();
  requestAnimationFrame(render);
})();
