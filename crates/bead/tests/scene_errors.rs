//! Every class of scene error, rendered exactly: file, line, column, message and the caret
//! under the offending text. And a fuzz test: no input makes the loader panic.

use std::path::Path;

use bead::scene::Scene;

/// A valid scene that the tests break one way at a time.
const BASE: &str = r#"title = "t"
[params]
g = 10.0
[world]
gravity = [0.0, "g"]
[[particle]]
name = "bead"
mass = 1.0
position = [1.0, 0.0]
[[constraint]]
expr = "bead.x^2 + bead.y^2 - 1"
"#;

/// A parametric form for BASE.
const PARAMETRIC: &str = r#"[parametric]
coordinates = ["q"]
initial = [0.0]
[parametric.positions]
bead = ["cos(q)", "sin(q)"]
"#;

fn error(text: &str) -> String {
    error_with(text, &[])
}

fn error_with(text: &str, overrides: &[(String, f64)]) -> String {
    match Scene::parse(text, "s.toml", overrides) {
        Ok(_) => panic!("expected an error for:\n{text}"),
        Err(e) => {
            assert!(
                e.render()
                    .starts_with(&format!("s.toml:{}:{}: ", e.line, e.column))
                    || e.line == 0
            );
            e.render()
        }
    }
}

/// BASE with `from` replaced by `to` (which must occur).
fn edit(from: &str, to: &str) -> String {
    assert!(BASE.contains(from), "{from}");
    BASE.replacen(from, to, 1)
}

#[test]
fn base_and_base_with_parametric_form_load() {
    Scene::parse(BASE, "s.toml", &[]).unwrap();
    let scene = Scene::parse(&format!("{BASE}{PARAMETRIC}"), "s.toml", &[]).unwrap();
    assert!(scene.warnings().is_empty(), "{:?}", scene.warnings());
}

#[test]
fn toml_syntax_error() {
    assert_eq!(
        error(&edit("mass = 1.0", "mass = = 1.0")),
        "s.toml:8:8: extra `=`, expected nothing\n  mass = = 1.0\n         ^"
    );
    assert_eq!(
        error(&edit("name = \"bead\"", "name = \"bead")),
        "s.toml:7:13: invalid basic string, expected `\"`\n  name = \"bead\n              ^"
    );
    assert_eq!(
        error(&edit("mass = 1.0", "mass = 1.0\nmass = 2.0")),
        "s.toml:9:1: duplicate key `mass`\n  mass = 2.0\n  ^^^^"
    );
}

#[test]
fn unknown_key() {
    assert_eq!(
        error(&edit("mass = 1.0", "mass = 1.0\ncolour = \"red\"")),
        "s.toml:9:1: unknown key `colour`, expected one of `for`, `name`, `mass`, `position`, `velocity`\n  colour = \"red\"\n  ^^^^^^"
    );
    assert_eq!(
        error(&format!("{BASE}[wrold]\n")),
        "s.toml:12:2: unknown key `wrold`, expected one of `title`, `about`, `params`, `world`, `particle`, `force`, \
         `constraint`, `parametric`, `run`, `event`\n  [wrold]\n   ^^^^^"
    );
    assert_eq!(
        error(&format!(
            "{BASE}[run]\nstabilize = {{ frequency = 1.0, damp = 1 }}\n"
        )),
        "s.toml:13:32: unknown key `damp`, expected `frequency` or `damping`\n  \
         stabilize = { frequency = 1.0, damp = 1 }\n                                 ^^^^"
    );
}

