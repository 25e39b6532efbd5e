//! `bead export-page`, run for real: the folder it writes, the committed demo page it
//! rebuilds (docs/demo is current), and every error a user can cause.

mod common;

use std::path::{Path, PathBuf};

use common::{bead_in, fails, ok, TempDir};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn p(path: &Path) -> &str {
    path.to_str().expect("utf-8 path")
}

/// The names in a page's `scenes.js`, in order.
fn scene_names(dir: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join("scenes.js")).unwrap();
    bead_viewer::page::read_scenes_script(&text)
        .expect("a scenes.js of bead export-page")
        .into_iter()
        .map(|s| s.name)
        .collect()
}

/// The folder holds the page, the engine (the committed one, byte for byte, and its base64
/// copy), the scenes (the given one first, then the shipped ones it does not replace) and the
/// embed snippet, which the command also prints.
#[test]
fn the_folder_holds_the_page_the_engine_and_the_scenes() {
    let dir = TempDir::new("export-page");
    let scene = dir.write(
        "my scene.toml",
        &std::fs::read_to_string(root().join("scenes/circle.toml")).unwrap(),
    );
    let out = dir.path("site");
    let printed = ok(bead_in(
        &dir.0,
        &["export-page", p(&scene), "--out", p(&out)],
    ));
    for file in [
        "index.html",
        "viewer.js",
        "viewer.css",
        "engine.js",
        "bead.wasm",
        "bead-wasm.js",
        "scenes.js",
        "embed.html",
    ] {
        assert!(out.join(file).is_file(), "{file}: {printed}");
        assert!(printed.contains(file), "{file}: {printed}");
    }
    let wasm = std::fs::read(out.join("bead.wasm")).unwrap();
    assert_eq!(
        wasm,
        std::fs::read(root().join("docs/demo/bead.wasm")).unwrap()
    );
    let names = scene_names(&out);
    // The circle replaces the shipped circle (same text); the rest follow in picker order.
    assert_eq!(names[0], "my scene");
    assert!(!names.contains(&"circle".to_string()), "{names:?}");
    assert_eq!(names[1], "parabola");
    assert_eq!(names.len(), bead_viewer::scenes::SHIPPED.len());
    let embed = std::fs::read_to_string(out.join("embed.html")).unwrap();
    assert!(
        embed.contains("index.html?scene=my%20scene&amp;present=1\""),
        "{embed}"
    );
    assert!(printed.contains(embed.trim_end()), "{printed}");

    // --only: the given scenes alone, in order; the page names itself.
    let only = dir.path("only");
    ok(bead_in(
        &dir.0,
        &[
            "export-page",
            p(&root().join("scenes/loop.toml")),
            p(&root().join("scenes/parabola.toml")),
            "--only",
            "--out",
            p(&only),
            "--title",
            "Loops & parabolas",
        ],
    ));
    assert_eq!(scene_names(&only), ["loop", "parabola"]);
    let html = std::fs::read_to_string(only.join("index.html")).unwrap();
    assert!(
        html.contains("<title>Loops &amp; parabolas</title>"),
        "{html}"
    );
}

/// docs/demo is what `scripts/build-web` makes of the sources: the same command writes the
/// same files (the engine itself is rebuilt and compared by `scripts/build-web --check` in
/// CI, which needs the wasm32 toolchain).
#[test]
fn the_committed_demo_page_is_current() {
    let dir = TempDir::new("demo-page");
    let out = dir.path("demo");
    ok(bead_in(
        &root(),
        &[
            "export-page",
            "scenes/parabola.toml",
            "--out",
            p(&out),
            "--intro",
            "docs/demo/intro.html",
            "--title",
            "bead: a bead on a wire, two ways",
        ],
    ));
    for entry in std::fs::read_dir(&out).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_str().unwrap().to_string();
        let committed = std::fs::read(root().join("docs/demo").join(&name))
            .unwrap_or_else(|e| panic!("docs/demo/{name}: {e}; run scripts/build-web"));
        assert!(
            std::fs::read(&path).unwrap() == committed,
            "docs/demo/{name} is not what the sources give: run scripts/build-web and commit docs/demo"
        );
    }
}

/// Bad input: a missing or invalid scene (located), two scenes of one name, --only without
/// scenes, a missing intro, an unwritable folder: exit 1 with what and where; no --out:
/// usage, exit 2.
#[test]
fn bad_input_is_refused_with_what_and_where() {
    let dir = TempDir::new("export-page-bad");
    let out = dir.path("site");
    let err = fails(
        bead_in(&dir.0, &["export-page", "nowhere.toml", "--out", p(&out)]),
        1,
    );
    assert!(err.contains("nowhere.toml"), "{err}");
    let bad = dir.write(
        "bad.toml",
        "[world]\ngravity = [0.0, 9.81]\n\n[[particle]]\nname = \"a\"\nmass = 1.0\nposition = [0.0, 0.0]\n\n[[constraint]]\nexpr = \"a.x^2 + \"\n",
    );
    let err = fails(
        bead_in(&dir.0, &["export-page", p(&bad), "--out", p(&out)]),
        1,
    );
    assert!(err.contains("bad.toml:10:"), "{err}");
    let twin = dir.path("twin");
    std::fs::create_dir_all(&twin).unwrap();
    std::fs::copy(root().join("scenes/circle.toml"), twin.join("loop.toml")).unwrap();
    let err = fails(
        bead_in(
            &dir.0,
            &[
                "export-page",
                p(&root().join("scenes/loop.toml")),
                p(&twin.join("loop.toml")),
                "--out",
                p(&out),
            ],
        ),
        1,
    );
    assert!(err.contains("a second scene named `loop`"), "{err}");
    let err = fails(
        bead_in(&dir.0, &["export-page", "--only", "--out", p(&out)]),
        1,
    );
    assert!(err.contains("--only needs at least one scene"), "{err}");
    let err = fails(
        bead_in(
            &dir.0,
            &["export-page", "--intro", "missing.html", "--out", p(&out)],
        ),
        1,
    );
    assert!(err.contains("missing.html"), "{err}");
    let file = dir.write("a-file", "not a folder");
    let err = fails(bead_in(&dir.0, &["export-page", "--out", p(&file)]), 1);
    assert!(err.contains("a-file"), "{err}");
    let err = fails(bead_in(&dir.0, &["export-page"]), 2);
    assert!(err.contains("--out"), "{err}");
    assert!(!out.exists(), "nothing written by a refused command");
}

/// A folder whose index.html another tool wrote (a site's front page) is not overwritten
/// without --force; a page export-page wrote is written again.
#[test]
fn a_sites_own_index_html_is_not_replaced_without_force() {
    let dir = TempDir::new("export-page-site");
    let site = dir.path("site");
    std::fs::create_dir_all(&site).unwrap();
    std::fs::write(site.join("index.html"), "<html>my site</html>").unwrap();
    let err = fails(bead_in(&dir.0, &["export-page", "--out", p(&site)]), 1);
    assert!(
        err.contains("index.html exists and is not a page bead export-page wrote"),
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(site.join("index.html")).unwrap(),
        "<html>my site</html>"
    );
    ok(bead_in(
        &dir.0,
        &["export-page", "--out", p(&site), "--force"],
    ));
    // Ours now: written again without --force.
    ok(bead_in(&dir.0, &["export-page", "--out", p(&site)]));
    assert!(std::fs::read_to_string(site.join("index.html"))
        .unwrap()
        .contains("engine.js"));
}
