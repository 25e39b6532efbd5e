//! `bead export-page`: the viewer as a static folder (no server: the engine runs in the page,
//! `bead_viewer::page`).

use std::collections::HashSet;
use std::io::Write;
use std::path::Path;

use anyhow::{bail, Context, Result};
use bead_viewer::page::StaticPage;
use bead_viewer::{Catalog, NamedScene};

use super::serve::{scene_name, viewer_scene};
use crate::args::ExportPageArgs;

/// The engine: `crates/bead-web` built for wasm32 by `scripts/build-web`, committed with the
/// demo page (CI rebuilds it and checks that it is current).
pub const ENGINE_WASM: &[u8] = include_bytes!("../../../../docs/demo/bead.wasm");

/// Write the folder; print its files and the embed snippet.
pub fn export_page(args: &ExportPageArgs) -> Result<()> {
    let scenes = page_scenes(&args.scenes, args.only)?;
    let intro_html = match &args.intro {
        Some(path) => Some(
            std::fs::read_to_string(path)
                .with_context(|| format!("cannot read `{}`", path.display()))?,
        ),
        None => None,
    };
    refuse_foreign_page(&args.out, args.force)?;
    let page = StaticPage {
        scenes,
        wasm: ENGINE_WASM,
        intro_html,
        title: args.title.clone(),
    };
    let files = page.write(&args.out)?;
    let mut stdout = std::io::stdout().lock();
    let total: usize = files.iter().map(|(_, c)| c.len()).sum();
    writeln!(
        stdout,
        "wrote {} ({} files, {:.2} MB; the page loads bead.wasm, {:.2} MB, or from file:// its base64 copy):",
        args.out.display(),
        files.len(),
        total as f64 / 1e6,
        ENGINE_WASM.len() as f64 / 1e6
    )?;
    for (name, contents) in &files {
        writeln!(stdout, "  {name:<14} {:>9} bytes", contents.len())?;
    }
    writeln!(
        stdout,
        "open {}/index.html, or publish the folder on any static host; to embed the first scene in a post:",
        args.out.display()
    )?;
    let embed = files
        .iter()
        .find(|(name, _)| *name == "embed.html")
        .map(|(_, c)| String::from_utf8_lossy(c).into_owned())
        .unwrap_or_default();
    write!(stdout, "{embed}")?;
    Ok(())
}

/// The picker's scenes: each given file (named by its file stem, checked as `bead serve`
/// checks its scene), then the shipped scenes not replaced by one of them (same name or same
/// text), unless `only`. No file: the shipped scenes.
fn page_scenes(paths: &[std::path::PathBuf], only: bool) -> Result<Vec<NamedScene>> {
    let mut given: Vec<NamedScene> = Vec::new();
    let mut names = HashSet::new();
    for path in paths {
        let scene = viewer_scene(path, scene_name(path))?;
        if !names.insert(scene.name.clone()) {
            bail!(
                "{}: a second scene named `{}` (scenes are named by their file names without .toml)",
                path.display(),
                scene.name
            );
        }
        given.push(scene);
    }
    if only && given.is_empty() {
        bail!("--only needs at least one scene file");
    }
    let mut scenes = given.clone();
    if !only {
        scenes.extend(
            Catalog::shipped()
                .scenes
                .into_iter()
                .filter(|s| !given.iter().any(|g| g.name == s.name || g.text == s.text)),
        );
    }
    Ok(scenes)
}

/// Refuse to replace an `index.html` in `dir` that is not a page `bead export-page` wrote (it
/// loads `engine.js`), unless `force`: a site's own front page is not ours to overwrite.
fn refuse_foreign_page(dir: &Path, force: bool) -> Result<()> {
    let index = dir.join("index.html");
    if force || !index.is_file() {
        return Ok(());
    }
    let text = std::fs::read_to_string(&index).unwrap_or_default();
    if !text.contains(r#"<script src="engine.js"></script>"#) {
        bail!(
            "{} exists and is not a page bead export-page wrote; choose another --out, or --force to replace it",
            index.display()
        );
    }
    Ok(())
}