#[test]
fn wrong_type() {
    assert_eq!(
        error(&edit("mass = 1.0", "mass = true")),
        "s.toml:8:8: invalid type: boolean `true`, expected a number or an expression string\n  mass = true\n         ^^^^"
    );
    assert_eq!(
        error(&edit("name = \"bead\"", "name = 3")),
        "s.toml:7:8: invalid type: integer `3`, expected a string\n  name = 3\n         ^"
    );
    assert_eq!(
        error(&edit("position = [1.0, 0.0]", "position = 1.0")),
        "s.toml:9:12: invalid type: floating point `1.0`, expected an array of numbers or expression strings\n  \
         position = 1.0\n             ^^^"
    );
    assert_eq!(
        error(&edit("[[particle]]", "[particle]")),
        "s.toml:6:1: invalid type: map, expected an array of tables (`[[...]]` sections)\n  [particle]\n  ^^^^^^^^^^"
    );
}

#[test]
fn missing_mass() {
    assert_eq!(
        error(&format!(
            "{BASE}[[particle]]\nname = \"b\"\nposition = [0.0, 0.0]\n"
        )),
        "s.toml:12:1: particle 2: missing `mass`\n  [[particle]]\n  ^^^^^^^^^^^^"
    );
}

#[test]
fn mass_not_positive() {
    assert_eq!(
        error(&edit("mass = 1.0", "mass = -1.0")),
        "s.toml:8:8: particle 1: `mass` must be positive, got -1\n  mass = -1.0\n         ^^^^"
    );
    assert_eq!(
        error(&edit("mass = 1.0", "mass = \"g - 10\"")),
        "s.toml:8:8: particle 1: `mass` must be positive, got 0\n  mass = \"g - 10\"\n         ^^^^^^^^"
    );
}

/// A mass of 1e308 was refused by the builder but located at the particle's name (issue 7).
#[test]
fn mass_out_of_range_is_located_at_the_mass() {
    assert_eq!(
        error(&edit("mass = 1.0", "mass = 1e308")),
        "s.toml:8:8: particle 1: `mass` must be between 1e-100 and 1e100, got 1e308: masses, \
         their inverses and momenta must stay far from overflow and underflow\n  mass = 1e308\n         ^^^^^"
    );
    assert!(error(&edit("mass = 1.0", "mass = \"1e-200\"")).contains("got 1e-200"));
}

#[test]
fn nan_and_inf() {
    assert_eq!(
        error(&edit("mass = 1.0", "mass = nan")),
        "s.toml:8:8: particle 1: `mass` must be finite, got NaN\n  mass = nan\n         ^^^"
    );
    assert_eq!(
        error(&edit("position = [1.0, 0.0]", "position = [1.0, -inf]")),
        "s.toml:9:18: particle 1: component 2 of `position` must be finite, got -inf\n  \
         position = [1.0, -inf]\n                   ^^^^"
    );
    assert_eq!(
        error(&edit("mass = 1.0", "mass = \"1/0\"")),
        "s.toml:8:8: particle 1: `mass` must be finite, got inf\n  mass = \"1/0\"\n         ^^^^^"
    );
}

#[test]
fn dimension_mismatch() {
    assert_eq!(
        error(&edit("position = [1.0, 0.0]", "position = [1.0, 0.0, 0.0]")),
        "s.toml:9:12: particle 1: `position` has 3 components but the scene is 2D (set by the length of `gravity`)\n  \
         position = [1.0, 0.0, 0.0]\n             ^^^^^^^^^^^^^^^"
    );
    assert_eq!(
        error(&edit("gravity = [0.0, \"g\"]", "gravity = [0.0, \"g\", 0, 0]")),
        "s.toml:5:11: world: `gravity` must have 2 or 3 components (it sets the dimension), got 4\n  \
         gravity = [0.0, \"g\", 0, 0]\n            ^^^^^^^^^^^^^^^^"
    );
}

#[test]
fn duplicate_particle_name() {
    assert_eq!(
        error(&format!("{BASE}[[particle]]\nname = \"bead\"\nmass = 1.0\nposition = [0.0, 0.0]\n")),
        "s.toml:13:8: particle 2: duplicate particle name `bead`\n  name = \"bead\"\n         ^^^^^^"
    );
}

