//! A scene's warnings say which line of the file they are about, so that a front end can
//! point at it (Python raises each as a `UserWarning` at that file and line).

use bead::scene::{Scene, SceneWarning};

/// The article's parabola with the bead 8 px below the wire, its velocity on its own line,
/// and a rod whose length is not the initial distance (a table without `expr`).
const OFF: &str = r#"title = "Bead off the parabola"

[world]
gravity = [0.0, 500.0]

[[particle]]
name = "bead"
mass = 1.0
position = [150.0, -217.0]
velocity = [0.0, 3.0]

[[particle]]
name = "stone"
mass = 1.0
position = [10.0, 0.0]

[[constraint]]
expr = "bead.x^2 + 100*bead.y"

[[constraint]]
kind = "distance"
particle = "stone"
anchor = [0.0, 0.0]
length = 2.0

[parametric]
coordinates = ["q", "a"]
initial = [150.0, 0.0]
rates = [0.0, 0.0]

[parametric.positions]
bead = ["q", "-q^2/100"]
stone = ["2*cos(a)", "2*sin(a)"]
"#;

#[test]
fn each_warning_has_the_line_it_is_about() {
    let scene = Scene::parse(OFF, "off.toml", &[]).unwrap();
    let warnings = scene.located_warnings();
    let found: Vec<(Option<usize>, &str)> = warnings
        .iter()
        .map(|w| (w.line, w.message.split(':').next().unwrap()))
        .collect();
    assert_eq!(
        found,
        [
            // The parametric form starts elsewhere: the particle's position and velocity.
            (Some(9), "particle `bead`"),
            (Some(10), "particle `bead`"),
            (Some(15), "particle `stone`"),
            // Off the wire, off the rod's circle: the constraint's expr, the rod's table.
            (Some(18), "constraint 1 (`bead.x^2 + 100*bead.y = 0`)"),
            (Some(20), "constraint 2 (`distance(stone, [0.0, 0.0]) = 2`)"),
        ],
        "{warnings:#?}"
    );
    let messages: Vec<String> = warnings.into_iter().map(|w| w.message).collect();
    assert_eq!(scene.warnings(), messages);
}

#[test]
fn a_scene_that_starts_on_its_constraints_has_no_warnings() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/parabola.toml");
    let scene = Scene::load(std::path::Path::new(path), &[]).unwrap();
    assert_eq!(scene.located_warnings(), Vec::<SceneWarning>::new());
}
