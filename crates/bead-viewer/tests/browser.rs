//! End to end in real headless Chromium, driven through chromedriver (fantoccini): the page
//! loads without errors, draws, reacts to its controls, drags a bead along its curve and
//! shows a bad curve expression inline.
//!
//! Every wait waits for the state it checks, never for a value that a message from before
//! the request could also show: after a panel restarts, for a frame of its new epoch
//! (`frame.epoch === info.epoch`); for motion, for the motion itself rather than a delay.
//! Saves screenshots to `target/viewer-*.png` (the end-to-end one, `viewer-screenshot.png`,
//! also to `docs/viewer.png` with `BEAD_UPDATE_SCREENSHOT=1`).
//!
//! At scale: a chain of 1000 rods and a 3D cloth of rods served for real are drawn whole
//! (every rod, particle and pin counted in the page's draw list, `lastDraw`, and found inked
//! on the canvas) and keep running; a 50 x 50 cloth (2500 particles, 4900 rods), which the
//! dense solver of this branch cannot run within a test, is shown to the page through its
//! message handler as a session would send it, and drawn whole. Draw times are reported and
//! held to a generous bound only ([`DRAW_BOUND_MS`]).
//!
//! Skipped with a notice when chromium or chromedriver is missing, unless
//! `BEAD_REQUIRE_BROWSER=1`, which makes their absence a failure. `BEAD_CHROMIUM` and
//! `BEAD_CHROMEDRIVER` override the binaries (default `/usr/bin/chromium` and `chromedriver`
//! on the PATH).

use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use bead_viewer::protocol::{encode_frame, Applies, Encoded, PanelFrame, PanelInfo, ServerMessage};
use bead_viewer::server::{bind, serve};
use bead_viewer::session::{parse_scene, scene_info};
use bead_viewer::{Catalog, NamedScene, ServerConfig};
use fantoccini::{Client, ClientBuilder};
use futures_util::future::LocalBoxFuture;
use futures_util::FutureExt;
use serde_json::{json, Value};

mod generated;

/// Kills chromedriver (and the browser it started) when the test ends, however it ends.
struct Driver(Child);

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn find_on_path(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|dir| dir.join(name))
        .find(|p| p.is_file())
}

/// The browser and driver binaries, or why they are unavailable.
fn browser() -> Result<(PathBuf, PathBuf), String> {
    let chromium = std::env::var_os("BEAD_CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    if !chromium.is_file() {
        return Err(format!("no chromium at {}", chromium.display()));
    }
    let driver = match std::env::var_os("BEAD_CHROMEDRIVER") {
        Some(p) => PathBuf::from(p),
        None => find_on_path("chromedriver").ok_or("no chromedriver on the PATH")?,
    };
    if !driver.is_file() {
        return Err(format!("no chromedriver at {}", driver.display()));
    }
    Ok((chromium, driver))
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("no free port")
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

async fn js(client: &Client, script: &str) -> Value {
    client
        .execute(script, Vec::new())
        .await
        .unwrap_or_else(|e| panic!("script failed: {e}\n{script}"))
}

/// Poll `condition` (a JS expression) until it is truthy.
async fn wait_until(client: &Client, condition: &str, what: &str) {
    wait_within(client, condition, what, Duration::from_secs(15)).await
}

/// Poll `condition` (a JS expression) until it is truthy, for at most `limit`.
async fn wait_within(client: &Client, condition: &str, what: &str, limit: Duration) {
    let start = Instant::now();
    loop {
        let value = js(client, &format!("return !!({condition});")).await;
        if value == Value::Bool(true) {
            return;
        }
        if start.elapsed() > limit {
            let errors = js(client, "return window.__errors || [];").await;
            panic!("timed out waiting for {what} ({condition}); page errors: {errors}");
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// A JS condition: panel `panel`'s latest frame belongs to its current epoch (the panel's
/// last restart) and satisfies `condition` on `f`.
fn current(panel: u64, condition: &str) -> String {
    format!(
        "(() => {{ const p = window.__viewer.panels.get({panel}); const f = p && p.frame; \
         return !!(f && f.epoch === p.info.epoch && ({condition})); }})()"
    )
}

async fn frame(client: &Client, panel: u64) -> Value {
    js(
        client,
        // Positions are a Float64Array in the page: as an array here.
        &format!(
            "const f = window.__viewer.panels.get({panel}).frame; return {{...f, x: Array.from(f.x)}};"
        ),
    )
    .await
}

/// Dispatch a pointer event on panel `panel`'s canvas at scene point (x, y).
async fn pointer(client: &Client, panel: u64, kind: &str, x: f64, y: f64) {
    js(
        client,
        &format!(
            "const v = window.__viewer; const [cx, cy] = v.clientPoint({panel}, {x}, {y});
             const canvas = v.panels.get({panel}).dom.canvas;
             canvas.dispatchEvent(new PointerEvent('{kind}', {{clientX: cx, clientY: cy,
                 pointerId: 1, bubbles: true, isPrimary: true, button: 0, buttons: 1}}));
             return null;"
        ),
    )
    .await;
}

/// The text of the shipped scene `name`.
fn shipped(name: &str) -> String {
    bead_viewer::scenes::SHIPPED
        .iter()
        .find(|(n, _)| *n == name)
        .unwrap_or_else(|| panic!("no shipped scene {name}"))
        .1
        .to_string()
}

/// Press Play/Pause (every panel running) and wait until every panel is paused.
async fn pause_all(client: &Client) {
    js(
        client,
        "document.getElementById('play').click(); return null;",
    )
    .await;
    wait_within(
        client,
        "[...window.__viewer.panels.values()].every(p => p.frame && p.frame.status === 'paused')",
        "a pause",
        Duration::from_secs(30),
    )
    .await;
}

/// Turn every kind of arrow off.
async fn arrows_off(client: &Client) {
    js(
        client,
        "for (const k of ['velocity', 'gravity', 'applied', 'constraint']) {
           const b = document.getElementById('arrow-' + k); b.checked = false; b.dispatchEvent(new Event('change'));
         }
         return null;",
    )
    .await;
}

/// One browser test at a time: each starts chromium, and the large scenes keep a core busy.
static BROWSER: std::sync::Mutex<()> = std::sync::Mutex::new(());

type Checks = for<'a> fn(&'a Client, SocketAddr) -> LocalBoxFuture<'a, ()>;

/// Serve `config` on 127.0.0.1 and run `checks` in headless Chromium against it (skipped
/// with a notice when the browser is missing, unless `BEAD_REQUIRE_BROWSER=1`).
fn in_browser(config: ServerConfig, checks: Checks) {
    in_browser_at(Site::Served(config), checks)
}

/// Run `checks` in headless Chromium against `site` (skipped as [`in_browser`] is).
fn in_browser_at(site: Site, checks: Checks) {
    let (chromium, chromedriver) = match browser() {
        Ok(found) => found,
        Err(why) => {
            if std::env::var("BEAD_REQUIRE_BROWSER").as_deref() == Ok("1") {
                panic!("BEAD_REQUIRE_BROWSER=1 but {why} (apt-get install -y chromium chromium-driver)");
            }
            // Straight to stderr, past the test harness's capture, so that the skip shows.
            use std::io::Write as _;
            let _ = writeln!(
                std::io::stderr(),
                "skipping the browser test: {why} (set BEAD_REQUIRE_BROWSER=1 to fail instead)"
            );
            return;
        }
    };
    let _one_at_a_time = BROWSER.lock().unwrap_or_else(|e| e.into_inner());
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    runtime.block_on(end_to_end(chromium, chromedriver, site, checks));
}

/// What the browser opens: a bead server, or a static folder served by a plain static file
/// server (Python's `http.server`: no bead process; the engine runs in the page).
enum Site {
    Served(ServerConfig),
    Static(PathBuf),
}

/// Kills the static file server when the test ends.
struct StaticServer(Child);

impl Drop for StaticServer {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Serve `dir` on 127.0.0.1 with `python3 -m http.server`, once it accepts connections.
fn static_server(dir: &Path) -> (StaticServer, SocketAddr) {
    let port = free_port();
    let python = std::env::var_os("BEAD_PYTHON").unwrap_or_else(|| "python3".into());
    let server = StaticServer(
        Command::new(&python)
            .args([
                "-m",
                "http.server",
                &port.to_string(),
                "--bind",
                "127.0.0.1",
                "--directory",
            ])
            .arg(dir)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {python:?} -m http.server: {e}")),
    );
    let addr = SocketAddr::from(([127, 0, 0, 1], port));
    let start = Instant::now();
    let mut server = server;
    while TcpStream::connect(addr).is_err() {
        // A server that could not bind (the port taken since `free_port`) exits: say so
        // rather than wait, or talk to whatever holds the port.
        if let Ok(Some(status)) = server.0.try_wait() {
            panic!("the static file server exited ({status}) before it listened on {addr}");
        }
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "the static file server did not start"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    (server, addr)
}

/// Every shipped scene is in the page's picker, in the catalog's order, and each, chosen
/// there, loads and is drawn in every panel (the singular curves' implicit panel may have
/// stopped at the singular point, saying so).
#[test]
fn every_shipped_scene_is_in_the_picker_and_drawn() {
    in_browser(ServerConfig::default(), |client, addr| {
        picker_checks(client, addr).boxed_local()
    });
}

async fn picker_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_until(
        client,
        "window.__viewer && window.__viewer.scene",
        "the page",
    )
    .await;
    let listed = js(
        client,
        "return [...document.getElementById('scene-select').options].map(o => o.value);",
    )
    .await;
    let shipped: Vec<&str> = bead_viewer::scenes::SHIPPED
        .iter()
        .map(|(n, _)| *n)
        .collect();
    assert_eq!(listed, json!(shipped));
    for name in shipped {
        js(
            client,
            &format!(
                "window.__viewer.scene.replaced = true;
                 const s = document.getElementById('scene-select'); s.value = '{name}';
                 s.dispatchEvent(new Event('change')); return null;"
            ),
        )
        .await;
        wait_within(
            client,
            &format!(
                "!window.__viewer.scene.replaced && window.__viewer.scene.name === '{name}' && \
                 window.__viewer.panels.size > 0 && \
                 [...window.__viewer.panels.values()].every(p => p.frame && \
                 p.frame.epoch === p.info.epoch && p.lastDraw && \
                 (p.frame.steps > 0 || p.frame.status === 'failed'))"
            ),
            &format!("{name} loaded and drawn"),
            Duration::from_secs(60),
        )
        .await;
        // A |C| chart only where there is a C; energies in the scene's unit.
        let shown = js(
            client,
            "const s = window.__viewer.scene;
             return [...window.__viewer.panels.values()].map(p => [p.dom.chartC.hidden === (s.constraints.length === 0), s.energy_unit || null]);",
        )
        .await;
        // The article's pixel scenes (the parabolas and the ball in its bowl).
        let unit = if name.starts_with("parabola") || name == "bounce" {
            "kg px^2/s^2"
        } else {
            "J"
        };
        for panel in shown.as_array().unwrap() {
            assert_eq!(panel, &json!([true, unit]), "{name}: {shown}");
        }
    }
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// The page stops at the scene's duration (issue 18: it ran forever) and says so; "loop"
/// in the at-the-end picker starts the panels again.
#[test]
fn the_page_stops_at_the_scenes_end_and_loops_on_request() {
    let text = shipped("circle")
        .replace("dt = 0.001", "dt = 0.01")
        .replace("duration = 10.0", "duration = 1.0");
    in_browser(serving("short", text), |client, addr| {
        end_checks(client, addr).boxed_local()
    });
}

async fn end_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    // Every panel paused at its 100th step, t = 1, and the readout says why.
    wait_within(
        client,
        "window.__viewer && window.__viewer.clock && window.__viewer.clock.ended && \
         window.__viewer.panels.size === 2 && [...window.__viewer.panels.values()].every(p => \
         p.frame && p.frame.status === 'paused' && p.frame.steps === 100 && \
         Math.abs(p.frame.t - 1) < 1e-12)",
        "the end of the scene",
        Duration::from_secs(30),
    )
    .await;
    let readout = js(
        client,
        "return document.getElementById('rate').textContent;",
    )
    .await;
    assert!(
        readout.as_str().unwrap().starts_with("ended at t = 1 s"),
        "{readout}"
    );
    assert_eq!(
        js(
            client,
            "return document.getElementById('play').textContent;"
        )
        .await,
        "Play"
    );
    // Loop, then Play: the panels run again and start over at the end.
    let generation = js(client, "return window.__viewer.clock.generation;").await;
    js(
        client,
        "const s = document.getElementById('at-end'); s.value = 'loop';
         s.dispatchEvent(new Event('change'));
         document.getElementById('play').click(); return null;",
    )
    .await;
    wait_within(
        client,
        &format!(
            "window.__viewer.clock.at_end === 'loop' && !window.__viewer.clock.ended && \
             window.__viewer.clock.generation >= {generation} + 2 && \
             [...window.__viewer.panels.values()].every(p => p.frame && p.frame.status === 'running')"
        ),
        "a loop",
        Duration::from_secs(30),
    )
    .await;
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// The distance (scene units) of each panel's first particle to the nearest segment of the
/// curves the page draws for it (`p.curves`), as JSON numbers.
const BEAD_TO_DRAWN_WIRE: &str = "
    const dim = window.__viewer.scene.dim;
    return [...window.__viewer.panels.values()].map(p => {
      const x = p.frame.x; let best = Infinity;
      for (const line of (p.curves || p.info.curves)) {
        for (let i = 0; i + 2 * dim <= line.length; i += dim) {
          let ab2 = 0, t = 0;
          for (let a = 0; a < dim; a++) { const d = line[i + dim + a] - line[i + a]; ab2 += d * d; t += d * (x[a] - line[i + a]); }
          t = ab2 > 0 ? Math.min(1, Math.max(0, t / ab2)) : 0;
          let d2 = 0;
          for (let a = 0; a < dim; a++) { const e = x[a] - line[i + a] - t * (line[i + dim + a] - line[i + a]); d2 += e * e; }
          best = Math.min(best, Math.sqrt(d2));
        }
      }
      return best;
    });";

#[test]
fn the_helix_wire_is_under_the_bead_at_the_end_and_after_a_loop() {
    // The helix ends at 4.9 s, where the bead has slid to phi = -7.9, past the first drawn
    // interval [-2 pi, 2 pi] of its wire.
    let text = shipped("helix").replace("duration = 5.0", "duration = 4.9");
    in_browser(serving("helix", text), |client, addr| {
        helix_checks(client, addr).boxed_local()
    });
}

async fn helix_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    // Five times real time (the page's time-scale control), so that the test takes seconds.
    wait_within(
        client,
        "window.__viewer && window.__viewer.panels.size === 2",
        "the panels",
        Duration::from_secs(30),
    )
    .await;
    js(
        client,
        "const s = document.getElementById('time-scale'); s.value = '5';
         s.dispatchEvent(new Event('change')); return null;",
    )
    .await;
    wait_within(
        client,
        "window.__viewer && window.__viewer.clock && window.__viewer.clock.ended && \
         window.__viewer.panels.size === 2 && [...window.__viewer.panels.values()].every(p => \
         p.frame && p.frame.status === 'paused' && Math.abs(p.frame.t - 4.9) < 1e-9)",
        "the end of the scene",
        Duration::from_secs(60),
    )
    .await;
    let distances = js(client, BEAD_TO_DRAWN_WIRE).await;
    for d in distances.as_array().unwrap() {
        assert!(
            d.as_f64().unwrap() < 1e-3,
            "bead to drawn wire at 4.9 s: {distances}"
        );
    }
    // Loop: past the end into the next run, the wire is still under the bead.
    let generation = js(client, "return window.__viewer.clock.generation;").await;
    js(
        client,
        "const s = document.getElementById('at-end'); s.value = 'loop';
         s.dispatchEvent(new Event('change'));
         document.getElementById('play').click(); return null;",
    )
    .await;
    wait_within(
        client,
        &format!(
            "window.__viewer.clock.generation >= {generation} + 2 && \
             [...window.__viewer.panels.values()].every(p => p.frame && p.frame.t > 0.5)"
        ),
        "a loop",
        Duration::from_secs(60),
    )
    .await;
    pause_all(client).await;
    let distances = js(client, BEAD_TO_DRAWN_WIRE).await;
    for d in distances.as_array().unwrap() {
        assert!(
            d.as_f64().unwrap() < 1e-3,
            "bead to drawn wire after a loop: {distances}"
        );
    }
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

#[test]
fn zooming_out_draws_the_curve_over_the_whole_view() {
    in_browser(ServerConfig::default(), |client, addr| {
        zoom_checks(client, addr).boxed_local()
    });
}

async fn zoom_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.scene && window.__viewer.scene.name === 'parabola' && \
         window.__viewer.panels.has(1) && window.__viewer.panels.get(1).frame",
        "the parabola",
        Duration::from_secs(30),
    )
    .await;
    // Zoom out 20 times: the page shows far more than the contours were made over, asks for
    // them over what it shows, and draws the parabola (y = -x^2 / 100) down to the new
    // bottom edge, ten times deeper than the view box.
    js(client, "window.__viewer.zoom(1, 0.05); return null;").await;
    wait_within(
        client,
        "(() => { const p = window.__viewer.panels.get(1), c = p.info.curve_region;
                  const w = c[2] - c[0];
                  return p.curveRegion[2] - p.curveRegion[0] > 15 * w &&
                    p.curves.some(l => l[1] < 10 * c[1] &&
                                       Math.abs(l[1] + l[0] * l[0] / 100) < 0.02 * l[0] * l[0] / 100); })()",
        "curves over the zoomed-out view",
        Duration::from_secs(30),
    )
    .await;
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

#[test]
fn parameters_are_typed_including_zero_negatives_and_whole_numbers() {
    // The shipped chain at 5 links, released at an angle theta0 from the downward vertical.
    let text = shipped("chain")
        .replace("N = { value = 1000,", "N = { value = 5,")
        .replace(
            "[world]",
            "theta0 = { value = \"pi/2\", unit = \"rad\", range = [\"-pi\", \"pi\"] }   # release angle\n\n[world]",
        )
        .replace(
            "position = [\"(i+1)*L\", 0.0]",
            "position = [\"(i+1)*L*sin(theta0)\", \"(i+1)*L*cos(theta0)\"]",
        );
    in_browser(serving("angled-chain", text), |client, addr| {
        param_checks(client, addr).boxed_local()
    });
}

async fn param_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.scene && window.__viewer.scene.params.length === 4 && \
         document.querySelector('#params .param[data-param=\"theta0\"] .param-value')",
        "the parameters",
        Duration::from_secs(30),
    )
    .await;
    let value =
        |name: &str| format!("window.__viewer.scene.params.find(p => p.name === '{name}').value");
    // Units and descriptions on the page; whole numbers step by 1.
    let shown = js(
        client,
        "const row = (n) => document.querySelector(`#params .param[data-param=\"${n}\"]`);
         const n = row('N').querySelector('input[type=range]');
         return [row('theta0').textContent, row('g').textContent, n.step, n.min, n.max];",
    )
    .await;
    let shown = shown.as_array().unwrap();
    assert!(
        shown[0].as_str().unwrap().contains("rad")
            && shown[0].as_str().unwrap().contains("release angle"),
        "{shown:?}"
    );
    assert!(
        shown[1].as_str().unwrap().contains("m/s^2")
            && shown[1]
                .as_str()
                .unwrap()
                .contains("gravitational acceleration"),
        "{shown:?}"
    );
    assert_eq!(&shown[2..], &[json!("1"), json!("1"), json!("2000")]);
    // Typed: 0, a negative expression; the slider's right end is pi exactly.
    for (typed, expected) in [("'0'", "0"), ("'-pi/4'", "-Math.PI / 4")] {
        js(
            client,
            &format!("window.__viewer.setParam('theta0', {typed}); return null;"),
        )
        .await;
        wait_within(
            client,
            &format!("{} === {expected}", value("theta0")),
            "the typed value",
            Duration::from_secs(30),
        )
        .await;
    }
    js(
        client,
        "const s = document.querySelector('#params .param[data-param=\"theta0\"] input[type=range]');
         s.value = s.max; s.dispatchEvent(new Event('input')); s.dispatchEvent(new Event('change'));
         return null;",
    )
    .await;
    wait_within(
        client,
        &format!("{} === Math.PI", value("theta0")),
        "theta0 = pi from the slider's end",
        Duration::from_secs(30),
    )
    .await;
    // A whole number of links, then one that is not: refused and said.
    js(client, "window.__viewer.setParam('N', '7'); return null;").await;
    wait_within(
        client,
        &format!(
            "{} === 7 && window.__viewer.scene.particles.length === 7",
            value("N")
        ),
        "N = 7",
        Duration::from_secs(30),
    )
    .await;
    js(client, "window.__viewer.setParam('N', '7.5'); return null;").await;
    wait_within(
        client,
        "document.getElementById('messages').textContent.includes('parameter `N` is a whole number, got 7.5')",
        "the whole-number message",
        Duration::from_secs(30),
    )
    .await;
    screenshot(client, "params").await;
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