#[test]
fn invalid_particle_name_from_the_model() {
    assert_eq!(
        error(&edit("name = \"bead\"", "name = \"my bead\"")),
        "s.toml:7:8: particle 1: particle name `my bead` must be a letter or `_` followed by letters, digits or `_`\n  \
         name = \"my bead\"\n         ^^^^^^^^^"
    );
}

/// Control characters in a title or a constraint name were echoed raw to the terminal
/// (issue 7): they are refused where they are written; a raw one in the file is a TOML error
/// whose snippet shows it escaped, with the caret under the escape.
#[test]
fn control_characters_in_titles_and_names_are_refused() {
    assert_eq!(
        error(&edit("title = \"t\"", "title = \"a\\u001b[31mb\"")),
        "s.toml:1:9: `title` must not contain control characters, found `\\x1b`\n  \
         title = \"a\\u001b[31mb\"\n          ^^^^^^^^^^^^^^"
    );
    assert_eq!(
        error(&format!(
            "{BASE}[[constraint]]\nname = \"ring\\r\"\nexpr = \"bead.x\"\n"
        )),
        "s.toml:13:8: constraint 2: `name` must not contain control characters, found `\\r`\n  \
         name = \"ring\\r\"\n         ^^^^^^^^"
    );
    assert_eq!(
        error(&edit("title = \"t\"", "title = \"a\u{1b}b\"")),
        "s.toml:1:11: invalid basic string, expected non-double-quote visible characters, `\\`\n  \
         title = \"a\\x1bb\"\n            ^^^^"
    );
}

/// The loader accepted Unicode particle names that no expression could use: the lexer took
/// ASCII identifiers only (issue 7). Names and expressions now share one rule (Unicode XID,
/// as in Rust), so `α.x` works, and a name that is not an identifier is refused where it is
/// written.
#[test]
fn unicode_names_are_usable_in_expressions() {
    let text = r#"title = "α on a circle"
[params]
"ℓ" = 2.0
[world]
gravity = [0.0, -9.81]
[[particle]]
name = "α"
mass = 1.0
position = ["ℓ", 0.0]
[[constraint]]
expr = "α.x^2 + α.y^2 - ℓ^2"
[parametric]
coordinates = ["θ"]
initial = ["pi/2"]
[parametric.positions]
"α" = ["ℓ*sin(θ)", "-ℓ*cos(θ)"]
"#;
    let scene = Scene::parse(text, "s.toml", &[]).unwrap_or_else(|e| panic!("{e}"));
    assert!(scene.warnings().is_empty(), "{:?}", scene.warnings());
    let system = &scene.system;
    assert_eq!(system.coordinate_name(0), "α.x");
    assert_eq!(system.coordinate_name(1), "α.y");
    assert_eq!(system.degrees_of_freedom(), 1);
    assert_eq!(scene.params, [("ℓ".to_string(), 2.0)]);
    // --set reaches a Unicode parameter.
    let moved = Scene::parse(
        &text.replace("position = [\"ℓ\", 0.0]", "position = [3.0, 0.0]"),
        "s.toml",
        &[("ℓ".to_string(), 3.0)],
    )
    .unwrap();
    assert!(moved.warnings().is_empty(), "{:?}", moved.warnings());

    // Names that are not identifiers are refused, located.
    assert_eq!(
        error(&edit("name = \"bead\"", "name = \"x²\"")),
        "s.toml:7:8: particle 1: particle name `x²` must be a letter or `_` followed by letters, \
         digits or `_`\n  name = \"x²\"\n         ^^^^"
    );
    assert_eq!(
        error(&edit("g = 10.0", "\"θ₁\" = 10.0")),
        "s.toml:3:1: parameter `θ₁`: a parameter name must be a letter or `_` followed by \
         letters, digits or `_`\n  \"θ₁\" = 10.0\n  ^^^^"
    );
}

