//! The viewer's page, and the same page as a static folder that needs no server.
//!
//! The served page ([`INDEX_HTML`], [`VIEWER_JS`], [`VIEWER_CSS`]) talks to a [`Session`]
//! over the server's WebSocket. The static page ([`StaticPage`]) is the same page and the
//! same script with one more script before it, [`ENGINE_JS`]: the session compiled to
//! WebAssembly (`crates/bead-web`), behind an object with the WebSocket's interface
//! (`send`, `onmessage`, `readyState`), so that the page cannot tell the two apart. The
//! session's messages are the protocol's ([`crate::protocol`]) in both.
//!
//! A static folder holds:
//! - `index.html`, `viewer.js`, `viewer.css`: the page;
//! - `engine.js`: loads the engine, runs the session's clock (~60 ticks a second);
//! - `bead.wasm`: the engine; `bead-wasm.js`: the same bytes in base64, which the page loads
//!   where it cannot fetch a file (opened from `file://`);
//! - `scenes.js`: the picker's scenes (name and TOML text), the first loaded on open;
//! - `embed.html`: an `<iframe>` snippet that shows the first scene in a post.
//!
//! [`Session`]: crate::session::Session

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::scenes::NamedScene;

/// The page (served as `/`).
pub const INDEX_HTML: &str = include_str!("../assets/index.html");
/// The page's script (protocol client, drawing, controls).
pub const VIEWER_JS: &str = include_str!("../assets/viewer.js");
/// The page's style.
pub const VIEWER_CSS: &str = include_str!("../assets/viewer.css");
/// The static page's transport: the engine in the page, with a WebSocket's interface.
pub const ENGINE_JS: &str = include_str!("../assets/engine.js");

/// The tag that loads the page's script; the static page puts its own scripts before it.
const VIEWER_SCRIPT_TAG: &str = r#"<script src="viewer.js"></script>"#;
/// Where the static page puts its introduction: after the toolbar.
const INTRO_ANCHOR: &str = r#"<section id="scene-bar">"#;

/// A static page to write: its scenes, the engine, and an optional introduction.
#[derive(Clone, Debug)]
pub struct StaticPage<'a> {
    /// The picker's scenes in order; the first is loaded when the page opens.
    pub scenes: Vec<NamedScene>,
    /// The engine: `bead_web.wasm` built for wasm32-unknown-unknown.
    pub wasm: &'a [u8],
    /// An HTML fragment shown above the scene (the article's lesson on the demo page).
    pub intro_html: Option<String>,
    /// The page's title (the browser tab).
    pub title: String,
}

/// Why a static page could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PageError {
    #[error("a static page needs at least one scene")]
    NoScenes,
    #[error("two scenes are named `{0}`; each scene of a page needs its own name")]
    DuplicateName(String),
    #[error("the engine (bead.wasm) is not a WebAssembly module ({0} bytes without the `\\0asm` header)")]
    NotWasm(usize),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// The files of a static page: (file name, contents), in a fixed order.