#[test]
fn arrows_show_the_rods_force_to_scale() {
    let text = shipped("circle");
    in_browser(serving("circle", text), |client, addr| {
        arrow_checks(client, addr).boxed_local()
    });
}

async fn arrow_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    // Running, then paused a moment later: the state the arrows are drawn at.
    wait_within(
        client,
        "window.__viewer && window.__viewer.panels.size === 2 && \
         [...window.__viewer.panels.values()].every(p => p.frame && p.frame.t > 0.4 && p.frame.arrows)",
        "the pendulum swinging",
        Duration::from_secs(30),
    )
    .await;
    pause_all(client).await;
    let toggles = js(
        client,
        "return ['velocity', 'gravity', 'applied', 'constraint'].map(k => document.getElementById('arrow-' + k).checked);",
    )
    .await;
    assert_eq!(
        toggles,
        json!([true, true, true, true]),
        "arrows on for one particle"
    );
    let ids: Vec<u64> = js(client, "return [...window.__viewer.panels.keys()];")
        .await
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    for (k, id) in ids.iter().enumerate() {
        let got = js(
            client,
            &format!(
                "window.__viewer.drawTimes({id}, 1);
                 const f = window.__viewer.panels.get({id}).frame;
                 return [window.__viewer.arrowsOf({id}), [...f.x], f.arrows];"
            ),
        )
        .await;
        let (drawn, x, arrows) = (&got[0], &got[1], &got[2]);
        let list = drawn["arrows"].as_array().unwrap();
        let kinds: Vec<&str> = list.iter().map(|a| a["kind"].as_str().unwrap()).collect();
        // No applied forces in this scene: v, m g and the constraint force.
        assert_eq!(kinds, ["velocity", "gravity", "constraint"], "panel {id}");
        let c = list.iter().find(|a| a["kind"] == "constraint").unwrap();
        let length = (c["x1"].as_f64().unwrap() - c["x0"].as_f64().unwrap())
            .hypot(c["y1"].as_f64().unwrap() - c["y0"].as_f64().unwrap());
        // The rod's force from Newton's law at the server's state (m = 1, g = 9.81, L = 1):
        // T = m (g y / r + |v|^2 / r).
        let (x, v) = (
            [x[0].as_f64().unwrap(), x[1].as_f64().unwrap()],
            [
                arrows["velocity"][0].as_f64().unwrap(),
                arrows["velocity"][1].as_f64().unwrap(),
            ],
        );
        let r = x[0].hypot(x[1]);
        let tension = 9.81 * x[1] / r + (v[0] * v[0] + v[1] * v[1]) / r;
        let pixels_per_newton =
            drawn["scales"]["force"].as_f64().unwrap() * drawn["pixelsPerUnit"].as_f64().unwrap();
        let expected = tension.abs() * pixels_per_newton;
        assert!(expected > 20.0, "a visible arrow: {expected} px");
        assert!(
            (length - expected).abs() < 1.0,
            "panel {id}: drawn {length} px, Newton {expected} px"
        );
        // The implicit panel labels it lambda grad C and the server's lambda |grad C| is it.
        if k == 0 {
            assert_eq!(c["label"], "λ∇C");
            let row = &arrows["rows"][0];
            let server =
                row["lambda"].as_f64().unwrap().abs() * row["gradient_norm"].as_f64().unwrap();
            assert!(
                (server * pixels_per_newton - length).abs() < 1.0,
                "{server} N vs {length} px"
            );
        } else {
            assert_eq!(c["label"], "F_c");
        }
    }
    screenshot(client, "arrows").await;

    // Paused, drag the tip of the implicit panel's velocity arrow on along itself: every
    // panel restarts at t = 0 with the longer velocity (along the circle, so kept whole).
    let id = ids[0];
    let before = js(
        client,
        &format!(
            "window.__viewer.drawTimes({id}, 1);
             const a = window.__viewer.arrowsOf({id}).arrows.find(a => a.kind === 'velocity');
             const f = window.__viewer.panels.get({id}).frame;
             return [a.x0, a.y0, a.x1, a.y1, Math.hypot(f.arrows.velocity[0], f.arrows.velocity[1]), f.epoch];"
        ),
    )
    .await;
    let b: Vec<f64> = before
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let (length, speed) = ((b[2] - b[0]).hypot(b[3] - b[1]), b[4]);
    let (ux, uy) = ((b[2] - b[0]) / length, (b[3] - b[1]) / length);
    let to = (b[2] + 40.0 * ux, b[3] + 40.0 * uy);
    let canvas_event = |kind: &str, (cx, cy): (f64, f64)| {
        format!(
            "const c = window.__viewer.panels.get({id}).dom.canvas, r = c.getBoundingClientRect();
             c.dispatchEvent(new PointerEvent('{kind}', {{clientX: r.left + {cx} * r.width / c.width,
                 clientY: r.top + {cy} * r.height / c.height, pointerId: 1, bubbles: true,
                 isPrimary: true, button: 0, buttons: 1}}));
             return null;"
        )
    };
    js(client, &canvas_event("pointerdown", (b[2], b[3]))).await;
    js(client, &canvas_event("pointermove", to)).await;
    js(client, &canvas_event("pointerup", to)).await;
    let epoch = b[5];
    wait_within(
        client,
        &format!(
            "[...window.__viewer.panels.values()].every(p => p.frame && p.frame.epoch > {epoch} && p.frame.t === 0 && p.frame.arrows)"
        ),
        "the restart with the dragged velocity",
        Duration::from_secs(30),
    )
    .await;
    let speeds = js(
        client,
        "return [...window.__viewer.panels.values()].map(p => Math.hypot(p.frame.arrows.velocity[0], p.frame.arrows.velocity[1]));",
    )
    .await;
    let expected = speed * (length + 40.0) / length;
    for v in speeds.as_array().unwrap() {
        let v = v.as_f64().unwrap();
        assert!(
            (v - expected).abs() < 0.02 * expected,
            "dragged speed {v}, expected {expected}"
        );
    }
    // Typed: at the bottom, 1.5 m/s to the right, in both panels.
    js(
        client,
        "const boxes = [...document.querySelectorAll('#start-state .start-value')];
         const values = ['0', '1', '1.5', '0'];
         boxes.forEach((b, i) => { b.value = values[i]; b.dispatchEvent(new Event('input')); });
         document.querySelector('#start-state .start-set').click(); return null;",
    )
    .await;
    wait_within(
        client,
        "[...window.__viewer.panels.values()].every(p => p.frame && p.frame.t === 0 && p.frame.arrows && \
           Math.abs(p.frame.x[0]) < 1e-9 && Math.abs(p.frame.x[1] - 1) < 1e-9 && \
           Math.abs(p.frame.arrows.velocity[0] - 1.5) < 1e-9 && Math.abs(p.frame.arrows.velocity[1]) < 1e-9)",
        "the typed start",
        Duration::from_secs(30),
    )
    .await;
    // Off: nothing drawn.
    arrows_off(client).await;
    let none = js(
        client,
        &format!(
            "window.__viewer.drawTimes({}, 1); return window.__viewer.arrowsOf({}).arrows.length;",
            ids[0], ids[0]
        ),
    )
    .await;
    assert_eq!(none, json!(0));
    // The helix: two rows act on the bead, their forces drawn faint and their sum (the
    // particle's constraint force) in full, equal to the faint ones added tip to tail; the
    // sum is the parametric panel's reaction F_c at the same t (the same physics).
    js(
        client,
        "const s = document.getElementById('scene-select'); s.value = 'helix'; s.dispatchEvent(new Event('change'));
         const b = document.getElementById('arrow-constraint'); b.checked = true; b.dispatchEvent(new Event('change'));
         return null;",
    )
    .await;
    wait_within(
        client,
        "window.__viewer.scene.name === 'helix' && window.__viewer.panels.size === 2 && \
         [...window.__viewer.panels.values()].every(p => p.frame && p.frame.epoch === p.info.epoch && p.frame.t > 0.5 && p.frame.arrows)",
        "the helix running",
        Duration::from_secs(30),
    )
    .await;
    pause_all(client).await;
    let got = js(
        client,
        "const [a, b] = [...window.__viewer.panels.values()];
         const arrows = (p) => { window.__viewer.drawTimes(p.info.id, 1); return window.__viewer.arrowsOf(p.info.id).arrows.filter(x => x.kind === 'constraint'); };
         return [arrows(a), [...a.frame.arrows.constraint, ...b.frame.arrows.constraint], a.frame.t, b.frame.t];",
    )
    .await;
    assert_eq!(got[2], got[3], "one clock: {got}");
    let implicit = got[0].as_array().unwrap();
    let faint: Vec<&Value> = implicit
        .iter()
        .filter(|a| a["faint"] == json!(true))
        .collect();
    let total: Vec<&Value> = implicit
        .iter()
        .filter(|a| a["label"] == json!("Σλ∇C"))
        .collect();
    assert_eq!((faint.len(), total.len()), (2, 1), "{implicit:?}");
    let vector = |a: &Value| {
        [
            a["x1"].as_f64().unwrap() - a["x0"].as_f64().unwrap(),
            a["y1"].as_f64().unwrap() - a["y0"].as_f64().unwrap(),
        ]
    };
    let sum = [0, 1].map(|i| vector(faint[0])[i] + vector(faint[1])[i]);
    let whole = vector(total[0]);
    assert!(
        (sum[0] - whole[0]).hypot(sum[1] - whole[1]) < 1.0,
        "{sum:?} {whole:?}"
    );
    let f: Vec<f64> = got[1]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let size = f[..3].iter().map(|v| v * v).sum::<f64>().sqrt();
    let apart = (0..3)
        .map(|i| (f[i] - f[3 + i]).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(size > 1.0 && apart < 1e-4 * size, "{f:?}");
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

#[test]
fn presentation_mode_fits_a_projector_without_scrolling() {
    in_browser(ServerConfig::default(), |client, addr| {
        presentation_checks(client, addr).boxed_local()
    });
}

/// For every panel: whether its canvas, energy bars and energy chart lie inside the
/// window, the canvas's CSS width, and the clock drawn on the canvas.
const PRESENTED: &str = "
    return [...window.__viewer.panels.values()].map(p => {
      const inside = (e) => { const r = e.getBoundingClientRect();
        return r.width > 0 && r.top >= 0 && r.left >= 0 && r.bottom <= window.innerHeight && r.right <= window.innerWidth; };
      window.__viewer.drawTimes(p.info.id, 1);
      return { canvas: inside(p.dom.canvas), bars: inside(p.dom.bars), chart: inside(p.dom.chartE),
               width: p.dom.canvas.getBoundingClientRect().width, clock: p.lastClock && p.lastClock.text[0],
               scrolls: document.documentElement.scrollHeight > window.innerHeight + 1,
               viewport: [window.innerWidth, window.innerHeight] };
    });";

async fn presentation_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.panels.size === 2 && \
         [...window.__viewer.panels.values()].every(p => p.frame)",
        "the panels",
        Duration::from_secs(30),
    )
    .await;
    js(client, "window.__viewer.setPresenting(true); return null;").await;
    for (w, h, min_width) in [(1920u32, 1080u32, 600.0), (1366, 768, 360.0)] {
        client.set_window_size(w, h).await.unwrap();
        // The resize reaches the page, then its layout settles.
        wait_within(
            client,
            &format!("window.innerWidth <= {w} && window.outerWidth === {w}"),
            "the window size",
            Duration::from_secs(30),
        )
        .await;
        js(
            client,
            "window.dispatchEvent(new Event('resize')); return null;",
        )
        .await;
        let shown = js(client, PRESENTED).await;
        for panel in shown.as_array().unwrap() {
            assert_eq!(panel["canvas"], true, "{w}x{h}: {shown}");
            assert_eq!(panel["bars"], true, "{w}x{h}: {shown}");
            assert_eq!(panel["chart"], true, "{w}x{h}: {shown}");
            assert_eq!(panel["scrolls"], false, "{w}x{h}: {shown}");
            assert!(
                panel["width"].as_f64().unwrap() >= min_width,
                "{w}x{h}: {shown}"
            );
            assert!(
                panel["clock"].as_str().unwrap().starts_with("t = "),
                "{shown}"
            );
        }
        screenshot(client, &format!("present-{w}x{h}")).await;
    }
    js(client, "window.__viewer.setPresenting(false); return null;").await;
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

#[test]
fn export_and_refresh_keep_what_the_page_shows() {
    let text = shipped("circle");
    in_browser(serving("circle", text), |client, addr| {
        export_checks(client, addr).boxed_local()
    });
}