#[test]
fn duplicate_constraint_name() {
    assert_eq!(
        error(&format!("{BASE}[[constraint]]\nname = \"constraint 1\"\nexpr = \"bead.x\"\n")),
        "s.toml:13:8: constraint 2: duplicate constraint name `constraint 1`\n  name = \"constraint 1\"\n         ^^^^^^^^^^^^^^"
    );
}

#[test]
fn unknown_particle_in_force_and_constraint() {
    assert_eq!(
        error(&format!("{BASE}[[force]]\nkind = \"constant\"\nparticle = \"bed\"\nvector = [1.0, 0.0]\n")),
        "s.toml:14:12: force 1: unknown particle `bed`; particles: bead\n  particle = \"bed\"\n             ^^^^^"
    );
    assert_eq!(
        error(&format!("{BASE}[[constraint]]\nkind = \"distance\"\nbetween = [\"bead\", \"ball\"]\nlength = 1.0\n")),
        "s.toml:14:20: constraint 2: unknown particle `ball`; particles: bead\n  \
         between = [\"bead\", \"ball\"]\n                     ^^^^^^"
    );
    // Inside an expression the caret is under the name.
    assert_eq!(
        error(&edit("bead.x^2 + bead.y^2 - 1", "bead.x^2 + bed.y^2 - 1")),
        "s.toml:11:20: constraint 1: unknown particle `bed`; particles: bead\n  \
         expr = \"bead.x^2 + bed.y^2 - 1\"\n                     ^^^^^"
    );
}

#[test]
fn expression_syntax_error_points_inside_the_string() {
    assert_eq!(
        error(&edit(
            "bead.x^2 + bead.y^2 - 1",
            "bead.x^2 + * bead.y^2 - 1"
        )),
        "s.toml:11:20: constraint 1: expected a number, name or `(`, found `*`\n  \
         expr = \"bead.x^2 + * bead.y^2 - 1\"\n                     ^"
    );
    // Literal strings map exactly too.
    assert_eq!(
        error(&edit(
            "\"bead.x^2 + bead.y^2 - 1\"",
            "'bead.x^2 + * bead.y^2 - 1'"
        )),
        "s.toml:11:20: constraint 1: expected a number, name or `(`, found `*`\n  \
         expr = 'bead.x^2 + * bead.y^2 - 1'\n                     ^"
    );
    // With escapes the text in the file is not the expression: the caret covers the string.
    assert_eq!(
        error(&edit(
            "\"bead.x^2 + bead.y^2 - 1\"",
            "\"bead.x^2 + * bead.y^2 - 1\\u0020\""
        )),
        "s.toml:11:8: constraint 1: expected a number, name or `(`, found `*`\n  \
         expr = \"bead.x^2 + * bead.y^2 - 1\\u0020\"\n         ^^^^^^^^^^^^^^^^^^^^^^^^^^^^^^^^^"
    );
    assert_eq!(
        error(&edit(
            "\"bead.x^2 + bead.y^2 - 1\"",
            "\"\"\"bead.x^2 + * bead.y^2 - 1\"\"\""
        )),
        "s.toml:11:8: constraint 1: expected a number, name or `(`, found `*`\n  \
         expr = \"\"\"bead.x^2 + * bead.y^2 - 1\"\"\"\n         ^^^^^^^^^^^^^^^^^^^^^^^^^^^^^^^"
    );
    assert_eq!(
        error(&edit("bead.x^2 + bead.y^2 - 1", "")),
        "s.toml:11:9: constraint 1: empty expression\n  expr = \"\"\n          ^"
    );
    // Columns count characters, and tabs are kept so that the caret lines up. (`²`, two
    // bytes: `ü` was used here until identifiers became Unicode and `ü` a name.)
    assert_eq!(
        error(&edit("mass = 1.0", "mass =\t\"2*²\"")),
        "s.toml:8:11: particle 1: unexpected character `²`\n  mass =\t\"2*²\"\n        \t   ^"
    );
}

