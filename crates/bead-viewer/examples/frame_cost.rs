//! Measures the viewer's own per-frame costs for a scene: loading, a frame's stepping,
//! building, encoding (binary, as sent, and the JSON text protocol version 2 sent) and, with
//! `--wire SECONDS`, frames received per second by a WebSocket client of a real server.
//!
//! `cargo run -p bead-viewer --example frame_cost -- SCENE [--wire 3] [--write FILE]`
//!
//! SCENE is a scene file, or a generated scene (the tests' generators): `chain N
//! [INTEGRATOR]`, `cloth ROWS COLS [INTEGRATOR]` (rods), `cloth3d ROWS COLS [INTEGRATOR]`
//! (the same in 3D), `springs ROWS COLS` (a cloth of springs pinned at two corners), `free N`
//! (N particles falling, no constraints). `--write FILE` saves the scene text.

#[path = "../tests/generated/mod.rs"]
mod generated;

use std::sync::Arc;
use std::time::{Duration, Instant};

use bead_viewer::protocol::{encode_frame, Limits, PanelFrame, ServerMessage};
use bead_viewer::session::Session;
use bead_viewer::{Catalog, NamedScene, ServerConfig};
use futures_util::StreamExt;
use serde::Serialize;

/// A panel as protocol version 2 sent it: positions as a JSON array.
#[derive(Serialize)]
struct JsonPanel<'a> {
    #[serde(flatten)]
    frame: &'a PanelFrame,
    x: &'a [f64],
}

#[derive(Serialize)]
struct JsonFrame<'a> {
    #[serde(rename = "type")]
    kind: &'static str,
    time_scale: f64,
    panels: Vec<JsonPanel<'a>>,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let option = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .map(|i| args[i + 1].clone())
    };
    let wire = option("--wire").map(|s| s.parse::<f64>().unwrap());
    let positional: Vec<&str> = args
        .iter()
        .take_while(|a| !a.starts_with("--"))
        .map(String::as_str)
        .collect();
    let number = |i: usize| positional[i].parse::<usize>().unwrap();
    let text = match positional.as_slice() {
        ["chain", _, rest @ ..] => generated::chain(number(1), rest.first().unwrap_or(&"rattle")),
        ["cloth", _, _, rest @ ..] => {
            generated::cloth(number(1), number(2), rest.first().unwrap_or(&"rattle"))
        }
        ["cloth3d", _, _, rest @ ..] => {
            generated::cloth_3d(number(1), number(2), rest.first().unwrap_or(&"rattle"))
        }
        ["springs", _, _] => generated::spring_cloth(number(1), number(2)),
        ["free", _] => generated::free(number(1)),
        [path] => std::fs::read_to_string(path).unwrap(),
        _ => panic!("usage: frame_cost SCENE [--wire SECONDS] [--write FILE]"),
    };
    if let Some(file) = option("--write") {
        std::fs::write(file, &text).unwrap();
    }
    let catalog = Arc::new(Catalog::with_first(NamedScene {
        name: "scene".into(),
        text,
    }));
    let start = Instant::now();
    let mut session = Session::new(Arc::clone(&catalog), Limits::default());
    let load = start.elapsed();
    let greeting = session.greeting();
    let scene_bytes: usize = greeting
        .iter()
        .map(|m| serde_json::to_string(m).unwrap().len())
        .sum();
    println!(
        "load {:.3} s, greeting {} bytes, panels {}",
        load.as_secs_f64(),
        scene_bytes,
        session.panel_count()
    );
    if session.panel_count() == 0 {
        let replies = session.handle(bead_viewer::protocol::ClientMessage::LoadScene {
            name: Some("scene".into()),
            toml: None,
            file_name: None,
        });
        println!("refused: {replies:?}");
        return;
    }
    // A few frames of stepping, each timed.
    let mut steps = Vec::new();
    for _ in 0..10 {
        let start = Instant::now();
        session.advance(1.0 / 60.0);
        steps.push(start.elapsed().as_secs_f64() * 1e3);
    }
    let ServerMessage::Frame { panels, .. } = session.frame() else {
        unreachable!()
    };
    println!(
        "advance per frame: median {:.2} ms; {} steps, {:.1} steps/s; t = {}, status {}, behind {}{}",
        median(steps),
        panels[0].steps,
        panels[0].steps_per_second,
        panels[0].t,
        panels[0].status,
        panels[0].behind,
        panels[0]
            .error
            .as_deref()
            .map(|e| format!(", error: {e}"))
            .unwrap_or_default()
    );
    let (mut build, mut binary, mut json) = (Vec::new(), Vec::new(), Vec::new());
    let (mut binary_bytes, mut json_bytes) = (0, 0);
    for _ in 0..200 {
        let start = Instant::now();
        let frame = session.frame();
        build.push(start.elapsed().as_secs_f64() * 1e3);
        let ServerMessage::Frame {
            time_scale, panels, ..
        } = &frame
        else {
            unreachable!()
        };
        let start = Instant::now();
        let bytes = encode_frame(*time_scale, panels).unwrap();
        binary.push(start.elapsed().as_secs_f64() * 1e3);
        binary_bytes = bytes.len();
        let start = Instant::now();
        let text = serde_json::to_string(&JsonFrame {
            kind: "frame",
            time_scale: *time_scale,
            panels: panels
                .iter()
                .map(|frame| JsonPanel { frame, x: &frame.x })
                .collect(),
        })
        .unwrap();
        json.push(start.elapsed().as_secs_f64() * 1e3);
        json_bytes = text.len();
    }
    println!(
        "frame build {:.3} ms; binary {} bytes in {:.3} ms; json (v2) {} bytes in {:.3} ms (medians of 200)",
        median(build),
        binary_bytes,
        median(binary),
        json_bytes,
        median(json)
    );
    if let Some(seconds) = wire {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap();
        runtime.block_on(async move {
            let listener = bead_viewer::server::bind("127.0.0.1:0".parse().unwrap())
                .await
                .unwrap();
            let addr = listener.local_addr().unwrap();
            tokio::spawn(bead_viewer::serve(
                listener,
                ServerConfig {
                    catalog,
                    limits: Limits::default(),
                    ..ServerConfig::default()
                },
            ));
            let (mut client, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/ws"))
                .await
                .unwrap();
            // Skip the greeting and the first frame (loading).
            loop {
                if let Some(Ok(tokio_tungstenite::tungstenite::Message::Binary(_))) =
                    client.next().await
                {
                    break;
                }
            }
            let start = Instant::now();
            let (mut frames, mut bytes) = (0u64, 0usize);
            while start.elapsed() < Duration::from_secs_f64(seconds) {
                if let Some(Ok(tokio_tungstenite::tungstenite::Message::Binary(b))) =
                    client.next().await
                {
                    frames += 1;
                    bytes += b.len();
                }
            }
            let wall = start.elapsed().as_secs_f64();
            println!(
                "wire: {:.1} frames/s, {:.2} MB/s over {:.1} s",
                frames as f64 / wall,
                bytes as f64 / wall / 1e6,
                wall
            );
        });
    }
}