async fn export_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.panels.size === 2 && \
         [...window.__viewer.panels.values()].every(p => p.frame && p.frame.t > 0.5)",
        "the pendulum swinging",
        Duration::from_secs(30),
    )
    .await;
    pause_all(client).await;
    let got = js(
        client,
        "const id = [...window.__viewer.panels.keys()][0], f = window.__viewer.panels.get(id).frame;
         return [window.__viewer.panelCsv(id), [f.t, ...f.x, ...f.arrows.velocity, f.energy]];",
    )
    .await;
    let csv = got[0].as_str().unwrap();
    let last_frame: Vec<f64> = got[1]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let lines: Vec<&str> = csv.lines().collect();
    assert!(
        lines[0].starts_with("# Bead on a circle") && lines[0].contains("theta0 = "),
        "{}",
        lines[0]
    );
    assert_eq!(
        lines[1],
        "t,bead.x,bead.y,bead.vx,bead.vy,kinetic,potential,energy,work,energy_error,constraint_error,lambda0"
    );
    let rows: Vec<Vec<f64>> = lines[2..]
        .iter()
        .map(|l| l.split(',').map(|v| v.parse::<f64>().unwrap()).collect())
        .collect();
    assert!(rows.len() > 20, "{} rows", rows.len());
    for row in &rows {
        // On the circle of radius 1 and T = m |v|^2 / 2, computed here, not by bead.
        assert!((row[1].hypot(row[2]) - 1.0).abs() < 1e-6, "{row:?}");
        assert!(
            (row[5] - 0.5 * (row[3] * row[3] + row[4] * row[4])).abs() < 1e-12 * (1.0 + row[5]),
            "{row:?}"
        );
        assert!(row[0] >= 0.0);
    }
    assert!(rows.windows(2).all(|w| w[1][0] > w[0][0]), "times increase");
    // The last row is the last frame, bit for bit.
    let last = rows.last().unwrap();
    assert_eq!(&last[..5], &last_frame[..5]);
    assert_eq!(last[7], last_frame[5]);
    // The picture: a PNG of the canvas's size.
    let size = js(
        client,
        "const url = window.__viewer.panelPng([...window.__viewer.panels.keys()][0]);
         if (!url.startsWith('data:image/png;base64,')) return url.slice(0, 30);
         const img = new Image(); img.src = url; await img.decode(); return [img.naturalWidth, img.naturalHeight];",
    )
    .await;
    assert_eq!(size, json!([920, 680]));

    // A parameter and the time scale, then a refresh: the page comes back to them.
    js(client, "window.__viewer.setParam('g', '5'); return null;").await;
    wait_within(
        client,
        "window.__viewer.scene.params.find(p => p.name === 'g').value === 5",
        "g = 5",
        Duration::from_secs(30),
    )
    .await;
    js(
        client,
        "const s = document.getElementById('time-scale'); s.value = '2'; s.dispatchEvent(new Event('change')); return null;",
    )
    .await;
    wait_within(
        client,
        "location.search.includes('param.g=5') && location.search.includes('ts=2')",
        "the address bar",
        Duration::from_secs(30),
    )
    .await;
    client.refresh().await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.scene && window.__viewer.restore === null && \
         window.__viewer.scene.params.find(p => p.name === 'g').value === 5 && window.__viewer.timeScale === 2 && \
         window.__viewer.panels.size === 2",
        "the page after a refresh",
        Duration::from_secs(30),
    )
    .await;
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// A curve edit and a typed start state go into the address bar, and a refresh (or the
/// share URL opened elsewhere) comes back to them: the implicit panel's edited curve and
/// every panel starting from the placed state, bit for bit.
#[test]
fn the_share_url_keeps_curve_edits_and_the_start_state() {
    let text = shipped("circle");
    in_browser(serving("circle", text), |client, addr| {
        share_checks(client, addr).boxed_local()
    });
}

async fn share_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.panels.size === 2 && \
         [...window.__viewer.panels.values()].every(p => p.frame)",
        "the panels",
        Duration::from_secs(30),
    )
    .await;
    pause_all(client).await;
    // The curve, as a user edits it: a circle of radius 1.5 for the implicit panel.
    js(
        client,
        "const row = document.querySelector('#curves .curve-edit'); row.querySelector('.curve-expr').value = 'bead.x^2 + bead.y^2 - 2.25';
         row.querySelector('.curve-apply').click(); return null;",
    )
    .await;
    wait_within(
        client,
        "[...window.__viewer.panels.values()][0].info.exprs[0] === 'bead.x^2 + bead.y^2 - 2.25' && location.search.includes('curve.0=')",
        "the edited curve in the address bar",
        Duration::from_secs(30),
    )
    .await;
    pause_all_if_running(client).await;
    // A typed start: on the new circle, at 3 o'clock, moving down.
    js(
        client,
        "const inputs = [...document.querySelectorAll('#start-state .start-value')];
         const values = ['1.5', '0', '0', '2'];
         inputs.forEach((input, i) => { input.value = values[i]; input.dispatchEvent(new Event('input')); });
         document.querySelector('#start-state .start-set').click(); return null;",
    )
    .await;
    wait_within(
        client,
        "location.search.includes('start.x=') && location.search.includes('curve.0=')",
        "the start in the address bar",
        Duration::from_secs(30),
    )
    .await;
    let before = js(
        client,
        "const p = [...window.__viewer.panels.values()][0];
         return [location.search, window.__viewer.customStart.positions, window.__viewer.customStart.velocities];",
    )
    .await;
    let search = before[0].as_str().unwrap().to_string();
    assert!(
        search.contains("curve.0=bead.x%5E2+%2B+bead.y%5E2+-+2.25"),
        "{search}"
    );
    client.refresh().await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.scene && window.__viewer.restore === null && \
         window.__viewer.panels.size === 2 && window.__viewer.customStart && window.__viewer.customStart.epochs && \
         [...window.__viewer.panels.values()].every(p => p.frame && p.frame.epoch === p.info.epoch)",
        "the page restored",
        Duration::from_secs(30),
    )
    .await;
    let after = js(
        client,
        "const [a, b] = [...window.__viewer.panels.values()];
         return [location.search, a.info.exprs[0], window.__viewer.customStart.positions, window.__viewer.customStart.velocities];",
    )
    .await;
    assert_eq!(after[1], json!("bead.x^2 + bead.y^2 - 2.25"), "{after}");
    // Placed again from the URL's numbers: already on the curve, so the same state.
    assert_eq!(after[2], before[1], "{after} {before}");
    assert_eq!(after[3], before[2], "{after} {before}");
    assert_eq!(after[0].as_str().unwrap(), search);
    // On the edited circle of radius 1.5: the start is there, not on the scene's circle.
    let x = before[1].as_array().unwrap();
    let r = x[0].as_f64().unwrap().hypot(x[1].as_f64().unwrap());
    assert!((r - 1.5).abs() < 1e-12, "{r}");
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// Pause every panel if any runs.
async fn pause_all_if_running(client: &Client) {
    let running = js(
        client,
        "return [...window.__viewer.panels.values()].some(p => p.frame && p.frame.status === 'running');",
    )
    .await;
    if running == json!(true) {
        pause_all(client).await;
    }
}

/// No text is clipped or overlaps other text, at a laptop's 1366x768, a projector's
/// 1920x1080 and a large screen's 2560x1440, for every shipped scene, with the page as it opens, in overlay mode and
/// presenting: every text a canvas drew lies inside the canvas and clear of the others;
/// every text of the page lies inside its panel, clear of the others, and the page does not
/// scroll sideways.
#[test]
fn no_text_is_clipped_or_overlaps_at_laptop_and_projector_sizes() {
    in_browser(ServerConfig::default(), |client, addr| {
        layout_checks(client, addr).boxed_local()
    });
}

/// Two boxes [x0, y0, x1, y1] overlap by more than `slack` in both directions.
fn overlap(a: &[f64], b: &[f64], slack: f64) -> bool {
    a[0].max(b[0]) + slack < a[2].min(b[2]) && a[1].max(b[1]) + slack < a[3].min(b[3])
}

/// What is wrong with a page's text layout (`window.__viewer.textLayout()`), in words.
fn layout_faults(layout: &Value) -> Vec<String> {
    let mut faults = Vec::new();
    let number = |v: &Value| v.as_f64().unwrap();
    for canvas in layout["canvases"].as_array().unwrap() {
        let (w, h) = (number(&canvas["width"]), number(&canvas["height"]));
        let name = canvas["name"].as_str().unwrap();
        let texts: Vec<(String, Vec<f64>)> = canvas["texts"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| {
                (
                    t["text"].as_str().unwrap().to_string(),
                    ["x0", "y0", "x1", "y1"].map(|k| number(&t[k])).to_vec(),
                )
            })
            .collect();
        for (text, b) in &texts {
            if b[0] < -0.5 || b[1] < -0.5 || b[2] > w + 0.5 || b[3] > h + 0.5 {
                faults.push(format!(
                    "{name}: {text:?} at {b:?} leaves the {w}x{h} canvas"
                ));
            }
        }
        for (i, (ta, a)) in texts.iter().enumerate() {
            for (tb, b) in &texts[i + 1..] {
                if overlap(a, b, 1.0) {
                    faults.push(format!("{name}: {ta:?} {a:?} overlaps {tb:?} {b:?}"));
                }
            }
        }
    }
    let nodes = layout["nodes"].as_array().unwrap();
    let width = number(&layout["width"]);
    if number(&layout["scrollWidth"]) > width + 0.5 {
        faults.push(format!(
            "the page scrolls sideways: {} > {width}",
            layout["scrollWidth"]
        ));
    }
    let rects = |n: &Value| -> Vec<Vec<f64>> {
        n["rects"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r.as_array().unwrap().iter().map(number).collect())
            .collect()
    };
    for n in nodes {
        let text = n["text"].as_str().unwrap();
        for r in rects(n) {
            if r[2] > width + 0.5 {
                faults.push(format!(
                    "page: {text:?} at {r:?} past the window's {width} px"
                ));
            }
            if let Some(panel) = n["panel"].as_array() {
                let p: Vec<f64> = panel.iter().map(number).collect();
                if r[0] < p[0] - 0.5 || r[2] > p[2] + 0.5 || r[1] < p[1] - 0.5 || r[3] > p[3] + 0.5
                {
                    faults.push(format!("page: {text:?} at {r:?} leaves its panel {p:?}"));
                }
            }
        }
    }
    for (i, a) in nodes.iter().enumerate() {
        for b in &nodes[i + 1..] {
            for ra in rects(a) {
                for rb in rects(b) {
                    if overlap(&ra, &rb, 1.0) {
                        faults.push(format!(
                            "page: {:?} {ra:?} overlaps {:?} {rb:?}",
                            a["text"], b["text"]
                        ));
                    }
                }
            }
        }
    }
    faults
}

async fn layout_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_until(
        client,
        "window.__viewer && window.__viewer.scene",
        "the page",
    )
    .await;
    let names: Vec<&str> = bead_viewer::scenes::SHIPPED
        .iter()
        .map(|(n, _)| *n)
        .collect();
    let mut faults = Vec::new();
    for (w, h) in [(1366u32, 768u32), (1920, 1080), (2560, 1440)] {
        client.set_window_size(w, h).await.unwrap();
        wait_within(
            client,
            &format!("window.outerWidth === {w}"),
            "the window size",
            Duration::from_secs(30),
        )
        .await;
        for name in &names {
            js(
                client,
                &format!(
                    "window.__viewer.scene.replaced = true;
                     const s = document.getElementById('scene-select'); s.value = '{name}';
                     s.dispatchEvent(new Event('change')); return null;"
                ),
            )
            .await;
            wait_within(
                client,
                &format!(
                    "!window.__viewer.scene.replaced && window.__viewer.scene.name === '{name}' && \
                     window.__viewer.panels.size > 0 && \
                     [...window.__viewer.panels.values()].every(p => p.frame && \
                     p.frame.epoch === p.info.epoch && p.lastDraw && p.history.length > 3 && \
                     (p.frame.steps > 0 || p.frame.status === 'failed'))"
                ),
                &format!("{name} loaded and drawn"),
                Duration::from_secs(60),
            )
            .await;
            let modes: &[&str] = if ["parabola", "circle", "spinning-hoop", "helix"].contains(name)
            {
                &["as it opens", "overlay", "presenting"]
            } else {
                &["as it opens"]
            };
            for mode in modes {
                let setup = match *mode {
                    "overlay" => "window.__viewer.setOverlay(true);",
                    "presenting" => {
                        "window.__viewer.setOverlay(false); window.__viewer.setPresenting(true);"
                    }
                    _ => "",
                };
                let layout = js(
                    client,
                    &format!(
                        "{setup} await new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)));
                         return window.__viewer.textLayout();"
                    ),
                )
                .await;
                assert!(
                    layout["canvases"].as_array().unwrap().len() >= 4,
                    "{name}: {layout}"
                );
                for fault in layout_faults(&layout) {
                    faults.push(format!("{w}x{h} {name} ({mode}): {fault}"));
                }
            }
            js(client, "window.__viewer.setPresenting(false); return null;").await;
        }
    }
    assert!(
        faults.is_empty(),
        "{} faults:\n{}",
        faults.len(),
        faults.join("\n")
    );
    // The check sees what it should: a text put over the toolbar's, and one past a chart's
    // edge, are found.
    let planted = js(
        client,
        "const d = document.createElement('div'); d.textContent = 'planted text';
         d.style.cssText = 'position: absolute; left: 4px; top: 6px; font-size: 20px';
         document.body.appendChild(d);
         const layout = window.__viewer.textLayout();
         d.remove();
         const c = layout.canvases.find(c => c.name.includes('chart-energy'));
         c.texts.push({ text: 'past the edge', x0: c.width - 10, y0: 10, x1: c.width + 40, y1: 30 });
         return layout;",
    )
    .await;
    let found = layout_faults(&planted).join("\n");
    assert!(
        found.contains("\"planted text\"") && found.contains("\"past the edge\""),
        "{found}"
    );
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// The live plot: a panel's x against vx (chosen in its selects), the parametric panel's
/// q' against q, a log axis with nothing to draw, and the overlay's plot of every panel: the
/// newest point of each is the last frame's numbers, drawn where the axes say.
#[test]
fn a_live_plot_of_any_quantity_against_any_other() {
    let text = shipped("circle");
    in_browser(serving("circle", text), |client, addr| {
        live_plot_checks(client, addr).boxed_local()
    });
}

async fn live_plot_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.panels.size === 2 && \
         [...window.__viewer.panels.values()].every(p => p.frame && p.frame.t > 0.5)",
        "the pendulum swinging",
        Duration::from_secs(30),
    )
    .await;
    // Chosen as a user does: the panel's selects.
    let options = js(
        client,
        "const [a, b] = [...window.__viewer.panels.values()];
         const choose = (p, cls, v) => { const s = p.dom.root.querySelector(cls); s.value = v; s.dispatchEvent(new Event('change')); };
         choose(a, '.plot-x', 'bead.x'); choose(a, '.plot-y', 'bead.vx');
         choose(b, '.plot-x', 'theta'); choose(b, '.plot-y', \"theta'\");
         return [[...a.dom.plotY.options].map(o => o.value), [...b.dom.plotY.options].map(o => o.textContent), b.plot];",
    )
    .await;
    let implicit: Vec<&str> = options[0]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    for key in [
        "t",
        "bead.x",
        "bead.vy",
        "energy",
        "constraint_error",
        "lambda0",
    ] {
        assert!(implicit.contains(&key), "{key} in {implicit:?}");
    }
    let labels = options[1].to_string();
    assert!(
        labels.contains("bead velocity vx (m/s)") && labels.contains("coordinate theta"),
        "{labels}"
    );
    assert_eq!(
        options[2],
        json!({"x": "theta", "y": "theta'", "log": false})
    );
    pause_all(client).await;
    // The newest point of each plot is the last frame's, exactly, and is drawn at its pixel.
    wait_within(
        client,
        "(() => { const [a, b] = [...window.__viewer.panels.values()];
           return !!(a.lastPlot && b.lastPlot && a.lastPlot.points > 20 && b.lastPlot.points > 20 &&
             a.lastPlot.last[0][0] === a.frame.x[0] && a.lastPlot.last[0][1] === a.frame.arrows.velocity[0] &&
             b.lastPlot.last[0][0] === b.frame.generalized[0] && b.lastPlot.last[0][1] === b.frame.generalized[1]); })()",
        "each plot's newest point at the last frame",
        Duration::from_secs(30),
    )
    .await;
    let got = js(
        client,
        "const out = [];
         for (const p of window.__viewer.panels.values()) {
           const d = p.lastPlot, c = p.dom.plot, [x, y] = d.last[0];
           const X = d.plot.x0 + (x - d.x[0]) / (d.x[1] - d.x[0]) * (d.plot.x1 - d.plot.x0);
           const Y = d.plot.y0 + (1 - (y - d.y[0]) / (d.y[1] - d.y[0])) * (d.plot.y1 - d.plot.y0);
           out.push([Array.from(c.getContext('2d').getImageData(Math.round(X), Math.round(Y), 1, 1).data), d.data]);
         }
         return out;",
    )
    .await;
    for panel in got.as_array().unwrap() {
        assert_eq!(
            panel[0],
            json!([31, 111, 235, 255]),
            "the newest point's marker: {got}"
        );
    }
    // On the unit circle |x| <= 1 and the speed is at most sqrt(2 g (1 + 1)) (g = 9.81).
    let data = &got[0][1];
    let (xs, vs) = (data["x"].as_array().unwrap(), data["y"].as_array().unwrap());
    assert!(
        xs.iter().all(|v| v.as_f64().unwrap().abs() <= 1.0 + 1e-9),
        "{data}"
    );
    assert!(
        vs.iter()
            .all(|v| v.as_f64().unwrap().abs() <= (4.0f64 * 9.81).sqrt()),
        "{data}"
    );
    assert!(
        xs[1].as_f64().unwrap() > xs[0].as_f64().unwrap() + 0.1,
        "{data}"
    );
    // A log axis with nothing on it (nothing does work on the pendulum: W is exactly 0): said.
    let log = js(
        client,
        "const b = [...window.__viewer.panels.values()][1];
         window.__viewer.setPlot(b.info.id, { x: 't', y: 'work', log: true });
         await new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)));
         return [b.lastPlot, b.dom.plotLog.checked, b.dom.plotY.value];",
    )
    .await;
    assert_eq!(log, json!([{"points": 0}, true, "work"]));
    // Overlay: one plot, every panel in its colour, chosen in the overlay's selects.
    js(
        client,
        "window.__viewer.setOverlay(true);
         for (const [id, v] of [['overlay-plot-x', 'bead.x'], ['overlay-plot-y', 'bead.vx']]) {
           const s = document.getElementById(id); s.value = v; s.dispatchEvent(new Event('change'));
         }
         return null;",
    )
    .await;
    wait_within(
        client,
        "(() => { const o = window.__viewer.overlay.lastPlot, [a, b] = [...window.__viewer.panels.values()];
           return o && o.last.length === 2 && o.last[0][0] === a.frame.x[0] && o.last[0][1] === a.frame.arrows.velocity[0] &&
             o.last[1][0] === b.frame.x[0] && o.last[1][1] === b.frame.arrows.velocity[0]; })()",
        "the overlay's plot of both panels",
        Duration::from_secs(30),
    )
    .await;
    screenshot(client, "live-plot").await;
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

