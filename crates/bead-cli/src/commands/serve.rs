//! `bead serve`: the live browser viewer (crate `bead_viewer`).

use std::io::Write;
use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use bead_viewer::protocol::Limits;
use bead_viewer::{Catalog, NamedScene, ServerConfig};

use super::{load_scene, warn};
use crate::args::ServeArgs;

/// Serve until interrupted.
pub fn serve(args: &ServeArgs) -> Result<()> {
    let catalog = match &args.scene {
        Some(path) => Catalog::with_first(viewer_scene(path, scene_name(path))?),
        None => Catalog::shipped(),
    };
    let config = ServerConfig {
        catalog: Arc::new(catalog),
        ..ServerConfig::default()
    };
    let addr = SocketAddr::new(args.host, args.port);
    if !args.host.is_loopback() {
        warn(&format!(
            "listening on {}: the viewer has no authentication; anyone who can reach this address can use it",
            args.host
        ));
    }
    let open = args.open;
    bead_viewer::serve_blocking(addr, config, |bound| {
        let host = if bound.ip().is_unspecified() {
            "127.0.0.1".to_string()
        } else if bound.is_ipv6() {
            format!("[{}]", bound.ip())
        } else {
            bound.ip().to_string()
        };
        let url = format!("http://{host}:{}/", bound.port());
        // A closed stdout (the caller stopped reading) must not take the server down, so
        // write without println!'s panic on a broken pipe.
        let mut stdout = std::io::stdout();
        let _ = writeln!(stdout, "bead viewer at {url}");
        let _ = writeln!(stdout, "press Ctrl-C to stop");
        let _ = stdout.flush();
        if open {
            open_browser(&url);
        }
    })
    .with_context(|| format!("cannot serve on {addr}"))
}

/// A scene file for the viewer's picker, named `name`, checked up front so that a bad scene
/// fails here, located, not in the page; the viewer's particle limit too (a session refuses
/// more).
pub(super) fn viewer_scene(path: &Path, name: String) -> Result<NamedScene> {
    let scene = load_scene(path, &[])?;
    let (count, limit) = (
        scene.system.particles().len(),
        Limits::default().max_particles,
    );
    if count > limit {
        bail!(
            "{}: too many particles for the viewer: {count} (limit {limit})",
            path.display()
        );
    }
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read `{}`", path.display()))?;
    Ok(NamedScene { name, text })
}

/// The picker name (and share URL's `scene=`) of a scene file: its file name without
/// `.toml`, for `bead serve` and `bead export-page` alike.
pub(super) fn scene_name(path: &Path) -> String {
    path.file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string())
}

/// Open `url` with `open` (macOS) or `xdg-open` (elsewhere); warn when that fails.
fn open_browser(url: &str) {
    let opener = if cfg!(target_os = "macos") {
        "open"
    } else {
        "xdg-open"
    };
    let failed = move |why: String| {
        warn(&format!(
            "could not open a browser ({opener} {why}); open {url} yourself"
        ))
    };
    let url = url.to_string();
    match std::process::Command::new(opener)
        .arg(&url)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
    {
        Ok(mut child) => {
            // Do not hold the server up: wait for the opener on the side.
            std::thread::spawn(move || match child.wait() {
                Ok(status) if status.success() => {}
                Ok(status) => warn(&format!(
                    "could not open a browser ({opener} exited with {status}); open {url} yourself"
                )),
                Err(e) => warn(&format!(
                    "could not open a browser ({opener}: {e}); open {url} yourself"
                )),
            });
        }
        Err(e) => failed(format!("could not start: {e}")),
    }
}
