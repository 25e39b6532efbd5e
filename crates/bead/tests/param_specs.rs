//! What a scene says about its parameters besides their values (`Scene::param_specs`):
//! tables with `value`, `range`, `unit`, `description` and `integer`, descriptions from the
//! line's comment, derived parameters and whole numbers found from `for` ranges.

use bead::scene::{ParamSpec, Scene};

const CIRCLE: &str = r#"
[params]
g = { value = 9.81, unit = "m/s^2", range = [0, 30] }   # gravitational acceleration
theta0 = { value = "pi/3", unit = "rad", range = ["-pi", "pi"], description = "initial angle" }
L = 1.0              # radius (m)
N = 4                # masses
half = "L/2"         # derived from L
[world]
gravity = [0.0, "g"]
[[particle]]
for = { i = "0..N" }
name = "p{i}"
mass = 1.0
position = ["L*sin(theta0) + i", "L*cos(theta0)"]
"#;

fn spec<'a>(scene: &'a Scene, name: &str) -> &'a ParamSpec {
    scene.param_specs.iter().find(|s| s.name == name).unwrap()
}

#[test]
fn tables_comments_derived_and_whole_parameters() {
    let scene = Scene::parse(CIRCLE, "c.toml", &[]).unwrap();
    let names: Vec<&str> = scene.param_specs.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["g", "theta0", "L", "N", "half"]);
    assert_eq!(scene.params[0], ("g".to_string(), 9.81));
    // The value of an expression in a table has the bits of the expression alone.
    assert_eq!(scene.params[1].1, std::f64::consts::PI / 3.0);
    let g = spec(&scene, "g");
    assert_eq!(g.unit.as_deref(), Some("m/s^2"));
    assert_eq!(g.range, Some([0.0, 30.0]));
    assert_eq!(g.description.as_deref(), Some("gravitational acceleration"));
    assert!(!g.integer && g.expr.is_none() && g.depends_on.is_empty());
    let theta0 = spec(&scene, "theta0");
    // Exact ends: -pi and pi to the last bit.
    assert_eq!(
        theta0.range,
        Some([-std::f64::consts::PI, std::f64::consts::PI])
    );
    assert_eq!(theta0.description.as_deref(), Some("initial angle"));
    assert_eq!(theta0.expr.as_deref(), Some("pi/3"));
    assert!(theta0.depends_on.is_empty());
    let l = spec(&scene, "L");
    assert_eq!(l.description.as_deref(), Some("radius (m)"));
    assert!(l.unit.is_none() && l.range.is_none());
    // N is named by a `for` range: a whole number.
    assert!(spec(&scene, "N").integer);
    let half = spec(&scene, "half");
    assert_eq!(half.depends_on, ["L"]);
    assert_eq!(half.description.as_deref(), Some("derived from L"));
    // Overrides keep the specs.
    let moved = scene.with_param("g", 1.0).unwrap();
    assert_eq!(moved.param_specs, scene.param_specs);
}

#[test]
fn whole_numbers_reach_through_derived_parameters() {
    let text = r#"
[params]
M = 3
K = "M + 1"
[world]
gravity = [0.0, 1.0]
[[particle]]
for = { i = "0..K" }
name = "p{i}"
mass = 1.0
position = ["i", 0.0]
"#;
    let scene = Scene::parse(text, "k.toml", &[]).unwrap();
    assert!(scene.param_specs.iter().all(|s| s.integer));
    assert_eq!(scene.system.particles().len(), 4);
}

fn error(text: &str, overrides: &[(String, f64)]) -> String {
    match Scene::parse(text, "s.toml", overrides) {
        Ok(_) => panic!("expected an error for:\n{text}"),
        Err(e) => e.render(),
    }
}

#[test]
fn bad_parameter_tables_are_located() {
    let scene = |params: &str| {
        format!("[params]\n{params}\n[world]\ngravity = [0.0, 1.0]\n[[particle]]\nname = \"a\"\nmass = 1.0\nposition = [0.0, 0.0]\n")
    };
    let e = error(&scene(r#"g = { unit = "m" }"#), &[]);
    assert!(
        e.starts_with("s.toml:2:1: parameter `g`: a parameter table needs `value`"),
        "{e}"
    );
    let e = error(&scene(r#"g = { value = 1.0, colour = "red" }"#), &[]);
    assert!(e.contains("s.toml:2:") && e.contains("colour"), "{e}");
    let e = error(&scene(r#"g = { value = 1.0, range = [2, 1] }"#), &[]);
    assert!(
        e.contains("s.toml:2:") && e.contains("`range` must be [lo, hi] with lo < hi"),
        "{e}"
    );
    let e = error(
        &scene("h = 2.0\ng = { value = 1.0, range = [0, \"h\"] }"),
        &[],
    );
    assert!(
        e.contains("s.toml:3:") && e.contains("numbers, pi and e only"),
        "{e}"
    );
    let e = error(&scene(r#"n = { value = 2.5, integer = true }"#), &[]);
    assert!(
        e.contains("s.toml:2:") && e.contains("is a whole number (`integer = true`), got 2.5"),
        "{e}"
    );
    let e = error(
        &scene(r#"n = { value = 2, integer = true }"#),
        &[("n".to_string(), 2.5)],
    );
    assert!(
        e.contains("--set n=2.5: parameter `n` is a whole number"),
        "{e}"
    );
    let e = error(&scene("g = [1, 2]"), &[]);
    assert!(
        e.contains("s.toml:2:") && e.contains("a number, an expression string or a table"),
        "{e}"
    );
}

#[test]
fn shipped_scenes_describe_every_parameter() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    for entry in std::fs::read_dir(&dir).unwrap().flatten() {
        let path = entry.path();
        let scene = Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"));
        for spec in &scene.param_specs {
            assert!(
                spec.description.is_some(),
                "{}: `{}` has no description",
                path.display(),
                spec.name
            );
        }
    }
}

#[test]
fn world_units_say_what_the_numbers_are_in() {
    let base = "[world]\ngravity = [0.0, 1.0]\n{units}\n[[particle]]\nname = \"a\"\nmass = 1.0\nposition = [0.0, 0.0]\n";
    let with = |units: &str| base.replace("{units}", units);
    assert_eq!(
        Scene::parse(&with("units = \"SI\""), "u.toml", &[])
            .unwrap()
            .units
            .as_deref(),
        Some("SI")
    );
    assert_eq!(
        Scene::parse(&with("units = \" px \""), "u.toml", &[])
            .unwrap()
            .units
            .as_deref(),
        Some("px")
    );
    assert_eq!(Scene::parse(&with(""), "u.toml", &[]).unwrap().units, None);
    let e = error(&with("units = \"\""), &[]);
    assert!(
        e.starts_with("s.toml:3:9: world: `units` must be \"SI\" or the length unit"),
        "{e}"
    );
    // Every shipped scene says its units.
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    for entry in std::fs::read_dir(&dir).unwrap().flatten() {
        let scene = Scene::load(&entry.path(), &[]).unwrap();
        assert!(scene.units.is_some(), "{}", entry.path().display());
    }
}