#[test]
fn page_end_to_end() {
    in_browser(ServerConfig::default(), |client, addr| {
        checks(client, addr).boxed_local()
    });
}

async fn end_to_end(chromium: PathBuf, chromedriver: PathBuf, site: Site, checks: Checks) {
    let (_static_server, addr) = match site {
        Site::Served(config) => {
            let listener = bind("127.0.0.1:0".parse().unwrap()).await.unwrap();
            let addr = listener.local_addr().unwrap();
            tokio::spawn(serve(listener, config));
            (None, addr)
        }
        Site::Static(dir) => {
            let (server, addr) = static_server(&dir);
            (Some(server), addr)
        }
    };

    let port = free_port();
    let _driver = Driver(
        Command::new(&chromedriver)
            .arg(format!("--port={port}"))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", chromedriver.display())),
    );
    let start = Instant::now();
    while TcpStream::connect(SocketAddr::from(([127, 0, 0, 1], port))).is_err() {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "chromedriver did not start"
        );
        std::thread::sleep(Duration::from_millis(50));
    }

    let profile = std::env::temp_dir().join(format!(
        "bead-viewer-chromium-{}-{port}",
        std::process::id()
    ));
    let capabilities = json!({
        "goog:chromeOptions": {
            "binary": chromium,
            "args": [
                "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--disable-quic", "--no-first-run", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--window-size=1100,940",
                format!("--user-data-dir={}", profile.display()),
            ],
        }
    });
    let Value::Object(capabilities) = capabilities else {
        unreachable!()
    };
    let connector = hyper_util::client::legacy::connect::HttpConnector::new();
    let client = ClientBuilder::new(connector)
        .capabilities(capabilities)
        .connect(&format!("http://127.0.0.1:{port}"))
        .await
        .expect("cannot open a chromium session");

    // Close the session (chromedriver then quits the browser) even when a check fails.
    let result = std::panic::AssertUnwindSafe(checks(&client, addr))
        .catch_unwind()
        .await;
    let _ = client.close().await;
    let _ = std::fs::remove_dir_all(&profile);
    if let Err(panic) = result {
        std::panic::resume_unwind(panic);
    }
}

async fn checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();

    // Loads, connects, two panels (implicit left, parametric right) that run.
    wait_until(
        client,
        "window.__viewer && window.__viewer.panels.size === 2 && [...window.__viewer.panels.values()].every(p => p.frame && p.frame.t > 0.3)",
        "two running panels",
    )
    .await;
    let titles = js(
        client,
        "return [...document.querySelectorAll('.panel .panel-title')].map(e => e.textContent);",
    )
    .await;
    assert!(titles[0].as_str().unwrap().contains("implicit"), "{titles}");
    assert!(
        titles[1].as_str().unwrap().contains("parametric"),
        "{titles}"
    );

    // The canvases draw: many non-white pixels, some of them the curve's blue.
    let pixels = js(
        client,
        "return [...document.querySelectorAll('canvas.view')].map(c => {
            const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
            let ink = 0, blue = 0;
            for (let i = 0; i < d.length; i += 4) {
                if (d[i] < 240 || d[i + 1] < 240 || d[i + 2] < 240) ink++;
                if (d[i + 2] > 200 && d[i] < 80) blue++;
            }
            return [ink, blue];
        });",
    )
    .await;
    for canvas in pixels.as_array().unwrap() {
        assert!(canvas[0].as_u64().unwrap() > 2000, "blank canvas: {pixels}");
        assert!(
            canvas[1].as_u64().unwrap() > 200,
            "no curve drawn: {pixels}"
        );
    }
    let charts = js(
        client,
        "return [...document.querySelectorAll('canvas.chart')].every(c => {
            const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
            let ink = 0;
            for (let i = 0; i < d.length; i += 4) if (d[i] < 200) ink++;
            return ink > 100;
        });",
    )
    .await;
    assert_eq!(charts, Value::Bool(true), "a chart is blank");

    // Switching the integrator changes the panel and its readout.
    let before = js(
        client,
        "return document.querySelector('.panel[data-panel=\"1\"] .readout').textContent;",
    )
    .await;
    js(
        client,
        "const s = document.querySelector('.panel[data-panel=\"1\"] select.integrator');
         s.value = 'euler'; s.dispatchEvent(new Event('change')); return null;",
    )
    .await;
    wait_until(
        client,
        "document.querySelector('.panel[data-panel=\"1\"] .panel-title').textContent.includes('euler')",
        "the euler panel",
    )
    .await;
    // t > 0.5 in a frame of the euler panel's own epoch: a frame from before the restart
    // has t > 0.5 too, and the error of rk4.
    wait_until(
        client,
        &format!(
            "window.__viewer.panels.get(1).info.integrator === 'euler' && {}",
            current(1, "f.t > 0.5")
        ),
        "the euler panel to run",
    )
    .await;
    let after = js(
        client,
        "return document.querySelector('.panel[data-panel=\"1\"] .readout').textContent;",
    )
    .await;
    assert_ne!(before, after);
    // Explicit Euler gains energy far faster than RK4 on the parametric form.
    let euler = frame(client, 1).await["energy_error"].as_f64().unwrap();
    let rk4 = frame(client, 2).await["energy_error"].as_f64().unwrap();
    assert!(euler > 100.0 * rk4, "euler {euler} vs rk4 {rk4}");

    // Drag with RATTLE (implicit) and in the parametric panel: the bead follows the cursor
    // and stays on the curve.
    js(
        client,
        "const s = document.querySelector('.panel[data-panel=\"1\"] select.integrator');
         s.value = 'rattle'; s.dispatchEvent(new Event('change')); return null;",
    )
    .await;
    wait_until(
        client,
        "document.querySelector('.panel[data-panel=\"1\"] .panel-title').textContent.includes('rattle')",
        "the rattle panel",
    )
    .await;
    // Grab both beads while they run (a drag while paused sets the start state instead, see
    // `comparison_and_teaching_in_the_page`), at a tenth of real time so that they are slow.
    js(
        client,
        "const s = document.getElementById('time-scale'); s.value = '0.1'; s.dispatchEvent(new Event('change')); return null;",
    )
    .await;
    wait_until(
        client,
        &format!(
            "window.__viewer.timeScale === 0.1 && window.__viewer.panels.get(1).info.integrator === 'rattle' && {} && {}",
            current(1, "f.status === 'running'"),
            current(2, "f.status === 'running'")
        ),
        "the slow run",
    )
    .await;
    for panel in [1, 2] {
        // Down where the page drew the bead last, in one script (it moves between scripts).
        js(
            client,
            &format!(
                "const v = window.__viewer, p = v.panels.get({panel}), x = p.lastDraw.x;
                 const [cx, cy] = v.clientPoint({panel}, x[0], x[1]);
                 p.dom.canvas.dispatchEvent(new PointerEvent('pointerdown', {{clientX: cx, clientY: cy,
                     pointerId: 1, bubbles: true, isPrimary: true, button: 0, buttons: 1}}));
                 return null;"
            ),
        )
        .await;
        wait_until(client, &current(panel, "!!f.drag"), "the grab").await;
        let f = frame(client, panel).await;
        let (x, y) = (f["x"][0].as_f64().unwrap(), f["x"][1].as_f64().unwrap());
        for k in 1..=10 {
            let s = k as f64 / 10.0;
            pointer(
                client,
                panel,
                "pointermove",
                x + s * (-100.0 - x),
                y + s * (-60.0 - y),
            )
            .await;
            tokio::time::sleep(Duration::from_millis(30)).await;
        }
    }
    js(
        client,
        "const s = document.getElementById('time-scale'); s.value = '1'; s.dispatchEvent(new Event('change')); return null;",
    )
    .await;
    // The beads follow the cursor: wait for that, however long the machine takes.
    for panel in [1, 2] {
        wait_until(
            client,
            &current(panel, "f.status === 'running' && f.drag && f.x[0] < -50"),
            "the bead to follow the cursor",
        )
        .await;
    }
    for panel in [1, 2] {
        let f = frame(client, panel).await;
        assert!(f["drag"].is_object(), "panel {panel} is not dragging: {f}");
        let (x, y) = (f["x"][0].as_f64().unwrap(), f["x"][1].as_f64().unwrap());
        assert!(x < -50.0, "panel {panel}: the bead did not follow: {f}");
        assert!(
            (x * x + 100.0 * y).abs() < 1e-3,
            "panel {panel}: off the curve: {f}"
        );
        let readout: f64 = js(
            client,
            &format!(
                "return Number(document.querySelector('.panel[data-panel=\"{panel}\"] .r-cerr').dataset.value);"
            ),
        )
        .await
        .as_f64()
        .unwrap();
        assert!(readout < 1e-3, "panel {panel}: |C| readout {readout}");
    }
    for panel in [1, 2] {
        pointer(client, panel, "pointerup", -100.0, -60.0).await;
    }
    wait_until(
        client,
        "[1, 2].every(id => !window.__viewer.panels.get(id).frame.drag)",
        "the release",
    )
    .await;
    tokio::time::sleep(Duration::from_millis(1200)).await;

    // Screenshot: the page mid-run, with trails and charts.
    let png = client.screenshot().await.expect("screenshot");
    let root = workspace_root();
    let target = root.join("target");
    std::fs::create_dir_all(&target).unwrap();
    std::fs::write(target.join("viewer-screenshot.png"), &png).unwrap();
    if std::env::var("BEAD_UPDATE_SCREENSHOT").as_deref() == Ok("1") {
        std::fs::create_dir_all(root.join("docs")).unwrap();
        std::fs::write(root.join("docs/viewer.png"), &png).unwrap();
    }

    // A bad curve expression shows its error inline, under the input, with a caret; the
    // panels keep running.
    let t = frame(client, 1).await["t"].as_f64().unwrap();
    js(
        client,
        "const row = document.querySelector('#curves .curve-edit[data-constraint=\"0\"]');
         row.querySelector('.curve-expr').value = 'bead.x^2 + 100*bead.w';
         row.querySelector('.curve-apply').click(); return null;",
    )
    .await;
    wait_until(
        client,
        "(() => { const e = document.querySelector('#curves .curve-error'); return !e.hidden && e.textContent.includes('no coordinate'); })()",
        "the inline curve error",
    )
    .await;
    let error = js(
        client,
        "return document.querySelector('#curves .curve-error').textContent;",
    )
    .await;
    let error = error.as_str().unwrap();
    assert!(
        error.contains("bead.x^2 + 100*bead.w\n") && error.contains("               ^^^^^^"),
        "{error}"
    );
    wait_until(
        client,
        &current(1, &format!("f.status === 'running' && f.t > {t}")),
        "the panel to run on",
    )
    .await;

    // A valid edit redraws the implicit panel's curve and clears the error.
    js(
        client,
        "const row = document.querySelector('#curves .curve-edit[data-constraint=\"0\"]');
         row.querySelector('.curve-expr').value = 'bead.x^2 + 200*bead.y';
         row.querySelector('.curve-apply').click(); return null;",
    )
    .await;
    wait_until(
        client,
        &format!(
            "window.__viewer.panels.get(1).info.exprs[0] === 'bead.x^2 + 200*bead.y' && document.querySelector('#curves .curve-error').hidden && {}",
            current(1, "f.constraint_error < 1e-3")
        ),
        "the new curve",
    )
    .await;

    // Another scene from the picker.
    js(
        client,
        "const s = document.getElementById('scene-select'); s.value = 'double-pendulum';
         s.dispatchEvent(new Event('change')); return null;",
    )
    .await;
    wait_until(
        client,
        "window.__viewer.scene.name === 'double-pendulum' && window.__viewer.panels.size === 2 && [...window.__viewer.panels.values()].every(p => p.frame && p.frame.epoch === p.info.epoch && p.frame.t > 0.2)",
        "the double pendulum",
    )
    .await;

    // A scene file from disk, through the file picker.
    let file = workspace_root().join("scenes/cycloid.toml");
    let input = client
        .find(fantoccini::Locator::Id("scene-file"))
        .await
        .expect("the file input");
    input
        .send_keys(file.canonicalize().unwrap().to_str().unwrap())
        .await
        .expect("choosing a file");
    wait_until(
        client,
        "window.__viewer.scene.name === 'cycloid.toml' && window.__viewer.panels.size === 1",
        "the scene from the file",
    )
    .await;

    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// A server whose first scene is `text`.
fn serving(name: &str, text: String) -> ServerConfig {
    ServerConfig {
        catalog: Arc::new(Catalog::with_first(NamedScene {
            name: name.into(),
            text,
        })),
        ..ServerConfig::default()
    }
}

/// Save a screenshot of the page as `target/viewer-{name}.png`, to look at.
async fn screenshot(client: &Client, name: &str) {
    let png = client.screenshot().await.expect("screenshot");
    let target = workspace_root().join("target");
    std::fs::create_dir_all(&target).unwrap();
    std::fs::write(target.join(format!("viewer-{name}.png")), &png).unwrap();
}

/// `js` with arguments (`arguments[0]`, ... in the script).
async fn js_with(client: &Client, script: &str, args: Vec<Value>) -> Value {
    client
        .execute(script, args)
        .await
        .unwrap_or_else(|e| panic!("script failed: {e}\n{script}"))
}

/// What panel `panel` drew last (the page's `lastDraw`: rods, particles and pins in its draw
/// list, painting calls) and the checks of the canvas as it is, read in the same script (no
/// draw in between): which rods have no ink at their middle and which particles none at
/// their place, at the positions drawn (`lastDraw.x`: the state at the display time,
/// interpolated between frames; 3D positions through the panel's projection).
async fn drawn(client: &Client, panel: u64) -> Value {
    js(
        client,
        &format!(
            "const v = window.__viewer, p = v.panels.get({panel}), d = p.lastDraw, f = d.frame;
             const dim = v.scene.dim, canvas = p.dom.canvas, ctx = canvas.getContext('2d');
             const image = ctx.getImageData(0, 0, canvas.width, canvas.height).data;
             const inked = (...point) => {{
                 const [px, py] = v.canvasPoint({panel}, ...point);
                 for (let dy = -1; dy <= 1; dy++) for (let dx = -1; dx <= 1; dx++) {{
                     const i = 4 * (Math.round(py + dy) * canvas.width + Math.round(px + dx));
                     if (image[i] < 240 || image[i + 1] < 240 || image[i + 2] < 240) return true;
                 }}
                 return false;
             }};
             const at = (k) => Array.from(d.x.slice(dim * k, dim * k + dim));
             const fixed = (q) => dim === 3 ? [q[0], q[1], q.length > 2 ? q[2] : 0] : q;
             const blankRods = [], blankParticles = [];
             v.scene.rods.forEach((rod, k) => {{
                 const a = at(rod.a), b = rod.b != null ? at(rod.b) : fixed(rod.anchor);
                 if (!inked(...a.map((c, i) => (c + b[i]) / 2))) blankRods.push(k);
             }});
             for (let k = 0; k < v.scene.particles.length; k++) {{
                 if (!inked(...at(k))) blankParticles.push(k);
             }}
             return {{rods: d.rods, particles: d.particles, pins: d.pins, paintCalls: d.paintCalls,
                     sceneRods: v.scene.rods.length, sceneParticles: v.scene.particles.length,
                     scenePins: v.scene.pins.length, dim, steps: f.steps,
                     newest: f === p.frame, blankRods: blankRods.slice(0, 10),
                     blankParticles: blankParticles.slice(0, 10),
                     trails: document.getElementById('trails').checked}};"
        ),
    )
    .await
}

/// Assert that `drawn` (see [`drawn`]) drew the whole scene: `rods` rods, `particles`
/// particles and `pins` pins, each with ink, with a number of painting calls that does not
/// grow with the scene (one path for the rods, one for the particles, one for the anchors
/// and pins, the axes' lines and labels).
fn assert_whole(drawn: &Value, rods: usize, particles: usize, pins: usize) {
    assert_eq!(drawn["sceneRods"], rods, "{drawn}");
    assert_eq!(drawn["sceneParticles"], particles, "{drawn}");
    assert_eq!(drawn["scenePins"], pins, "{drawn}");
    assert_eq!(drawn["rods"], rods, "{drawn}");
    assert_eq!(drawn["particles"], particles, "{drawn}");
    assert_eq!(drawn["pins"], pins, "{drawn}");
    assert_eq!(drawn["blankRods"], json!([]), "rods without ink: {drawn}");
    assert_eq!(
        drawn["blankParticles"],
        json!([]),
        "particles without ink: {drawn}"
    );
    assert_eq!(
        drawn["trails"], false,
        "trails are off by default above 20 particles"
    );
    let calls = drawn["paintCalls"].as_u64().unwrap();
    assert!(calls <= 60, "{calls} painting calls for one draw: {drawn}");
}