#[test]
fn unknown_name_in_expression() {
    assert_eq!(
        error(&edit("bead.x^2 + bead.y^2 - 1", "bead.x^2 + bead.y^2 - L^2")),
        "s.toml:11:31: constraint 1: unknown name `L`; expressions may use t, pi, e, parameters (g) and particle \
         coordinates like bead.x\n  expr = \"bead.x^2 + bead.y^2 - L^2\"\n                                ^"
    );
    assert_eq!(
        error(&edit("mass = 1.0", "mass = \"2*m\"")),
        "s.toml:8:11: particle 1: unknown name `m`; numbers in a scene may use pi, e and parameters (g)\n  \
         mass = \"2*m\"\n            ^"
    );
    assert_eq!(
        error(&edit("g = 10.0", "g = \"2*h\"\nh = 1")),
        "s.toml:3:8: parameter `g`: parameter `h` is defined after this one; a parameter may use only the ones \
         before it\n  g = \"2*h\"\n         ^"
    );
    assert_eq!(
        error(&format!("{BASE}{}", PARAMETRIC.replace("sin(q)", "sin(r)"))),
        "s.toml:16:24: parametric: position of `bead`: unknown name `r`; parametric positions may use the \
         coordinates (q), t, pi, e and parameters (g)\n  bead = [\"cos(q)\", \"sin(r)\"]\n                         ^"
    );
}

#[test]
fn constraint_without_coordinates() {
    assert_eq!(
        error(&edit("bead.x^2 + bead.y^2 - 1", "g - 1")),
        "s.toml:11:8: constraint 1: the expression does not depend on any particle coordinate\n  \
         expr = \"g - 1\"\n         ^^^^^^^"
    );
}

#[test]
fn dt_not_positive() {
    assert_eq!(
        error(&format!("{BASE}[run]\ndt = 0.0\n")),
        "s.toml:13:6: run: `dt` must be positive, got 0\n  dt = 0.0\n       ^^^"
    );
    assert_eq!(
        error(&format!("{BASE}[run]\ndt = \"-1/60\"\n")),
        "s.toml:13:6: run: `dt` must be positive, got -0.016666666666666666\n  dt = \"-1/60\"\n       ^^^^^^^"
    );
    assert_eq!(
        error(&format!("{BASE}[run]\nsteps = 2.5\n")),
        "s.toml:13:9: run: `steps` must be a positive integer, got 2.5\n  steps = 2.5\n          ^^^"
    );
}

#[test]
fn unknown_method_and_integrator() {
    assert_eq!(
        error(&format!("{BASE}[run]\nmethod = \"explicit\"\n")),
        "s.toml:13:10: run: unknown method `explicit`; use implicit or parametric\n  method = \"explicit\"\n           ^^^^^^^^^^"
    );
    assert_eq!(
        error(&format!("{BASE}[run]\nmethod = \"parametric\"\n")),
        "s.toml:13:10: run: method `parametric` needs a `[parametric]` table, and the scene has none\n  \
         method = \"parametric\"\n           ^^^^^^^^^^^^"
    );
    // Every integrator is listed, in IntegratorKind::ALL's order.
    let names: Vec<&str> = bead::integrate::IntegratorKind::ALL
        .iter()
        .map(|k| k.name())
        .collect();
    assert!(names.starts_with(&["euler", "symplectic-euler", "midpoint", "rk4"]));
    assert_eq!(
        error(&format!("{BASE}[run]\nintegrator = \"rk5\"\n")),
        format!(
            "s.toml:13:14: run: unknown integrator `rk5`; use one of {}\n  \
             integrator = \"rk5\"\n               ^^^^^",
            names.join(", ")
        )
    );
    assert_eq!(
        error(&format!("{BASE}[run]\nstabilize = [1.0]\n")),
        "s.toml:13:13: run: `stabilize` must be `[ks, kd]` or `{ frequency = f, damping = zeta }`, got 1 number\n  \
         stabilize = [1.0]\n              ^^^^^"
    );
}