pub type PageFiles = Vec<(&'static str, Vec<u8>)>;

impl StaticPage<'_> {
    /// The page's files, in memory ([`StaticPage::write`] writes them).
    pub fn files(&self) -> Result<PageFiles, PageError> {
        let Some(first) = self.scenes.first() else {
            return Err(PageError::NoScenes);
        };
        for (i, scene) in self.scenes.iter().enumerate() {
            if self.scenes[..i].iter().any(|s| s.name == scene.name) {
                return Err(PageError::DuplicateName(scene.name.clone()));
            }
        }
        if !self.wasm.starts_with(b"\0asm") {
            return Err(PageError::NotWasm(self.wasm.len()));
        }
        Ok(vec![
            ("index.html", self.index_html().into_bytes()),
            ("viewer.js", VIEWER_JS.as_bytes().to_vec()),
            ("viewer.css", VIEWER_CSS.as_bytes().to_vec()),
            ("engine.js", ENGINE_JS.as_bytes().to_vec()),
            ("bead.wasm", self.wasm.to_vec()),
            ("bead-wasm.js", wasm_script(self.wasm).into_bytes()),
            ("scenes.js", scenes_script(&self.scenes).into_bytes()),
            ("embed.html", embed_snippet(&first.name).into_bytes()),
        ])
    }

    /// Write the page's files into `dir` (created if missing; files of the same names are
    /// replaced, others left alone).
    pub fn write(&self, dir: &Path) -> Result<PageFiles, PageError> {
        let files = self.files()?;
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| PageError::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        for (name, contents) in &files {
            let path = dir.join(name);
            std::fs::write(&path, contents).map_err(io(&path))?;
        }
        Ok(files)
    }

    fn index_html(&self) -> String {
        let scripts = format!(
            "<script src=\"scenes.js\"></script>\n<script src=\"engine.js\"></script>\n{VIEWER_SCRIPT_TAG}"
        );
        let mut html = INDEX_HTML.replacen(VIEWER_SCRIPT_TAG, &scripts, 1);
        html = html.replacen(
            "<title>bead viewer</title>",
            &format!("<title>{}</title>", escape_html(&self.title)),
            1,
        );
        if let Some(intro) = &self.intro_html {
            let section = format!("<section id=\"intro\">\n{intro}\n</section>\n{INTRO_ANCHOR}");
            html = html.replacen(INTRO_ANCHOR, &section, 1);
        }
        html
    }
}

/// `scenes.js`: the scenes as a JavaScript array of `{name, text}` (JSON, which is
/// JavaScript; a script file rather than a fetched JSON file so that `file://` pages load it).
fn scenes_script(scenes: &[NamedScene]) -> String {
    let list: Vec<serde_json::Value> = scenes
        .iter()
        .map(|s| serde_json::json!({ "name": s.name, "text": s.text }))
        .collect();
    let json = serde_json::to_string_pretty(&list).unwrap_or_else(|_| "[]".into());
    format!(
        "// The scenes of this page (name and TOML text), written by `bead export-page`; the first is loaded on open.\n{SCENES_ASSIGNMENT}{json};\n"
    )
}

/// The assignment `scenes.js` makes (the page reads the scenes there).
const SCENES_ASSIGNMENT: &str = "window.BEAD_SCENES = ";

/// The scenes of a `scenes.js` that [`StaticPage`] wrote, in order; `None` when `text` is not
/// one.
pub fn read_scenes_script(text: &str) -> Option<Vec<NamedScene>> {
    let json = text
        .split_once(SCENES_ASSIGNMENT)?
        .1
        .trim_end()
        .strip_suffix(';')?;
    let list: Vec<serde_json::Value> = serde_json::from_str(json).ok()?;
    list.iter()
        .map(|s| {
            Some(NamedScene {
                name: s.get("name")?.as_str()?.to_string(),
                text: s.get("text")?.as_str()?.to_string(),
            })
        })
        .collect()
}

/// `bead-wasm.js`: the engine's bytes in base64, for pages opened from `file://`, where a
/// browser refuses to fetch `bead.wasm`.
fn wasm_script(wasm: &[u8]) -> String {
    let mut out = String::with_capacity(wasm.len() * 4 / 3 + 200);
    out.push_str("// bead.wasm in base64, for pages opened from file:// (written by `bead export-page`).\nwindow.BEAD_WASM_BASE64 = \"");
    base64_into(wasm, &mut out);
    out.push_str("\";\n");
    out
}