/// Draw panel `panel` 31 times, rasterization included (the page reads a pixel back after
/// each draw): the median, the fastest and the slowest, in ms.
async fn draw_times(client: &Client, panel: u64) -> (f64, f64, f64) {
    let times = js(
        client,
        &format!("return window.__viewer.drawTimes({panel}, 31);"),
    )
    .await;
    let mut times: Vec<f64> = times
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    times.sort_by(f64::total_cmp);
    (times[times.len() / 2], times[0], times[times.len() - 1])
}

/// The bound on the median draw time of the tests (ms). The budget is a frame, 16.7 ms at
/// 60 frames/s, and the figures measured are below it (DESIGN.md, Viewer, Scale); the bound
/// is six times the budget because a loaded machine slows the browser too (the 50 x 50
/// cloth: 5 to 8 ms, up to 32 ms with a load average of 10 on 2 cores). What the tests
/// assert exactly is that the scene is drawn whole, in a number of painting calls that does
/// not grow with it.
const DRAW_BOUND_MS: f64 = 100.0;

/// Particles of the chain test.
const CHAIN: usize = 1000;

#[test]
fn a_1000_particle_chain_is_drawn_whole_and_runs() {
    in_browser(
        serving("chain.toml", generated::chain(CHAIN, "rk4")),
        |client, addr| chain_checks(client, addr).boxed_local(),
    );
}

/// A scene served for real, drawn whole, and running: three frames, each later than the
/// last and each drawn. A chain of 1000 rods steps at about 2,600 (rk4) and 3,500 (rattle)
/// steps/s on the sparse solve (release, `frame_cost`), 20 to 30 times real time at
/// dt = 1/120; the waits wait for states, however long the steps take on a loaded machine.
async fn chain_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    let patient = Duration::from_secs(120);
    wait_within(
        client,
        &format!(
            "window.__viewer.scene && window.__viewer.scene.particles.length === {CHAIN} && {}",
            current(1, "true")
        ),
        "the chain's first frame",
        patient,
    )
    .await;
    runs_and_is_drawn_whole(client, "chain of 1000", CHAIN, CHAIN, 0, patient).await;
}

/// Wait for a drawing of panel 1; check it is whole; report its draw time; then wait for
/// three later frames of the panel, each drawn as it is received.
async fn runs_and_is_drawn_whole(
    client: &Client,
    name: &str,
    rods: usize,
    particles: usize,
    pins: usize,
    patient: Duration,
) {
    wait_within(
        client,
        &format!("(() => {{ const d = window.__viewer.panels.get(1).lastDraw; return d && d.particles === {particles}; }})()"),
        "a drawing of the scene",
        patient,
    )
    .await;
    assert_whole(&drawn(client, 1).await, rods, particles, pins);
    let (median, fastest, slowest) = draw_times(client, 1).await;
    eprintln!(
        "{name}: draw {median:.2} ms median, {fastest:.2}..{slowest:.2} ms (31 draws, flushed)"
    );
    assert!(median < DRAW_BOUND_MS, "drawing {name} takes {median} ms");

    // Frames keep coming, each later than the last, and the page draws them: three
    // increases of t in the panel's epoch, each waited for in a frame received, then in a
    // frame drawn.
    for _ in 0..3 {
        let t = frame(client, 1).await["t"].as_f64().unwrap();
        wait_within(
            client,
            &current(1, &format!("f.status === 'running' && f.t > {t}")),
            "a later frame",
            patient,
        )
        .await;
        wait_within(
            client,
            &format!(
                "(() => {{ const p = window.__viewer.panels.get(1), d = p.lastDraw;
                   return d.frame.epoch === p.info.epoch && d.frame.t > {t}; }})()"
            ),
            "the drawing of a later frame",
            patient,
        )
        .await;
    }
    let drawing = drawn(client, 1).await;
    assert_whole(&drawing, rods, particles, pins);
    screenshot(client, &name.replace(' ', "-")).await;
    let stats = js(client, "return window.__viewer.stats;").await;
    let frames = stats["frames"].as_f64().unwrap();
    eprintln!(
        "{name}: {frames} frames received, {:.0} bytes and {:.3} ms of decoding each",
        stats["bytes"].as_f64().unwrap() / frames,
        stats["decodeMs"].as_f64().unwrap() / frames
    );
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// Rows and columns of the 3D cloth served for real: the size of `scenes/cloth.toml`, 2500
/// particles and 4900 rods (loads in about 0.5 s and steps at about 16 steps/s with rattle
/// on the sparse solve, release; `frame_cost`). The waits wait for states, however long
/// the steps take on a loaded machine.
const SERVED_CLOTH: (usize, usize) = (50, 50);

#[test]
fn a_3d_cloth_of_rods_is_drawn_whole_and_runs() {
    let (rows, cols) = SERVED_CLOTH;
    in_browser(
        serving("cloth.toml", generated::cloth_3d(rows, cols, "rattle")),
        |client, addr| cloth_checks(client, addr).boxed_local(),
    );
}

async fn cloth_checks(client: &Client, addr: SocketAddr) {
    let (rows, cols) = SERVED_CLOTH;
    let n = rows * cols;
    client.goto(&format!("http://{addr}/")).await.unwrap();
    let patient = Duration::from_secs(120);
    wait_within(
        client,
        &format!(
            "window.__viewer.scene && window.__viewer.scene.dim === 3 && window.__viewer.scene.particles.length === {n} && {}",
            current(1, &format!("f.x.length === {}", 3 * n))
        ),
        "the cloth's first frame",
        patient,
    )
    .await;
    let rods = generated::cloth_links(rows, cols).len();
    runs_and_is_drawn_whole(client, "3D cloth of 2500", rods, n, 2, patient).await;
}

#[test]
fn the_shipped_cloth_runs_in_real_time_and_says_how_fast() {
    in_browser(serving("cloth.toml", shipped("cloth")), |client, addr| {
        rate_checks(client, addr, "shipped cloth").boxed_local()
    });
}

/// The same for the shipped chain (1000 rods, RATTLE at dt = 1/120 fused along the path:
/// about 90 us a step through `Simulation`, release).
#[test]
fn the_shipped_chain_runs_in_real_time_and_says_how_fast() {
    in_browser(serving("chain.toml", shipped("chain")), |client, addr| {
        rate_checks(client, addr, "shipped chain").boxed_local()
    });
}

/// A shipped scene as served (the cloth: 50 x 50 masses, 4,906 rows, fast-projection at
/// dt = 1/60, about 12 ms a step, release) runs in its panel, and the rate the page shows is
/// the rate it runs at: the page samples every 50 ms its own clock, the frame's t and the
/// session's simulation rate while 2 simulated seconds pass (the scene's end set to go on),
/// and the mean rate shown agrees within 35% with the rate it measures itself (simulated
/// over wall time). Real time on an idle machine is a figure of the README measured with
/// this test (printed), not asserted: a loaded machine runs slower and must say so.
async fn rate_checks(client: &Client, addr: SocketAddr, name: &str) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    let patient = Duration::from_secs(120);
    // Past the scene's 3 s it goes on (a loaded machine may reach 3 s before the window).
    wait_within(
        client,
        "window.__viewer.clock && document.getElementById('at-end')",
        "the page",
        patient,
    )
    .await;
    js(
        client,
        "const s = document.getElementById('at-end'); s.value = 'continue';
         s.dispatchEvent(new Event('change')); return null;",
    )
    .await;
    wait_within(
        client,
        &format!(
            "window.__viewer.clock.at_end === 'continue' && {}",
            current(1, "f.status === 'running' && f.t >= 0.3")
        ),
        "the scene running on past its end",
        patient,
    )
    .await;
    js(
        client,
        "const v = window.__viewer; const p = v.panels.get(1);
         const epoch = p.info.epoch;
         window.__rate = { epoch, samples: [] };
         window.__rate.timer = setInterval(() => {
           const f = p.frame;
           if (!f || f.epoch !== epoch) return;
           window.__rate.samples.push([performance.now(), f.t, v.clock.sim_rate]);
         }, 50);
         return null;",
    )
    .await;
    wait_within(
        client,
        "(() => { const s = window.__rate.samples; return s.length > 1 && s[s.length - 1][1] >= s[0][1] + 2; })()",
        "2 simulated seconds",
        patient,
    )
    .await;
    let samples = js(
        client,
        "clearInterval(window.__rate.timer);
         const p = window.__viewer.panels.get(1);
         return { samples: window.__rate.samples, same: p.info.epoch === window.__rate.epoch };",
    )
    .await;
    assert_eq!(
        samples["same"],
        json!(true),
        "the panel restarted while measured"
    );
    let samples: Vec<[f64; 3]> = serde_json::from_value(samples["samples"].clone()).unwrap();
    let (first, last) = (samples[0], samples[samples.len() - 1]);
    let measured = (last[1] - first[1]) / ((last[0] - first[0]) / 1e3);
    let shown = samples.iter().map(|s| s[2]).sum::<f64>() / samples.len() as f64;
    eprintln!(
        "{name}: {measured:.2}x real time measured by the page, {shown:.2}x shown \
         ({} samples)",
        samples.len()
    );
    assert!(
        (shown - measured).abs() <= 0.35 * measured.max(shown),
        "{name}: the page shows {shown:.2}x real time and measures {measured:.2}x"
    );
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// Rows and columns of the cloth drawn at scale.
const CLOTH: (usize, usize) = (50, 50);

/// The hex digits of `bytes` (to hand a binary frame to the page through WebDriver).
fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[test]
fn a_50_by_50_cloth_is_drawn_whole_within_a_frame() {
    in_browser(ServerConfig::default(), |client, addr| {
        cloth_at_scale(client, addr).boxed_local()
    });
}

/// The page at the scale of `scenes/cloth.toml`: a 50 x 50 cloth of rods in 3D, 2500
/// particles, 4900 rods and 2 pins, independent of the server's speed: the page is shown
/// what a session would send: the scene as
/// `session::scene_info` describes it (no simulation needed), a panel, and binary frames made
/// by the server's `encode_frame`, the cloth swaying frame by frame, handed to the page's
/// message handler as they would come from its socket (which is closed first). Each frame
/// is waited for until drawn; then the drawing is checked whole and its draw time measured.
async fn cloth_at_scale(client: &Client, addr: SocketAddr) {
    let (rows, cols) = CLOTH;
    let n = rows * cols;
    let scene = parse_scene(&generated::cloth_3d(rows, cols, "rk4"), "cloth.toml")
        .expect("the cloth parses");
    let info = scene_info("cloth.toml", &scene);
    let rods = info.rods.len();
    assert_eq!(rods, generated::cloth_links(rows, cols).len());
    let exprs = vec![None; info.constraints.len()];
    let text = |message: ServerMessage| match message.encode().unwrap() {
        Encoded::Text(text) => Value::String(text),
        Encoded::Binary(_) => unreachable!("a frame"),
    };
    let scene_view = info.view;
    let scene_message = text(ServerMessage::Scene(info));
    let panels_message = text(ServerMessage::Panels {
        panels: vec![PanelInfo {
            id: 1,
            epoch: 1,
            method: "implicit".into(),
            integrator: "rk4".into(),
            dt: 1.0 / 120.0,
            ks: 0.0,
            kd: 0.0,
            project: false,
            reference: false,
            exprs,
            curves: Vec::new(),
            curve_source: "none".into(),
            curves_move: false,
            view: scene_view,
            curve_region: scene_view,
            curve_note: None,
            applies: Applies {
                feedback: true,
                project: true,
            },
            coordinates: Vec::new(),
        }],
    });

    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_until(client, &current(1, "true"), "the page's first frame").await;
    js(
        client,
        "const v = window.__viewer; v.ws.onmessage = null; v.ws.close();
         v.stats = {frames: 0, bytes: 0, decodeMs: 0, maxDecodeMs: 0}; return null;",
    )
    .await;
    js_with(
        client,
        "window.__viewer.receive(arguments[0]); window.__viewer.receive(arguments[1]); return null;",
        vec![scene_message, panels_message],
    )
    .await;
    wait_until(
        client,
        &format!("window.__viewer.scene.particles.length === {n} && window.__viewer.panels.has(1)"),
        "the cloth's scene and panel",
    )
    .await;

    let initial: Vec<f64> = scene
        .system
        .particles()
        .iter()
        .flat_map(|p| p.position.iter().copied())
        .collect();
    let frames = 30u64;
    let mut bytes_per_frame = 0;
    for k in 1..=frames {
        // A sway: each row shifted along x in proportion to its depth.
        let shear = 0.3 * (std::f64::consts::TAU * k as f64 / frames as f64).sin();
        let mut x = initial.clone();
        for p in x.chunks_mut(3) {
            p[0] += shear * p[1];
        }
        let panel = PanelFrame {
            id: 1,
            epoch: 1,
            t: k as f64 / 60.0,
            steps: k,
            x,
            energy: 0.0,
            kinetic: 0.0,
            potential: 0.0,
            energy_initial: 0.0,
            energy_scale: 1.0,
            energy_error: 0.0,
            energy_conserved: true,
            work: 0.0,
            not_conserved_by: Vec::new(),
            constraint_error: 0.0,
            steps_per_second: 0.0,
            distance: None,
            reference: None,
            reference_note: None,
            contact: None,
            status: "running".into(),
            error: None,
            behind: false,
            drag: None,
            path: Vec::new(),
            curves: None,
            curve_region: scene_view,
            arrows: None,
            generalized: None,
        };
        let bytes = encode_frame(1.0, &[panel]).unwrap();
        bytes_per_frame = bytes.len();
        js_with(
            client,
            "const h = arguments[0], b = new Uint8Array(h.length / 2);
             for (let i = 0; i < b.length; i++) b[i] = parseInt(h.substr(2 * i, 2), 16);
             window.__viewer.receive(b.buffer); return null;",
            vec![Value::String(hex(&bytes))],
        )
        .await;
        // The state: this frame drawn (its step count is new).
        wait_until(
            client,
            &format!("(() => {{ const d = window.__viewer.panels.get(1).lastDraw; return d && d.frame.steps === {k}; }})()"),
            "the drawing of the frame",
        )
        .await;
    }
    let drawing = drawn(client, 1).await;
    assert_eq!(drawing["dim"], 3, "{drawing}");
    assert_eq!(drawing["steps"], frames, "{drawing}");
    assert_whole(&drawing, rods, n, 2);
    let (median, fastest, slowest) = draw_times(client, 1).await;
    let stats = js(client, "return window.__viewer.stats;").await;
    assert_eq!(stats["frames"], frames, "{stats}");
    let decode = stats["decodeMs"].as_f64().unwrap() / frames as f64;
    eprintln!(
        "cloth of {n} (3D, {rods} rods): draw {median:.2} ms median, {fastest:.2}..{slowest:.2} ms (31 draws, flushed); frames of {bytes_per_frame} bytes, decoded in {decode:.3} ms each ({:.3} ms at most)",
        stats["maxDecodeMs"].as_f64().unwrap()
    );
    assert!(
        median < DRAW_BOUND_MS,
        "drawing the cloth takes {median} ms"
    );
    screenshot(client, "cloth-2500").await;
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// Measurements for DESIGN.md, with a real server streaming at the tick rate: `cargo test -p
/// bead-viewer --test browser -- --ignored --nocapture`. A 50 x 50 cloth of springs pinned at
/// two corners (2500 particles) and 10^4 falling particles (the particle limit), each drawn
/// as it is and then with rods between grid neighbours added to the page's draw list (rods
/// made of constraints would make the dense solver of this branch the bottleneck, not the
/// page), and the frames per second the page receives while it draws; screenshots in
/// `target/`. Reports only: its figures depend on the machine and its load.
#[test]
#[ignore]
fn draw_times_at_scale() {
    in_browser(
        serving("springs.toml", generated::spring_cloth(50, 50)),
        |client, addr| measure(client, addr, "springs-2500", 50).boxed_local(),
    );
    in_browser(
        serving("free.toml", generated::free(10_000)),
        |client, addr| measure(client, addr, "free-10000", 100).boxed_local(),
    );
}

/// Measure the draw time of panel 1, without and with rods between the neighbours of a grid
/// of `cols` columns.
async fn measure(client: &Client, addr: SocketAddr, name: &str, cols: usize) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_within(
        client,
        &current(1, "f.t > 0.5"),
        "running frames",
        Duration::from_secs(60),
    )
    .await;
    let median = |times: Value| {
        let mut times: Vec<f64> = times
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        times.sort_by(f64::total_cmp);
        times[times.len() / 2]
    };
    let plain = median(js(client, "return window.__viewer.drawTimes(1, 61);").await);
    let links = js(
        client,
        &format!(
            "const v = window.__viewer, n = v.scene.particles.length, cols = {cols}, pairs = [];
             for (let k = 0; k < n; k++) {{
                 if ((k % cols) + 1 < cols) pairs.push(k, k + 1);
                 if (k + cols < n) pairs.push(k, k + cols);
             }}
             v.scene.draw.pairs = Int32Array.from(pairs);
             return pairs.length / 2;"
        ),
    )
    .await;
    let with_rods = median(js(client, "return window.__viewer.drawTimes(1, 61);").await);
    let last = js(
        client,
        "const d = window.__viewer.panels.get(1).lastDraw; return {rods: d.rods, particles: d.particles, paintCalls: d.paintCalls};",
    )
    .await;
    let stats = js(client, "return window.__viewer.stats;").await;
    let frames = stats["frames"].as_f64().unwrap();
    eprintln!(
        "{name}: draw {plain:.2} ms median (flushed), {with_rods:.2} ms with {links} rods; last draw {last}; decode {:.3} ms a frame ({} frames, {:.0} bytes each)",
        stats["decodeMs"].as_f64().unwrap() / frames,
        frames,
        stats["bytes"].as_f64().unwrap() / frames,
    );
    // Frames per second reaching the page while it draws every one.
    let before = js(
        client,
        "return [window.__viewer.stats.frames, performance.now()];",
    )
    .await;
    tokio::time::sleep(Duration::from_secs(3)).await;
    let after = js(
        client,
        "return [window.__viewer.stats.frames, performance.now()];",
    )
    .await;
    let rate = (after[0].as_f64().unwrap() - before[0].as_f64().unwrap())
        / (after[1].as_f64().unwrap() - before[1].as_f64().unwrap())
        * 1000.0;
    let draws = js(
        client,
        "const p = window.__viewer.panels.get(1); const t = [...p.drawTimes].sort((a, b) => a - b); return [t.length, t[t.length >> 1]];",
    )
    .await;
    eprintln!("{name}: {rate:.1} frames/s received; page's own draws (unflushed) {draws}");
    screenshot(client, name).await;
}