#[test]
fn unknown_kind() {
    assert_eq!(
        error(&format!("{BASE}[[force]]\nkind = \"magnet\"\n")),
        "s.toml:13:8: force 1: unknown kind `magnet`; use constant, spring or drag\n  kind = \"magnet\"\n         ^^^^^^^^"
    );
    assert_eq!(
        error(&format!("{BASE}[[force]]\nkind = \"drag\"\ncoefficient = 0.1\nstiffness = 3\n")),
        "s.toml:15:13: force 1: `stiffness` does not apply to drag\n  stiffness = 3\n              ^"
    );
}

#[test]
fn unknown_override() {
    assert_eq!(
        error_with(BASE, &[("G".into(), 1.0)]),
        "s.toml: --set G=1: unknown parameter `G`; the scene's parameters are g"
    );
    let no_params = BASE
        .replace("[params]\ng = 10.0\n", "")
        .replace("\"g\"", "10.0");
    assert_eq!(
        error_with(&no_params, &[("g".into(), 1.0)]),
        "s.toml: --set g=1: unknown parameter `g`; the scene has no parameters"
    );
}

#[test]
fn reserved_parameter_name() {
    assert_eq!(
        error(&edit("g = 10.0", "g = 10.0\npi = 3")),
        "s.toml:4:1: parameter `pi`: `pi` is reserved (t, pi, e, x, y, z)\n  pi = 3\n  ^^"
    );
}

#[test]
fn parametric_coordinate_count_mismatch() {
    assert_eq!(
        error(&format!("{BASE}{}", PARAMETRIC.replace("initial = [0.0]", "initial = [1.0, 0.0]"))),
        "s.toml:14:11: parametric: `initial` has 2 values for 1 coordinate (q)\n  initial = [1.0, 0.0]\n            ^^^^^^^^^^"
    );
    assert_eq!(
        error(&format!("{BASE}{}", PARAMETRIC.replace("coordinates = [\"q\"]", "coordinates = [\"g\"]"))),
        "s.toml:13:16: parametric: coordinate `g` has the name of a parameter; rename one of them\n  \
         coordinates = [\"g\"]\n                 ^^^"
    );
}

#[test]
fn missing_parametric_position() {
    let text = format!(
        "{BASE}[[particle]]\nname = \"b\"\nmass = 1.0\nposition = [0.0, 0.0]\n{PARAMETRIC}"
    );
    assert_eq!(
        error(&text),
        "s.toml:19:1: parametric: no position for particle `b`; every particle needs one\n  \
         [parametric.positions]\n  ^^^^^^^^^^^^^^^^^^^^^^"
    );
    assert_eq!(
        error(&format!("{BASE}{}", PARAMETRIC.replace("bead = ", "beed = "))),
        "s.toml:16:1: parametric: unknown particle `beed`; particles: bead\n  beed = [\"cos(q)\", \"sin(q)\"]\n  ^^^^"
    );
}

#[test]
fn no_particles_and_no_world() {
    assert_eq!(
        error("[world]\ngravity = [0.0, 1.0]\n"),
        "s.toml:1:1: the scene has no particles; add at least one `[[particle]]` table"
    );
    assert_eq!(error(""), "s.toml:1:1: missing table `[world]` with `gravity` (its length, 2 or 3, sets the dimension)");
}

#[test]
fn file_not_found() {
    let e = Scene::load(Path::new("no/such/scene.toml"), &[]).unwrap_err();
    assert_eq!((e.line, e.column, e.snippet.as_deref()), (0, 0, None));
    assert!(
        e.render()
            .starts_with("no/such/scene.toml: cannot read the scene file: "),
        "{}",
        e.render()
    );
    assert!(!e.render().ends_with('\n'));
}

