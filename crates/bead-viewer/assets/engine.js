// bead engine in the page (the static page of `bead export-page`): the viewer's session,
// compiled to WebAssembly (crates/bead-web), behind the interface of the WebSocket that the
// served page uses (readyState, send, onopen, onmessage, onclose), so that viewer.js runs
// unchanged on it. The session's messages are the protocol's (crates/bead-viewer/src/
// protocol.rs): JSON text, and binary frames as ArrayBuffers. The clock ticks ~60 times a
// second, as the server's does. Plain modern JavaScript, no build step.
"use strict";

(function () {
  const FRAME_MS = 1000 / 60;
  const CONNECTING = 0, OPEN = 1, CLOSED = 3;
  const encoder = new TextEncoder();
  const decoder = new TextDecoder();

  // The engine's bytes: fetched (http, https), or from bead-wasm.js (base64) where the
  // browser refuses to fetch a file (file://).
  async function engineBytes() {
    if (location.protocol !== "file:") {
      try {
        const response = await fetch("bead.wasm");
        if (response.ok) return await response.arrayBuffer();
      } catch (e) { /* fall back to the script */ }
    }
    if (!window.BEAD_WASM_BASE64) {
      await new Promise((resolve, reject) => {
        const script = document.createElement("script");
        script.src = "bead-wasm.js";
        script.onload = resolve;
        script.onerror = () => reject(new Error("could not load bead-wasm.js"));
        document.head.appendChild(script);
      });
    }
    const text = atob(window.BEAD_WASM_BASE64);
    const bytes = new Uint8Array(text.length);
    for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
    return bytes.buffer;
  }

  class EngineSocket {
    constructor() {
      this.readyState = CONNECTING;
      this.binaryType = "arraybuffer";
      this.onopen = null;
      this.onmessage = null;
      this.onclose = null;
      // What the page shows where the served page says "connected".
      this.label = "running in this page";
      this.exports = null;
      this.panic = null;
      this.timer = null;
      // Whether drain() is delivering (a handler that sends must not be re-entered).
      this.draining = false;
      // For the tests: when the engine was ready, and its ticks.
      this.stats = { loadMs: null, ticks: 0, tickMs: 0, wasmBytes: 0 };
      const started = performance.now();
      this.load().then(() => {
        this.open();
        // Fetched, compiled, scenes added, the first scene loaded: ready to draw.
        this.stats.loadMs = performance.now() - started;
      }).catch((e) => this.fail("the engine did not load: " + (e && e.message ? e.message : e)));
    }

    async load() {
      const bytes = await engineBytes();
      this.stats.wasmBytes = bytes.byteLength;
      const self = this;
      const imports = {
        env: {
          // The session's budgets (seconds of work per tick) read the page's clock.
          bead_clock_ms: () => performance.now(),
          // A panic's message, just before the engine traps.
          bead_panic: (ptr, len) => { self.panic = self.text(ptr, len); },
        },
      };
      const { instance } = await WebAssembly.instantiate(bytes, imports);
      this.exports = instance.exports;
      for (const scene of window.BEAD_SCENES || []) {
        if (this.readyState === CLOSED) return;
        this.call(() => this.withString(scene.name, (np, nl) =>
          this.withString(scene.text, (tp, tl) => this.exports.bead_add_scene(np, nl, tp, tl))));
      }
    }

    open() {
      if (this.readyState === CLOSED) return;
      this.call(() => this.exports.bead_start());
      if (this.readyState === CLOSED) return;
      this.readyState = OPEN;
      if (this.onopen) this.onopen({});
      this.drain();
      let last = performance.now();
      const tick = () => {
        if (this.readyState !== OPEN) return;
        const now = performance.now();
        this.call(() => this.exports.bead_tick((now - last) / 1000));
        last = now;
        this.stats.ticks += 1;
        this.stats.tickMs += performance.now() - now;
        this.drain();
        // The next tick FRAME_MS after this one began (a tick that took longer: at once).
        this.timer = setTimeout(tick, Math.max(0, FRAME_MS - (performance.now() - now)));
      };
      this.timer = setTimeout(tick, FRAME_MS);
    }

    // The replies are delivered after the sender's handler returns (a microtask), as a
    // WebSocket delivers them in a later task: a handler that sends, then updates its own
    // state, sees the replies only after that update.
    send(text) {
      if (this.readyState !== OPEN) return;
      this.call(() => this.withString(text, (ptr, len) => this.exports.bead_message(ptr, len)));
      queueMicrotask(() => this.drain());
    }

    close() {
      if (this.timer !== null) clearTimeout(this.timer);
      this.readyState = CLOSED;
    }

    // Every message the session has for the page, in order, one handler at a time: what a
    // handler's own sends queue is delivered by this loop after that handler returns.
    drain() {
      if (this.draining) return;
      this.draining = true;
      try {
        while (this.readyState === OPEN) {
          const kind = this.call(() => this.exports.bead_next());
          if (!kind) return;
          const ptr = this.exports.bead_out_ptr();
          const len = this.exports.bead_out_len();
          const bytes = new Uint8Array(this.exports.memory.buffer, ptr, len);
          // Text as a string; a frame copied out of the engine's memory (it is reused).
          const data = kind === 1 ? decoder.decode(bytes) : bytes.slice().buffer;
          if (this.onmessage) this.onmessage({ data });
        }
      } finally {
        this.draining = false;
      }
    }

    // A call into the engine; a trap (a panic) stops the engine and closes the socket.
    call(f) {
      try {
        return f();
      } catch (e) {
        this.fail("the engine stopped: " + (this.panic || (e && e.message) || e));
        return 0;
      }
    }

    fail(message) {
      console.error(message);
      const was = this.readyState;
      this.close();
      if (was !== CLOSED && this.onclose) this.onclose({ reason: message });
    }

    // `text` in the engine's memory for the duration of f(ptr, len).
    withString(text, f) {
      const bytes = encoder.encode(text);
      const ptr = this.exports.bead_alloc(bytes.length);
      new Uint8Array(this.exports.memory.buffer, ptr, bytes.length).set(bytes);
      const result = f(ptr, bytes.length);
      this.exports.bead_free(ptr, bytes.length);
      return result;
    }

    text(ptr, len) {
      return decoder.decode(new Uint8Array(this.exports.memory.buffer, ptr, len));
    }
  }

  window.BeadEngine = { Socket: EngineSocket, OPEN };
})();