#[test]
fn the_page_draws_what_the_simulation_is() {
    in_browser(
        serving("shaken.toml", generated::SHAKEN.into()),
        |client, addr| truthful_checks(client, addr).boxed_local(),
    );
}

/// A JS expression: the largest |C(x, t)| over the curve panel 1 drew last, with `C` a JS
/// function of (x, y, t), and t the time of the frame whose curves were drawn.
fn drawn_curve_residual(c: &str) -> String {
    format!(
        "(() => {{ const p = window.__viewer.panels.get(1), d = p.lastDraw; const C = {c};
           let worst = 0;
           for (const line of p.drawnCurves) for (let i = 0; i + 1 < line.length; i += 2)
             worst = Math.max(worst, Math.abs(C(line[i], line[i + 1], d.frame.t)));
           return worst; }})()"
    )
}

/// A JS condition: the first panel's latest frame belongs to its current epoch and
/// satisfies `condition` on `p` (the panel) and `f` (the frame).
fn first_current(condition: &str) -> String {
    format!(
        "(() => {{ const p = [...window.__viewer.panels.values()][0]; const f = p && p.frame; \
         return !!(f && f.epoch === p.info.epoch && ({condition})); }})()"
    )
}

async fn truthful_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    // No arrows: the velocity arrow lies along the curve and would hide it from the pixel
    // count below.
    wait_until(
        client,
        "window.__viewer && window.__viewer.scene",
        "the scene",
    )
    .await;
    arrows_off(client).await;
    let shaken = "(x, y, t) => y + 0.5 * x * x + 0.3 * Math.sin(2 * t)";
    // 1. The moving curve is drawn at the frame's t, at two times: its samples satisfy
    //    C(x, t) = 0 there (and not C(x, 0) = 0), and the bead sits on the blue curve drawn.
    let mut last_t = 0.3;
    for _ in 0..2 {
        wait_until(
            client,
            &format!(
                "(() => {{ const p = window.__viewer.panels.get(1), d = p && p.lastDraw;
                   return d && d.frame.epoch === p.info.epoch && d.frame.t > {last_t} && d.frame.curves; }})()"
            ),
            "a drawing of the moving curve",
        )
        .await;
        let checks = js(
            client,
            &format!(
                "const p = window.__viewer.panels.get(1), d = p.lastDraw, c = p.dom.canvas;
                 const worst = {}; const frozen = {};
                 const [bx, by] = window.__viewer.canvasPoint(1, d.x[0], d.x[1]);
                 const image = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
                 let blue = 0;
                 for (let dy = -26; dy <= 26; dy++) for (let dx = -26; dx <= 26; dx++) {{
                   const r = Math.hypot(dx, dy); if (r < 14 || r > 26) continue;
                   const i = 4 * (Math.round(by + dy) * c.width + Math.round(bx + dx));
                   if (image[i + 2] > 200 && image[i] < 80) blue++;
                 }}
                 return {{t: d.frame.t, worst, frozen, blue, moving: p.info.curves_move}};",
                drawn_curve_residual(shaken),
                drawn_curve_residual("(x, y, t) => y + 0.5 * x * x")
            ),
        )
        .await;
        assert_eq!(checks["moving"], true, "{checks}");
        assert!(
            checks["worst"].as_f64().unwrap() < 2e-3,
            "curve off C(x, t) = 0: {checks}"
        );
        assert!(
            checks["frozen"].as_f64().unwrap() > 0.05,
            "curve of t = 0 drawn: {checks}"
        );
        assert!(
            checks["blue"].as_u64().unwrap() > 8,
            "no curve at the bead: {checks}"
        );
        last_t = checks["t"].as_f64().unwrap() + 0.4;
    }
    screenshot(client, "moving-constraint").await;

    // 2. Energy: the bars are the frame's kinetic, potential and total (the core's); the
    //    driven constraint's work is named as the reason energy changes.
    js(
        client,
        "document.getElementById('play').click(); return null;",
    )
    .await;
    wait_until(client, &current(1, "f.status === 'paused'"), "the pause").await;
    wait_until(
        client,
        "(() => { const p = window.__viewer.panels.get(1), b = p.lastBars, f = p.frame;
           return b && f.status === 'paused' && b.kinetic === f.kinetic && b.potential === f.potential && b.total === f.energy; })()",
        "energy bars equal to the frame's energies",
    )
    .await;
    let why = js(
        client,
        "return window.__viewer.panels.get(1).dom.energyWhy.textContent;",
    )
    .await;
    assert!(
        why.as_str().unwrap().contains("depends on t") && why.as_str().unwrap().contains("E − W"),
        "{why}"
    );
    let bars = js(
        client,
        "const p = window.__viewer.panels.get(1); return [p.lastBars, p.frame.kinetic + p.frame.potential - p.frame.energy];",
    )
    .await;
    assert!(bars[1].as_f64().unwrap().abs() < 1e-9, "T + V != E: {bars}");

    // 3. Zoom, pan, edge marker, fit.
    let before = js(client, "return window.__viewer.viewOf(1);").await;
    js(client, "window.__viewer.zoom(1, 2); return null;").await;
    let zoomed = js(client, "return window.__viewer.viewOf(1);").await;
    let ratio = zoomed["s"].as_f64().unwrap() / before["s"].as_f64().unwrap();
    assert!(
        (ratio - 2.0).abs() < 1e-9 && zoomed["auto"] == false,
        "{before} {zoomed}"
    );
    // Pan far away (a drag on empty space does this; here the view is set directly): the
    // bead is off view and a marker on the plot's edge points at it.
    js(
        client,
        "const p = window.__viewer.panels.get(1); p.view.auto = false; p.view.c = [50, 50]; p.dirty = true; return null;",
    )
    .await;
    wait_until(
        client,
        "(() => { const d = window.__viewer.panels.get(1).lastDraw, r = window.__viewer.viewOf(1).rect;
           const m = d.markers[0];
           return d.offView === 1 && m && m.x >= r.x0 && m.x <= r.x1 && m.y >= r.y0 && m.y <= r.y1; })()",
        "an edge marker for the bead off view",
    )
    .await;
    screenshot(client, "off-view-marker").await;
    js(
        client,
        "document.querySelector('.panel[data-panel=\"1\"] .fit').click(); return null;",
    )
    .await;
    wait_until(
        client,
        "(() => { const d = window.__viewer.panels.get(1).lastDraw; return window.__viewer.viewOf(1).auto && d.offView === 0 && d.markers.length === 0; })()",
        "the fitted view with the bead in it",
    )
    .await;
    // A drag on empty space pans.
    let center = js(client, "return window.__viewer.viewOf(1).center;").await;
    for (kind, dx) in [
        ("pointerdown", 0.0),
        ("pointermove", 60.0),
        ("pointerup", 60.0),
    ] {
        js(
            client,
            &format!(
                "const v = window.__viewer, c = v.panels.get(1).dom.canvas, b = c.getBoundingClientRect();
                 const r = v.viewOf(1).rect, k = b.width / c.width;
                 c.dispatchEvent(new PointerEvent('{kind}', {{clientX: b.left + (r.x0 + 12 + {dx}) * k,
                   clientY: b.top + (r.y0 + 12) * k, pointerId: 1, bubbles: true, isPrimary: true, button: 0, buttons: 1}}));
                 return null;"
            ),
        )
        .await;
    }
    let panned = js(client, "return window.__viewer.viewOf(1);").await;
    assert_eq!(panned["auto"], false, "{panned}");
    assert!(
        panned["center"][0].as_f64().unwrap() < center[0].as_f64().unwrap(),
        "dragging right moves the view left: {center} -> {panned}"
    );

    // 4. A curve edit redraws the new curve (at the frame's t) and refits.
    js(
        client,
        "const row = document.querySelector('#curves .curve-edit[data-constraint=\"0\"]');
         row.querySelector('.curve-expr').value = 'bead.y + 0.1*bead.x^2 + 0.3*sin(2*t)';
         row.querySelector('.curve-apply').click(); return null;",
    )
    .await;
    wait_until(
        client,
        &format!(
            "(() => {{ const p = window.__viewer.panels.get(1), d = p.lastDraw;
               return p.info.exprs[0] === 'bead.y + 0.1*bead.x^2 + 0.3*sin(2*t)' && d.frame.epoch === p.info.epoch
                 && window.__viewer.viewOf(1).auto && {} < 2e-3; }})()",
            drawn_curve_residual("(x, y, t) => y + 0.1 * x * x + 0.3 * Math.sin(2 * t)")
        ),
        "the edited curve drawn",
    )
    .await;

    // 5. The helix in 3D: a 3D view, z up as the scene says, the climb visible, orbit.
    js(
        client,
        "window.__viewer.ws.send(JSON.stringify({type: 'load_scene', name: 'helix'})); return null;",
    )
    .await;
    wait_until(
        client,
        &format!(
            "window.__viewer.scene.name === 'helix' && {}",
            first_current("p.lastDraw && f.t > 0.5")
        ),
        "the helix running",
    )
    .await;
    let helix = js(
        client,
        "const v = window.__viewer, p = [...v.panels.values()][0], id = p.info.id;
         const ys = []; for (const line of p.drawnCurves) for (let i = 0; i + 2 < line.length; i += 3) ys.push(v.canvasPoint(id, line[i], line[i + 1], line[i + 2])[1]);
         return {title: document.getElementById('scene-title').textContent, up: v.sceneUp(),
                 note: p.dom.note.textContent, climb: Math.max(...ys) - Math.min(...ys),
                 height: v.viewOf(id).rect.y1 - v.viewOf(id).rect.y0, yaw: v.viewOf(id).yaw};",
    )
    .await;
    assert_eq!(helix["up"], json!([0, 0, 1]), "{helix}");
    let title = helix["title"].as_str().unwrap();
    assert!(
        title.contains("3D view") && title.contains("z up"),
        "{helix}"
    );
    assert!(
        !helix["note"].as_str().unwrap().contains("y down"),
        "{helix}"
    );
    assert!(
        helix["climb"].as_f64().unwrap() > 0.3 * helix["height"].as_f64().unwrap(),
        "the helix's climb is not visible: {helix}"
    );
    for (kind, dx) in [
        ("pointerdown", 0.0),
        ("pointermove", 80.0),
        ("pointerup", 80.0),
    ] {
        js(
            client,
            &format!(
                "const v = window.__viewer, p = [...v.panels.values()][0], c = p.dom.canvas, b = c.getBoundingClientRect();
                 const r = v.viewOf(p.info.id).rect, k = b.width / c.width;
                 c.dispatchEvent(new PointerEvent('{kind}', {{clientX: b.left + (r.x0 + 12 + {dx}) * k,
                   clientY: b.top + (r.y0 + 12) * k, pointerId: 1, bubbles: true, isPrimary: true, button: 0, buttons: 1}}));
                 return null;"
            ),
        )
        .await;
    }
    let yaw = js(
        client,
        "const v = window.__viewer; return v.viewOf([...v.panels.values()][0].info.id).yaw;",
    )
    .await;
    assert!(
        (yaw.as_f64().unwrap() - helix["yaw"].as_f64().unwrap()).abs() > 0.3,
        "no orbit: {yaw} {helix}"
    );
    screenshot(client, "helix-3d").await;

    // Screenshots of the other scenes, to look at.
    for name in ["circle", "double-pendulum", "parabola", "cycloid"] {
        js(
            client,
            &format!("window.__viewer.ws.send(JSON.stringify({{type: 'load_scene', name: '{name}'}})); return null;"),
        )
        .await;
        wait_until(
            client,
            &format!(
                "window.__viewer.scene.name === '{name}' && {}",
                first_current("p.lastDraw && f.t > 1.0")
            ),
            "the scene running",
        )
        .await;
        screenshot(client, name).await;
    }
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// Issue 9's comparison and teaching features in the page, each waited for by a restart
/// counter (the clock's `generation`) or an epoch, never by a time or a value that a frame
/// from before the request could also show: overlay mode (both panels' particles in one
/// canvas in their colours; the distance chart and its readout, equal to the server's
/// distance, which is the distance of the two frames' positions), the keyboard shortcuts,
/// a slider change, a share URL round trip and a drag while paused.
#[test]
fn comparison_and_teaching_in_the_page() {
    in_browser(ServerConfig::default(), |client, addr| {
        teaching_checks(client, addr).boxed_local()
    });
}

/// The clock's generation in the newest frame the page holds.
async fn generation(client: &Client) -> u64 {
    js(
        client,
        "const v = window.__viewer; return v && v.clock ? v.clock.generation : -1;",
    )
    .await
    .as_u64()
    .unwrap_or(0)
}

/// A JS condition: the newest frame is of a generation after `after` and every panel's
/// frame belongs to its current epoch and satisfies `condition` on `f`.
fn all_after(after: u64, condition: &str) -> String {
    format!(
        "(() => {{ const v = window.__viewer; if (!v || !v.clock || v.clock.generation <= {after}) return false;
            const ps = [...v.panels.values()];
            return ps.length > 0 && ps.every(p => {{ const f = p.frame; return !!(f && f.epoch === p.info.epoch && ({condition})); }}); }})()"
    )
}

/// Press and release `key` (a real key event, to the focused page).
async fn press(client: &Client, key: char) {
    use fantoccini::actions::{InputSource, KeyAction, KeyActions};
    let keys = KeyActions::new("keyboard".into())
        .then(KeyAction::Down { value: key })
        .then(KeyAction::Up { value: key });
    client.perform_actions(keys).await.expect("key press");
}