/// splitmix64: a small deterministic generator.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// A random edit of `text`: truncation, a replaced or inserted character, a deleted range,
/// a duplicated or dropped line.
fn mutate(text: &str, rng: &mut Rng) -> String {
    const PIECES: &[&str] = &[
        "\"", "'", "[", "]", "[[", "]]", "=", "\n", "{", "}", ",", ".", "0", "-1", "1e999", "nan",
        "inf", "#", "\\", "^", "(", ")", "*", "/", "x", "bead", "a", "q", "ü", " ", "\"\"\"",
        "true", "1/0", "sqrt(-1)", "pi",
    ];
    let mut chars: Vec<char> = text.chars().collect();
    let n = chars.len();
    match rng.below(6) {
        0 => chars.truncate(rng.below(n + 1)),
        1 if n > 0 => {
            let i = rng.below(n);
            chars.splice(i..i + 1, PIECES[rng.below(PIECES.len())].chars());
        }
        2 => {
            let i = rng.below(n + 1);
            chars.splice(i..i, PIECES[rng.below(PIECES.len())].chars());
        }
        3 if n > 0 => {
            let i = rng.below(n);
            let j = (i + 1 + rng.below(20)).min(n);
            chars.drain(i..j);
        }
        _ => {
            let mut lines: Vec<&str> = text.lines().collect();
            if !lines.is_empty() {
                let i = rng.below(lines.len());
                if rng.below(2) == 0 {
                    lines.insert(i, lines[i]);
                } else {
                    lines.remove(i);
                }
            }
            return lines.join("\n");
        }
    }
    chars.into_iter().collect()
}

#[test]
fn mutated_scenes_never_panic() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    // The generated scenes are fuzzed at a few links, a 4 x 4 cloth and a small tassel: at
    // their full sizes (1000 links, 2500 masses) each of the thousands of loads below takes long in a debug
    // build, and the mutations exercise the same code at any size.
    let small = |text: String| {
        let mut text = text;
        for (from, to) in [
            ("N = { value = 1000,", "N = { value = 5,"),
            ("N = { value = 100,", "N = { value = 5,"),
            ("W = { value = 20,", "W = { value = 4,"),
            ("R = { value = 10,", "R = { value = 2,"),
            ("W = { value = 50,", "W = { value = 4,"),
            ("H = { value = 50,", "H = { value = 4,"),
            ("T = { value = 10,", "T = { value = 2,"),
            ("B = { value = 8,", "B = { value = 3,"),
            ("K = { value = 20,", "K = { value = 2,"),
        ] {
            text = text.replacen(from, to, 1);
        }
        text
    };
    let texts: Vec<String> = files
        .iter()
        .map(|p| small(std::fs::read_to_string(p).unwrap()))
        .collect();
    for (file, text) in files.iter().zip(&texts) {
        let scene = Scene::parse(text, "fuzz.toml", &[]).unwrap();
        assert!(scene.system.particles().len() <= 16, "{}", file.display());
    }
    assert!(!texts.is_empty());
    let mut rng = Rng(0x5EED);
    let (mut ok, mut err) = (0, 0);
    for case in 0..3000 {
        let mut text = texts[case % texts.len()].clone();
        for _ in 0..1 + rng.below(3) {
            text = mutate(&text, &mut rng);
        }
        let result = std::panic::catch_unwind(|| {
            let scene = Scene::parse(&text, "fuzz.toml", &[])?;
            let _ = scene.warnings();
            Ok::<_, bead::scene::SceneError>(())
        });
        match result {
            Ok(Ok(())) => ok += 1,
            Ok(Err(e)) => {
                let rendered = e.render();
                assert!(e.line >= 1 && e.column >= 1, "unplaced error {rendered}");
                err += 1;
            }
            Err(_) => panic!("the loader panicked on case {case}:\n{text}"),
        }
    }
    // The mutations must exercise both outcomes.
    assert!(ok > 100 && err > 100, "ok {ok}, err {err}");
}
