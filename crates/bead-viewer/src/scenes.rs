//! The scenes the viewer offers by name: the shipped scenes, embedded in the binary, plus any
//! scene given on the command line.

/// The shipped scenes (`scenes/*.toml`, every one: a test checks the list against the
/// folder), embedded at build time, in the picker's order: the article's parabola first, then
/// the curves, the teaching tracks, the 3D and moving ones, the systems of several
/// particles, the singular curves and the large ones.
pub const SHIPPED: [(&str, &str); 20] = [
    ("parabola", include_str!("../../../scenes/parabola.toml")),
    (
        "parabola-x0",
        include_str!("../../../scenes/parabola-x0.toml"),
    ),
    ("circle", include_str!("../../../scenes/circle.toml")),
    ("cycloid", include_str!("../../../scenes/cycloid.toml")),
    (
        "lemniscate",
        include_str!("../../../scenes/lemniscate.toml"),
    ),
    ("hump", include_str!("../../../scenes/hump.toml")),
    ("loop", include_str!("../../../scenes/loop.toml")),
    ("bounce", include_str!("../../../scenes/bounce.toml")),
    ("infinity", include_str!("../../../scenes/infinity.toml")),
    ("spiral", include_str!("../../../scenes/spiral.toml")),
    ("helix", include_str!("../../../scenes/helix.toml")),
    (
        "spinning-hoop",
        include_str!("../../../scenes/spinning-hoop.toml"),
    ),
    (
        "double-pendulum",
        include_str!("../../../scenes/double-pendulum.toml"),
    ),
    ("cusp", include_str!("../../../scenes/cusp.toml")),
    ("node", include_str!("../../../scenes/node.toml")),
    ("chain", include_str!("../../../scenes/chain.toml")),
    ("rope", include_str!("../../../scenes/rope.toml")),
    ("tassel", include_str!("../../../scenes/tassel.toml")),
    ("net", include_str!("../../../scenes/net.toml")),
    ("cloth", include_str!("../../../scenes/cloth.toml")),
];

/// A named scene text.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedScene {
    pub name: String,
    pub text: String,
}

/// The scenes a server offers, in picker order; the first is loaded on connect.
#[derive(Clone, Debug, PartialEq)]
pub struct Catalog {
    pub scenes: Vec<NamedScene>,
}

impl Catalog {
    /// The shipped scenes only (`parabola` first).
    pub fn shipped() -> Catalog {
        Catalog {
            scenes: SHIPPED
                .iter()
                .map(|(name, text)| NamedScene {
                    name: (*name).to_string(),
                    text: (*text).to_string(),
                })
                .collect(),
        }
    }

    /// The shipped scenes with `extra` first (it is loaded on connect). A shipped scene of the
    /// same name, or with the same text (`bead serve scenes/parabola.toml`), is replaced, so
    /// that the picker lists no scene twice.
    pub fn with_first(extra: NamedScene) -> Catalog {
        let mut catalog = Catalog::shipped();
        catalog
            .scenes
            .retain(|s| s.name != extra.name && s.text != extra.text);
        catalog.scenes.insert(0, extra);
        catalog
    }

    /// Look a scene up by name.
    pub fn get(&self, name: &str) -> Option<&NamedScene> {
        self.scenes.iter().find(|s| s.name == name)
    }

    /// The scene loaded on connect.
    pub fn first(&self) -> Option<&NamedScene> {
        self.scenes.first()
    }

    pub fn names(&self) -> Vec<String> {
        self.scenes.iter().map(|s| s.name.clone()).collect()
    }
}