async fn teaching_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_until(
        client,
        &all_after(0, "f.status === 'running' && f.t > 0.2"),
        "two running panels",
    )
    .await;
    let rate = js(
        client,
        "return document.getElementById('rate').textContent;",
    )
    .await;
    assert!(
        rate.as_str().unwrap().starts_with("simulation rate ×"),
        "{rate}"
    );
    let sps = js(
        client,
        "return document.querySelector('.panel .r-sps').textContent;",
    )
    .await;
    assert!(
        sps.as_str()
            .unwrap()
            .ends_with("steps per second of computing"),
        "{sps}"
    );
    // Settings that do nothing are hidden: feedback and projection on the parametric panel.
    let hidden = js(
        client,
        "return [1, 2].map(id => { const r = document.querySelector(`.panel[data-panel=\"${id}\"]`);
           return [r.querySelector('label.feedback').hidden, r.querySelector('label.projection').hidden]; });",
    )
    .await;
    assert_eq!(hidden, json!([[false, false], [true, true]]));

    // Keyboard: space pauses every panel, s steps once, r restarts, space plays again.
    press(client, ' ').await;
    wait_until(client, &all_after(0, "f.status === 'paused'"), "the pause").await;
    let steps: Vec<u64> = js(
        client,
        "return [...window.__viewer.panels.values()].map(p => p.frame.steps);",
    )
    .await
    .as_array()
    .unwrap()
    .iter()
    .map(|v| v.as_u64().unwrap())
    .collect();
    press(client, 's').await;
    wait_until(
        client,
        &format!(
            "[...window.__viewer.panels.values()].every((p, k) => p.frame.steps === {steps:?}[k] + 1)"
        ),
        "one step",
    )
    .await;
    let before = generation(client).await;
    press(client, 'r').await;
    wait_until(
        client,
        &all_after(before, "f.t === 0 && f.status === 'paused'"),
        "the reset",
    )
    .await;
    press(client, ' ').await;
    wait_until(
        client,
        &all_after(before, "f.status === 'running' && f.t > 0.3"),
        "play again",
    )
    .await;

    // Overlay: both panels' particles in one canvas, each in its colour; the distance chart
    // and readout show the server's distance.
    js(client, "window.__viewer.setOverlay(true); return null;").await;
    wait_until(
        client,
        "window.__viewer.overlay.lastDraw && window.__viewer.overlay.lastDraw.panels.length === 2 && !document.getElementById('overlay-view').hidden",
        "the overlay",
    )
    .await;
    // Paused, so that the drawn state is the frame's and stays put while pixels are read.
    press(client, ' ').await;
    wait_until(
        client,
        &all_after(before, "f.status === 'paused'"),
        "the pause",
    )
    .await;
    wait_until(
        client,
        "(() => { const v = window.__viewer, d = v.overlay.lastDraw; return d.panels.every(q => q.t === v.panels.get(q.id).frame.t); })()",
        "the overlay to draw the paused state",
    )
    .await;
    let overlay = js(
        client,
        "const v = window.__viewer, d = v.overlay.lastDraw;
         return d.panels.map(q => ({ id: q.id, color: q.color, point: q.points[0], pixel: v.overlayPixel(q.points[0][0], q.points[0][1]) }));",
    )
    .await;
    let hex = |p: &Value| {
        let c: Vec<u64> = p
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap())
            .collect();
        format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
    };
    // The second panel is drawn last: its colour is at its bead. The first panel's bead is
    // under it when they coincide, so look for its colour in a ring around its centre.
    let second = &overlay[1];
    assert_eq!(
        hex(&second["pixel"]),
        second["color"].as_str().unwrap(),
        "{overlay}"
    );
    let first_seen = js(
        client,
        "const v = window.__viewer, q = v.overlay.lastDraw.panels[0];
         const want = q.color; let found = false;
         for (let a = 0; a < 32 && !found; a++) {
           const px = v.overlayPixel(q.points[0][0] + 10 * Math.cos(a / 5), q.points[0][1] + 10 * Math.sin(a / 5));
           const h = '#' + px.slice(0, 3).map(c => c.toString(16).padStart(2, '0')).join('');
           found = h === want;
         }
         return found;",
    )
    .await;
    assert_eq!(
        first_seen,
        Value::Bool(true),
        "first panel's colour not drawn: {overlay}"
    );
    let legend = js(
        client,
        "return document.querySelectorAll('#overlay-legend .legend-item').length;",
    )
    .await;
    assert_eq!(legend, json!(2));
    let distance = js(
        client,
        "const v = window.__viewer, [a, b] = [...v.panels.values()];
         const e = document.querySelector('#distance-readout .distance[data-panel=\"' + b.info.id + '\"]');
         let by_hand = 0;
         for (let k = 0; k < a.frame.x.length; k += 2) by_hand = Math.max(by_hand, Math.hypot(a.frame.x[k] - b.frame.x[k], a.frame.x[k + 1] - b.frame.x[k + 1]));
         return { shown: Number(e.dataset.value), server: b.frame.distance, by_hand, same_t: a.frame.t === b.frame.t,
                  chart: v.overlay.history.get(b.info.id).points.length };",
    )
    .await;
    assert_eq!(distance["same_t"], Value::Bool(true), "{distance}");
    assert_eq!(distance["shown"], distance["server"], "{distance}");
    let (server, by_hand) = (
        distance["server"].as_f64().unwrap(),
        distance["by_hand"].as_f64().unwrap(),
    );
    assert!(
        (server - by_hand).abs() <= 1e-12 * by_hand.max(1.0),
        "{distance}"
    );
    assert!(distance["chart"].as_u64().unwrap() > 5, "{distance}");
    screenshot(client, "overlay").await;
    js(client, "window.__viewer.setOverlay(false); return null;").await;

    // A slider change: the scene restarts with g doubled (a new generation, the parameter's
    // new value, and the start energy E0 = m g h doubled).
    let g = js(
        client,
        "return window.__viewer.scene.params.find(p => p.name === 'g').value;",
    )
    .await
    .as_f64()
    .unwrap();
    let e0 = frame(client, 1).await["energy_initial"].as_f64().unwrap();
    let before = generation(client).await;
    js(
        client,
        &format!("window.__viewer.setParam('g', {}); return null;", 2.0 * g),
    )
    .await;
    wait_until(
        client,
        &format!(
            "window.__viewer.scene.params.find(p => p.name === 'g').value === {} && {}",
            2.0 * g,
            all_after(before, "true")
        ),
        "the scene with the new g",
    )
    .await;
    let ids: Vec<u64> = js(client, "return [...window.__viewer.panels.keys()];")
        .await
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    let e1 = frame(client, ids[0]).await["energy_initial"]
        .as_f64()
        .unwrap();
    assert!((e1 - 2.0 * e0).abs() < 1e-9 * e0.abs(), "E0 {e0} -> {e1}");
    // The number box shows the value; the slider (a thousand steps over g's range [0, 2000])
    // stands at its middle.
    let shown = js(
        client,
        "const r = document.querySelector('#params .param[data-param=\"g\"]');
         return [Number(r.querySelector('.param-value').value), Number(r.querySelector('input[type=range]').value)];",
    )
    .await;
    let shown: Vec<f64> = shown
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(shown, [2.0 * g, 500.0], "g = {g}");
    // Out of range: said on the page, nothing restarts.
    let before = generation(client).await;
    js(client, "window.__viewer.setParam('g', 1e9); return null;").await;
    wait_until(
        client,
        "document.getElementById('messages').textContent.includes('must be a number in')",
        "the range message",
    )
    .await;
    assert_eq!(generation(client).await, before);

    // Change a panel so that the share URL has something to restore: dt of panel 2.
    let second = ids[1];
    js(
        client,
        &format!(
            "const r = document.querySelector('.panel[data-panel=\"{second}\"]');
             r.querySelector('input.dt').value = '0.005'; r.querySelector('button.apply').click(); return null;"
        ),
    )
    .await;
    wait_until(
        client,
        &format!("window.__viewer.panels.get({second}).info.dt === 0.005"),
        "dt 0.005",
    )
    .await;
    js(
        client,
        "const s = document.getElementById('time-scale'); s.value = '0.5'; s.dispatchEvent(new Event('change')); return null;",
    )
    .await;
    wait_until(
        client,
        "window.__viewer.timeScale === 0.5",
        "time scale 0.5",
    )
    .await;
    js(
        client,
        "document.getElementById('share').click(); return null;",
    )
    .await;
    let url = js(client, "return document.getElementById('share-url').value;").await;
    let url = url.as_str().unwrap().to_string();
    assert!(
        url.contains("scene=parabola") && url.contains("param.g="),
        "{url}"
    );
    let wanted = js(
        client,
        "return [...window.__viewer.panels.values()].map(p => [p.info.method, p.info.integrator, p.info.dt]);",
    )
    .await;

    // The URL in a fresh page: the same scene, parameter, panels and time scale come back.
    client.goto("about:blank").await.unwrap();
    client.goto(&url).await.unwrap();
    wait_until(
        client,
        &format!(
            "window.__viewer && window.__viewer.scene && window.__viewer.scene.params.find(p => p.name === 'g').value === {} && window.__viewer.restore === null && JSON.stringify([...window.__viewer.panels.values()].map(p => [p.info.method, p.info.integrator, p.info.dt])) === JSON.stringify({wanted}) && window.__viewer.timeScale === 0.5",
            2.0 * g
        ),
        "the shared state back",
    )
    .await;

    // A bad share URL: each bad part said on the page, the rest used.
    client
        .goto(&format!(
            "http://{addr}/?scene=nowhere&param.g=abc&panel=implicit:warp:0.01&ts=7"
        ))
        .await
        .unwrap();
    wait_until(
        client,
        "(() => { const t = document.getElementById('messages').textContent;
            return t.includes('unknown scene `nowhere`') && t.includes('`abc` is not a number') && t.includes('unknown integrator `warp`') && t.includes('time scale `7`'); })()",
        "the bad URL's messages",
    )
    .await;

    // Drag while paused: the start state. Both panels restart from the dragged place, on the
    // curve, at rest.
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_until(client, &all_after(0, "f.t > 0.1"), "the page").await;
    press(client, ' ').await;
    wait_until(client, &all_after(0, "f.status === 'paused'"), "the pause").await;
    let before = generation(client).await;
    let f = frame(client, 1).await;
    let (x, y) = (f["x"][0].as_f64().unwrap(), f["x"][1].as_f64().unwrap());
    pointer(client, 1, "pointerdown", x, y).await;
    // To (-90, -80), just off the curve (y = -81 there).
    pointer(client, 1, "pointermove", -80.0, -60.0).await;
    pointer(client, 1, "pointermove", -90.0, -80.0).await;
    pointer(client, 1, "pointerup", -90.0, -80.0).await;
    wait_until(
        client,
        &all_after(
            before,
            "f.t === 0 && f.status === 'paused' && f.kinetic === 0",
        ),
        "the new start state",
    )
    .await;
    for panel in [1, 2] {
        let f = frame(client, panel).await;
        let (x, y) = (f["x"][0].as_f64().unwrap(), f["x"][1].as_f64().unwrap());
        assert!((x * x + 100.0 * y).abs() < 1e-6, "panel {panel}: {f}");
        assert!((x + 90.0).abs() < 1.0, "panel {panel}: {f}");
    }
    // Far off the curve, at (-100, -200): both panels start at the closest point of the
    // curve, (-136.6, -186.6) (issue 15: the two forms started on opposite sides of the
    // bowl), and the page says how far it moved the drop.
    let before = generation(client).await;
    let f = frame(client, 1).await;
    let (x, y) = (f["x"][0].as_f64().unwrap(), f["x"][1].as_f64().unwrap());
    pointer(client, 1, "pointerdown", x, y).await;
    pointer(client, 1, "pointermove", -95.0, -150.0).await;
    pointer(client, 1, "pointermove", -100.0, -200.0).await;
    pointer(client, 1, "pointerup", -100.0, -200.0).await;
    wait_until(
        client,
        &all_after(before, "f.t === 0 && f.status === 'paused'"),
        "the start at the closest point",
    )
    .await;
    let mut starts = Vec::new();
    for panel in [1, 2] {
        let f = frame(client, panel).await;
        let (x, y) = (f["x"][0].as_f64().unwrap(), f["x"][1].as_f64().unwrap());
        assert!(
            (x + 136.6).abs() < 0.1 && (y + 186.6).abs() < 0.1,
            "panel {panel}: {f}"
        );
        starts.push((x, y));
    }
    assert!((starts[0].0 - starts[1].0).abs() < 1e-9, "{starts:?}");
    wait_until(
        client,
        "(() => { const t = document.getElementById('messages').textContent;
            return /moved the drop \\d+ px onto the curve/.test(t); })()",
        "the message about the moved drop",
    )
    .await;
    // The equations on demand.
    js(client, "document.querySelector('.panel[data-panel=\"2\"] button.show-equations').click(); return null;").await;
    wait_until(
        client,
        "(() => { const e = document.querySelector('.panel[data-panel=\"2\"] .equations'); return !e.hidden && e.textContent.includes('acceleration = J q\\'\\' + h'); })()",
        "the parametric equations",
    )
    .await;
    // Typeset: the browser lays the MathML out as math (a fraction is taller than a line of
    // text), and the written-out equation of motion is there.
    let math = js(
        client,
        "const e = document.querySelector('.panel[data-panel=\"2\"] .equations');
         const blocks = [...e.querySelectorAll('math')];
         const frac = e.querySelector('mfrac'), line = parseFloat(getComputedStyle(e.querySelector('p')).fontSize);
         return [blocks.length, frac.getBoundingClientRect().height > 1.8 * line, e.textContent.includes('M(q)'),
                 blocks.every(b => b.getBoundingClientRect().width > 0)];",
    )
    .await;
    assert_eq!(math[1], json!(true), "{math}");
    assert!(math[0].as_u64().unwrap() >= 3, "{math}");
    assert_eq!(math[2], json!(true), "{math}");
    assert_eq!(math[3], json!(true), "{math}");

    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// The screenshots of the docs (`docs/viewer*.png`), from headless Chromium:
/// `cargo test -p bead-viewer --test browser -- --ignored docs_screenshots`. Each scene runs
/// for a few seconds first, so that trails and charts have something to show.
#[test]
#[ignore]
fn docs_screenshots() {
    in_browser(ServerConfig::default(), |client, addr| {
        take_docs_screenshots(client, addr).boxed_local()
    });
}

async fn take_docs_screenshots(client: &Client, addr: SocketAddr) {
    client.set_window_size(1280, 1350).await.unwrap();
    let docs = workspace_root().join("docs");
    std::fs::create_dir_all(&docs).unwrap();
    for (scene, file, overlay) in [
        ("parabola", "viewer.png", false),
        ("double-pendulum", "viewer-double-pendulum.png", false),
        ("helix", "viewer-helix-3d.png", false),
        ("spinning-hoop", "viewer-spinning-hoop.png", false),
        ("parabola", "viewer-overlay.png", true),
    ] {
        client
            .goto(&format!("http://{addr}/?scene={scene}"))
            .await
            .unwrap();
        wait_until(
            client,
            &format!(
                "window.__viewer && window.__viewer.scene && window.__viewer.scene.name === '{scene}' && window.__viewer.restore === null && {}",
                all_after(0, "f.status === 'running' && f.t > 0.1")
            ),
            "the scene",
        )
        .await;
        if overlay {
            // Two integrators on the implicit form beside the parametric one.
            js(client, "window.__viewer.setOverlay(true); return null;").await;
            js(
                client,
                "document.getElementById('new-method').value = 'implicit';
                 document.getElementById('new-integrator').value = 'euler';
                 document.getElementById('add-panel').click(); return null;",
            )
            .await;
            wait_until(
                client,
                "window.__viewer.panels.size === 3",
                "the third panel",
            )
            .await;
        }
        tokio::time::sleep(Duration::from_millis(4000)).await;
        if overlay {
            // The overlay first: scroll so that it and the toolbar show.
            js(client, "window.scrollTo(0, 0); return null;").await;
        }
        let png = client.screenshot().await.expect("screenshot");
        std::fs::write(docs.join(file), &png).unwrap();
    }
}

/// The reference ghost, turned on as a user does (the panel's `reference` box): the panel
/// restarts with the reference beside it, the ghost is drawn where the frame's reference
/// stands, the readout gives the distance the server computed, and the live plot charts
/// that distance against t on a log axis; the share URL keeps the choice.
#[test]
fn the_reference_ghost_is_drawn_and_its_distance_charted_on_a_log_axis() {
    let text = shipped("parabola");
    in_browser(serving("parabola", text), |client, addr| {
        ghost_checks(client, addr).boxed_local()
    });
}

async fn ghost_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.panels.size === 2 && \
         [...window.__viewer.panels.values()].every(p => p.frame && p.frame.t > 0.2)",
        "both panels running",
        Duration::from_secs(30),
    )
    .await;
    let first = js(
        client,
        "const p = [...window.__viewer.panels.values()][0];
         const box = p.dom.root.querySelector('input.reference');
         box.checked = true; box.dispatchEvent(new Event('change'));
         return [p.info.id, p.info.epoch];",
    )
    .await;
    let (id, epoch) = (first[0].as_u64().unwrap(), first[1].as_u64().unwrap());
    // The panel restarted (a new epoch) with its reference, and ran on past 1 s.
    wait_within(
        client,
        &format!(
            "(() => {{ const p = window.__viewer.panels.get({id}); const f = p && p.frame; \
             return !!(p.info.epoch > {epoch} && p.info.reference && f && f.epoch === p.info.epoch \
               && f.reference && f.t > 1.0 && p.lastDraw && p.lastDraw.ghost && p.lastPlot); }})()"
        ),
        "the ghost drawn and the distance plotted",
        Duration::from_secs(30),
    )
    .await;
    pause_all(client).await;
    // Paused: the plot and the readout catch up with the last frame.
    wait_within(
        client,
        &format!(
            "(() => {{ const p = window.__viewer.panels.get({id}); const f = p.frame; \
             return !!(f.reference && p.lastPlot && p.lastPlot.last[0][1] === f.reference.distance \
               && Number(p.dom.fields.ref.dataset.value) === f.reference.distance); }})()"
        ),
        "the plot's newest point and the readout at the last frame",
        Duration::from_secs(30),
    )
    .await;
    let seen = js(
        client,
        &format!(
            "const p = window.__viewer.panels.get({id}); const f = p.frame;
             return {{ distance: f.reference.distance, gx: f.reference.x[0], x: f.x[0],
               readout: p.dom.fields.ref.textContent, value: Number(p.dom.fields.ref.dataset.value),
               plot: p.plot, y: p.dom.plotY.value, log: p.dom.plotLog.checked,
               last: p.lastPlot.last, checked: p.dom.reference.checked,
               share: window.__viewer.shareUrl() }};"
        ),
    )
    .await;
    let distance = seen["distance"].as_f64().unwrap();
    assert!(distance > 0.0 && distance < 1.0, "{seen}");
    assert_eq!(seen["value"].as_f64().unwrap(), distance, "{seen}");
    assert!(
        seen["readout"]
            .as_str()
            .unwrap()
            .starts_with("distance to the reference"),
        "{seen}"
    );
    assert_eq!(seen["y"], "reference_distance", "{seen}");
    assert_eq!(seen["log"], true, "{seen}");
    assert_eq!(seen["checked"], true, "{seen}");
    // The plot's newest point is the last frame's (t, distance).
    assert_eq!(seen["last"][0][1].as_f64().unwrap(), distance, "{seen}");
    // The share URL keeps the reference with the panel.
    let share = seen["share"].as_str().unwrap();
    assert!(share.contains("reference"), "{share}");
    screenshot(client, "reference-ghost").await;
}

/// The ball of `bounce`: the readout says where it is (in flight or on the track) and counts
/// the bounces, as the frame does; the ball is never drawn below the bowl (the session test
/// checks that it flies off it by pixels).
#[test]
fn the_bounce_page_shows_the_ball_in_flight_and_counts_its_bounces() {
    let text = shipped("bounce");
    in_browser(serving("bounce", text), |client, addr| {
        bounce_checks(client, addr).boxed_local()
    });
}