/// Standard base64 (RFC 4648, with padding).
fn base64_into(bytes: &[u8], out: &mut String) {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[((n >> (18 - 6 * k)) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
}

/// `embed.html`: an `<iframe>` that shows `scene` from the folder in presentation mode (the
/// canvases fit the frame), to paste into a post (`PAGE_URL` is where the folder is
/// published).
pub fn embed_snippet(scene: &str) -> String {
    let mut out = String::new();
    let query = url_component(scene);
    let _ = writeln!(
        out,
        "<!-- Paste into a post; replace PAGE_URL with where this folder is published (e.g. https://example.org/bead). -->"
    );
    let _ = writeln!(
        out,
        "<iframe src=\"PAGE_URL/index.html?scene={query}&amp;present=1\" title=\"bead: {}\" width=\"100%\" height=\"720\" style=\"border: 1px solid #ccc\" loading=\"lazy\"></iframe>",
        escape_html(scene)
    );
    out
}

/// Percent-encoding of a URL query value (everything but unreserved characters).
fn url_component(text: &str) -> String {
    let mut out = String::new();
    for b in text.bytes() {
        if b.is_ascii_alphanumeric() || b"-_.~".contains(&b) {
            out.push(b as char);
        } else {
            let _ = write!(out, "%{b:02X}");
        }
    }
    out
}

fn escape_html(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(name: &str) -> NamedScene {
        NamedScene {
            name: name.into(),
            text: format!("# {name}\n"),
        }
    }

    #[test]
    fn base64_matches_the_rfc_examples() {
        // RFC 4648, section 10.
        for (input, want) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            let mut out = String::new();
            base64_into(input.as_bytes(), &mut out);
            assert_eq!(out, want, "{input}");
        }
    }

    #[test]
    fn the_static_page_is_the_served_page_with_the_engine_before_its_script() {
        let wasm = b"\0asm\x01\0\0\0";
        let page = StaticPage {
            scenes: vec![scene("parabola"), scene("a b")],
            wasm,
            intro_html: Some("<p>The lesson.</p>".into()),
            title: "bead <demo>".into(),
        };
        let files = page.files().unwrap();
        let names: Vec<&str> = files.iter().map(|(n, _)| *n).collect();
        assert_eq!(
            names,
            [
                "index.html",
                "viewer.js",
                "viewer.css",
                "engine.js",
                "bead.wasm",
                "bead-wasm.js",
                "scenes.js",
                "embed.html"
            ]
        );
        let html = String::from_utf8(files[0].1.clone()).unwrap();
        let order: Vec<usize> = ["scenes.js", "engine.js", "viewer.js"]
            .iter()
            .map(|s| html.find(&format!("<script src=\"{s}\">")).unwrap())
            .collect();
        assert!(order[0] < order[1] && order[1] < order[2], "{order:?}");
        assert!(html.contains("<title>bead &lt;demo&gt;</title>"));
        assert!(html.find("The lesson.").unwrap() < html.find(INTRO_ANCHOR).unwrap());
        // Everything else is the served page's.
        let back = html
            .replace(
                "<script src=\"scenes.js\"></script>\n<script src=\"engine.js\"></script>\n",
                "",
            )
            .replace(
                "<section id=\"intro\">\n<p>The lesson.</p>\n</section>\n",
                "",
            )
            .replace("bead &lt;demo&gt;", "bead viewer");
        assert_eq!(back, INDEX_HTML);
        let scenes = read_scenes_script(std::str::from_utf8(&files[6].1).unwrap()).unwrap();
        assert_eq!(scenes, page.scenes);
        assert_eq!(read_scenes_script("window.X = [];"), None);
        let embed = String::from_utf8(files[7].1.clone()).unwrap();
        assert!(
            embed.contains("index.html?scene=parabola&amp;present=1\""),
            "{embed}"
        );
        assert!(embed_snippet("a b").contains("?scene=a%20b&amp;"));
    }

    #[test]
    fn a_page_without_scenes_or_engine_or_with_two_scenes_of_one_name_is_refused() {
        let wasm = b"\0asm\x01\0\0\0";
        let page = |scenes, wasm| StaticPage {
            scenes,
            wasm,
            intro_html: None,
            title: "t".into(),
        };
        assert!(matches!(
            page(vec![], wasm).files(),
            Err(PageError::NoScenes)
        ));
        assert!(matches!(
            page(vec![scene("a"), scene("a")], wasm).files(),
            Err(PageError::DuplicateName(n)) if n == "a"
        ));
        assert!(matches!(
            page(vec![scene("a")], b"<html>").files(),
            Err(PageError::NotWasm(6))
        ));
    }
}