async fn bounce_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    // After its first bounce (whatever the load: the state, not a time).
    wait_within(
        client,
        "(() => { const p = window.__viewer && [...window.__viewer.panels.values()][0]; \
         const f = p && p.frame; \
         return !!(f && f.contact && f.contact.bounces >= 1 && p.lastDraw); })()",
        "the ball bounced",
        Duration::from_secs(60),
    )
    .await;
    pause_all(client).await;
    // Paused: the readout says what the last frame says, in flight or on the track.
    wait_within(
        client,
        "(() => { const p = [...window.__viewer.panels.values()][0]; const c = p.frame.contact; \
         const where = c.detached[0] ? 'in flight' : 'on the track'; \
         const text = p.dom.fields.contact.textContent; \
         return text.startsWith(where) && text.includes(`${c.bounces} bounce`); })()",
        "the readout at the last frame",
        Duration::from_secs(30),
    )
    .await;
    let seen = js(
        client,
        "const p = [...window.__viewer.panels.values()][0]; const f = p.frame;
         return { x: f.x[0], y: f.x[1], text: p.dom.fields.contact.textContent,
           hidden: p.dom.fields.contact.hidden, bounces: f.contact.bounces };",
    )
    .await;
    let (x, y) = (seen["x"].as_f64().unwrap(), seen["y"].as_f64().unwrap());
    let c = x * x + 100.0 * y;
    let text = seen["text"].as_str().unwrap();
    // Paused in flight or just after landing again: on the allowed side, never below.
    assert!(c <= 1e-6 * (x * x).max(1.0), "below the bowl: {seen}");
    assert!(!seen["hidden"].as_bool().unwrap(), "{seen}");
    assert!(
        text.contains(" bounce") && text.contains("landing"),
        "{text}"
    );
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

// ---------- the static page (issue 21): the same page with the engine in it ----------

/// A static folder of the shipped scenes (`bead_viewer::page::StaticPage`, as `bead
/// export-page` writes it) with the committed engine (`docs/demo/bead.wasm`, which CI
/// rebuilds from the sources and compares), under `target/`.
fn static_folder(name: &str) -> PathBuf {
    static_folder_first(name, "parabola")
}

/// [`static_folder`] with the shipped scene `first` loaded on open.
fn static_folder_first(name: &str, first: &str) -> PathBuf {
    let wasm = std::fs::read(workspace_root().join("docs/demo/bead.wasm"))
        .expect("docs/demo/bead.wasm (scripts/build-web writes it)");
    let dir = workspace_root()
        .join("target")
        .join(format!("static-page-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut scenes = Catalog::shipped().scenes;
    let at = scenes.iter().position(|s| s.name == first).unwrap();
    let chosen = scenes.remove(at);
    scenes.insert(0, chosen);
    bead_viewer::page::StaticPage {
        scenes,
        wasm: &wasm,
        intro_html: None,
        title: "bead".into(),
    }
    .write(&dir)
    .unwrap();
    dir
}

/// Removes a static folder when the test ends.
struct Folder(PathBuf);

impl Drop for Folder {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The served page's end-to-end checks (load, draw, controls, drag, bad curve) pass on the
/// static page, served by a plain file server: the engine in the page speaks the server's
/// protocol.
#[test]
fn the_static_page_passes_the_served_pages_end_to_end_checks() {
    let folder = Folder(static_folder("e2e"));
    in_browser_at(Site::Static(folder.0.clone()), |client, addr| {
        async move {
            checks(client, addr).await;
            static_page_stats(client).await;
        }
        .boxed_local()
    });
}

/// Every shipped scene, chosen in the static page's picker, loads and runs in the engine in
/// the page (the cloth's sparse factorization, the chain's fused path, the 3D views, the
/// bounce's contacts: the whole library built for wasm32), as on the served page.
#[test]
fn every_shipped_scene_runs_in_the_static_page() {
    let folder = Folder(static_folder("picker"));
    in_browser_at(Site::Static(folder.0.clone()), |client, addr| {
        picker_checks(client, addr).boxed_local()
    });
}

/// The teaching checks (overlay, keys, a slider, the share URL round trip, a drag while
/// paused) on the static page.
#[test]
fn the_static_page_passes_the_teaching_checks() {
    let folder = Folder(static_folder("teaching"));
    in_browser_at(Site::Static(folder.0.clone()), |client, addr| {
        teaching_checks(client, addr).boxed_local()
    });
}

/// The engine's load time and tick cost, printed (the README's figures come from here), and
/// that it is the engine in the page, not a server, that the page talks to.
async fn static_page_stats(client: &Client) {
    let stats = js(
        client,
        "const w = window.__viewer.ws; return { engine: !!window.BeadEngine && w instanceof window.BeadEngine.Socket,
           label: document.getElementById('connection').textContent, ...w.stats };",
    )
    .await;
    assert_eq!(stats["engine"], Value::Bool(true), "{stats}");
    assert_eq!(stats["label"], "running in this page", "{stats}");
    println!("static page: {stats}");
}

/// After 10 s of the article's scene, the page's two panels (implicit and parametric rk4 at
/// dt 1/60) hold the states that the library computes natively for the same settings, as
/// `bead run` does: the same bits (the scene's equations use no function whose result could
/// differ between the platforms' math libraries).
#[test]
fn the_static_page_after_10_s_holds_what_bead_run_computes() {
    let folder = Folder(static_folder("ten-seconds"));
    in_browser_at(Site::Static(folder.0.clone()), |client, addr| {
        ten_second_checks(client, addr).boxed_local()
    });
}

async fn ten_second_checks(client: &Client, addr: SocketAddr) {
    use bead::formulation::Method;
    use bead::integrate::IntegratorKind;
    use bead::simulate::{Simulation, SimulationConfig};
    // At 10x, the scene's 10 s end (where every panel stops) comes in about a second.
    client
        .goto(&format!("http://{addr}/?scene=parabola&ts=10"))
        .await
        .unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.clock && window.__viewer.clock.ended && \
         window.__viewer.panels.size === 2 && [...window.__viewer.panels.values()].every(p => \
         p.frame && p.frame.status === 'paused' && p.frame.steps === 600)",
        "the end of the scene",
        Duration::from_secs(120),
    )
    .await;
    let page = js(
        client,
        "return [...window.__viewer.panels.values()].map(p => ({ method: p.info.method, t: p.frame.t, x: Array.from(p.frame.x) }));",
    )
    .await;
    let scene =
        bead::scene::Scene::load(&workspace_root().join("scenes/parabola.toml"), &[]).unwrap();
    for (panel, method) in page
        .as_array()
        .unwrap()
        .iter()
        .zip([Method::Implicit, Method::Parametric])
    {
        assert_eq!(panel["method"], method.name(), "{page}");
        let config = SimulationConfig {
            method,
            integrator: IntegratorKind::Rk4,
            dt: 1.0 / 60.0,
            ..SimulationConfig::default()
        };
        let mut sim = Simulation::new(scene.system.clone(), config).unwrap();
        for _ in 0..600 {
            sim.step().unwrap();
        }
        let x: Vec<f64> = panel["x"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(panel["t"].as_f64().unwrap(), sim.t(), "{page}");
        assert_eq!(
            x,
            sim.positions(),
            "{method:?}: the page against the library"
        );
    }
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// Opened from `file://` (a folder downloaded and double-clicked), where the browser does not
/// fetch files: the page loads the engine from its base64 copy and runs; a share URL's scene
/// comes up, in presentation mode as the embed snippet asks (`present=1`), which the share
/// URL keeps.
#[test]
fn the_static_page_runs_from_file_urls() {
    let folder = Folder(static_folder("file"));
    let url = format!(
        "file://{}/index.html?scene=circle&present=1",
        folder.0.canonicalize().unwrap().display()
    );
    FILE_URL.with(|u| *u.borrow_mut() = url);
    in_browser_at(Site::Static(folder.0.clone()), |client, _addr| {
        file_checks(client).boxed_local()
    });
}

thread_local! {
    static FILE_URL: std::cell::RefCell<String> = const { std::cell::RefCell::new(String::new()) };
}

async fn file_checks(client: &Client) {
    let url = FILE_URL.with(|u| u.borrow().clone());
    client.goto(&url).await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.scene && window.__viewer.scene.name === 'circle' && \
         window.__viewer.panels.size === 2 && [...window.__viewer.panels.values()].every(p => \
         p.frame && p.frame.epoch === p.info.epoch && p.frame.t > 0.3 && p.lastDraw)",
        "the circle running from file://",
        Duration::from_secs(60),
    )
    .await;
    let loaded = js(
        client,
        "return { base64: typeof window.BEAD_WASM_BASE64 === 'string', protocol: location.protocol,
           presenting: document.body.classList.contains('presenting'), share: (() => { document.getElementById('share').click(); return document.getElementById('share-url').value; })() };",
    )
    .await;
    assert_eq!(loaded["base64"], Value::Bool(true), "{loaded}");
    assert_eq!(loaded["protocol"], "file:", "{loaded}");
    assert_eq!(loaded["presenting"], Value::Bool(true), "{loaded}");
    assert!(
        loaded["share"].as_str().unwrap().contains("&present=1"),
        "{loaded}"
    );
    // The share URL names the file, not an origin a file page does not have.
    assert!(
        loaded["share"]
            .as_str()
            .unwrap()
            .starts_with(&format!("{}?", url.split('?').next().unwrap())),
        "{loaded}"
    );
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// The committed demo page (docs/demo, the article's experiment), served as it is: its
/// introduction above the scene, the parabola with the implicit panel left and the
/// parametric right, both running; every shipped scene in its picker after it.
#[test]
fn the_demo_page_shows_the_article_side_by_side() {
    in_browser_at(
        Site::Static(workspace_root().join("docs/demo")),
        |client, addr| demo_checks(client, addr).boxed_local(),
    );
}

async fn demo_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.scene && window.__viewer.panels.size === 2 && \
         [...window.__viewer.panels.values()].every(p => p.frame && p.frame.epoch === p.info.epoch && \
         p.frame.t > 0.5 && p.lastDraw)",
        "both panels running",
        Duration::from_secs(60),
    )
    .await;
    let shown = js(
        client,
        "const v = window.__viewer; const intro = document.getElementById('intro');
         return { scene: v.scene.name, methods: [...v.panels.values()].map(p => p.info.method),
                  intro: intro ? intro.textContent : null, title: document.title,
                  picker: [...document.getElementById('scene-select').options].map(o => o.value) };",
    )
    .await;
    assert_eq!(shown["scene"], "parabola", "{shown}");
    assert_eq!(
        shown["methods"],
        json!(["implicit", "parametric"]),
        "{shown}"
    );
    let intro = shown["intro"].as_str().unwrap_or("");
    assert!(
        intro.contains("implicit form") && intro.contains("parametric form"),
        "{shown}"
    );
    let shipped: Vec<&str> = bead_viewer::scenes::SHIPPED
        .iter()
        .map(|(n, _)| *n)
        .collect();
    assert_eq!(shown["picker"], json!(shipped), "{shown}");
    screenshot(client, "demo").await;
    if std::env::var("BEAD_UPDATE_SCREENSHOT").as_deref() == Ok("1") {
        std::fs::copy(
            workspace_root().join("target/viewer-demo.png"),
            workspace_root().join("docs/demo.png"),
        )
        .unwrap();
    }
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// How fast the static page runs (printed for the README; a figure, not asserted, since a
/// loaded machine runs slower; ignored by default, as a benchmark): over 3 s of the page's clock, the frames the engine sent
/// per second, the page's animation frames per second (the engine runs on the page's
/// thread, so a slow tick shows here), the simulation rate it shows and the engine's mean
/// tick. The article's parabola with both panels, and the shipped 1000-link chain.
#[test]
#[ignore = "a measurement for the README (cargo test -p bead-viewer --test browser -- --ignored how_fast)"]
fn how_fast_the_static_page_runs() {
    for first in ["parabola", "chain"] {
        let folder = Folder(static_folder_first(&format!("speed-{first}"), first));
        in_browser_at(Site::Static(folder.0.clone()), |client, addr| {
            speed_checks(client, addr).boxed_local()
        });
    }
}

async fn speed_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.scene && window.__viewer.clock && \
         [...window.__viewer.panels.values()].every(p => p.frame && p.frame.status === 'running' && p.frame.t > 0.2)",
        "the panels running",
        Duration::from_secs(120),
    )
    .await;
    js(
        client,
        "const v = window.__viewer, w = v.ws;
         const s = document.getElementById('at-end'); s.value = 'continue'; s.dispatchEvent(new Event('change'));
         const m = { t0: performance.now(), frames0: v.stats.frames, ticks0: w.stats.ticks, tickMs0: w.stats.tickMs,
                     raf: 0, rates: [], done: false };
         const count = () => { m.raf += 1; if (!m.done) requestAnimationFrame(count); };
         requestAnimationFrame(count);
         m.timer = setInterval(() => {
           m.rates.push(v.clock.sim_rate);
           if (performance.now() - m.t0 >= 3000) {
             m.done = true; clearInterval(m.timer);
             const secs = (performance.now() - m.t0) / 1000;
             m.result = { scene: v.scene.name, panels: v.panels.size,
                          engine_frames_per_s: (v.stats.frames - m.frames0) / secs,
                          animation_frames_per_s: m.raf / secs,
                          sim_rate: m.rates.reduce((a, b) => a + b, 0) / m.rates.length,
                          tick_ms: (w.stats.tickMs - m.tickMs0) / Math.max(1, w.stats.ticks - m.ticks0),
                          load_ms: w.stats.loadMs, wasm_bytes: w.stats.wasmBytes };
           }
         }, 100);
         window.__speed = m;
         return null;",
    )
    .await;
    wait_within(
        client,
        "window.__speed.result",
        "3 s of measurement",
        Duration::from_secs(60),
    )
    .await;
    let result = js(client, "return window.__speed.result;").await;
    eprintln!("static page speed: {result}");
    assert!(
        result["engine_frames_per_s"].as_f64().unwrap() > 0.0,
        "{result}"
    );
    assert!(result["sim_rate"].as_f64().unwrap() > 0.0, "{result}");
    let errors = js(client, "return window.__errors;").await;
    assert_eq!(errors, json!([]), "errors in the page");
}

/// A share URL whose parameter the session refuses (g = 5000 is outside g's range) restores
/// the rest (its panel), says why g was refused and leaves the restore finished, on the
/// served page and on the static one. The static page's engine once delivered the refusal
/// inside the handler that sent the parameter, before it had moved on, and the restore
/// stalled (found in review): replies now come after the sender's handler, as over a
/// WebSocket.
#[test]
fn a_refused_share_url_parameter_leaves_the_rest_restored() {
    in_browser(ServerConfig::default(), |client, addr| {
        refused_share_checks(client, addr).boxed_local()
    });
    let folder = Folder(static_folder("refused-share"));
    in_browser_at(Site::Static(folder.0.clone()), |client, addr| {
        refused_share_checks(client, addr).boxed_local()
    });
}

async fn refused_share_checks(client: &Client, addr: SocketAddr) {
    client
        .goto(&format!(
            "http://{addr}/?scene=parabola&param.g=5000&panel=implicit:rk4:0.005"
        ))
        .await
        .unwrap();
    wait_within(
        client,
        "window.__viewer && window.__viewer.scene && window.__viewer.restore === null && \
         window.__viewer.panels.size === 1 && [...window.__viewer.panels.values()].every(p => \
         p.info.method === 'implicit' && p.info.integrator === 'rk4' && p.info.dt === 0.005) && \
         document.getElementById('messages').textContent.includes('must be a number in')",
        "the panel restored and g refused",
        Duration::from_secs(60),
    )
    .await;
    let g = js(
        client,
        "return window.__viewer.scene.params.find(p => p.name === 'g').value;",
    )
    .await;
    assert_eq!(g.as_f64(), Some(500.0), "g kept at the scene's value");
}

/// When the engine stops (a trap: what a panic in the module becomes), the page says so in
/// its toolbar and its error list, with the reason, and stops ticking; it does not freeze
/// silently.
#[test]
fn a_stopped_engine_is_said_on_the_page() {
    let folder = Folder(static_folder("stopped"));
    in_browser_at(Site::Static(folder.0.clone()), |client, addr| {
        stopped_checks(client, addr).boxed_local()
    });
}

async fn stopped_checks(client: &Client, addr: SocketAddr) {
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_until(
        client,
        &current(1, "f.status === 'running' && f.t > 0.2"),
        "a running panel",
    )
    .await;
    // The module's exports object is frozen: the socket's reference to it is replaced by
    // one whose tick traps as `unreachable` does.
    js(
        client,
        "const w = window.__viewer.ws;
         w.exports = Object.assign({}, w.exports, { bead_tick: () => { throw new WebAssembly.RuntimeError('unreachable'); } });
         return null;",
    )
    .await;
    wait_until(
        client,
        "document.getElementById('connection').textContent.startsWith('stopped (the engine stopped: unreachable)')",
        "the stop said in the toolbar",
    )
    .await;
    let state = js(
        client,
        "const w = window.__viewer.ws; return { ready: w.readyState, ticks: w.stats.ticks, errors: window.__errors };",
    )
    .await;
    assert_eq!(state["ready"], json!(3), "{state}");
    assert!(
        state["errors"].as_array().unwrap().iter().any(|e| e
            .as_str()
            .unwrap()
            .contains("the engine stopped: unreachable")),
        "{state}"
    );
    // No tick after the stop: the count stays (waiting for a later frame of the page's own
    // animation, not for a time).
    let ticks = state["ticks"].as_u64().unwrap();
    js(
        client,
        "window.__frames = 0; const f = () => { window.__frames += 1; if (window.__frames < 30) requestAnimationFrame(f); }; requestAnimationFrame(f); return null;",
    )
    .await;
    wait_until(client, "window.__frames >= 30", "30 animation frames").await;
    let after = js(client, "return window.__viewer.ws.stats.ticks;").await;
    assert_eq!(after, json!(ticks));
}
