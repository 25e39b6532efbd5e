//! The scene file as serde sees it: every value wrapped in [`Spanned`] so that errors can point
//! at it, every table closed to unknown keys, and every required key optional here so that the
//! loader can say which key is missing where.

use std::fmt;
use std::marker::PhantomData;
use std::ops::Range;

use serde::de::{self, Deserializer, MapAccess, SeqAccess, Visitor};
use serde::Deserialize;
use toml::Spanned;

/// The whole file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SceneFile {
    pub title: Option<Spanned<String>>,
    pub about: Option<Spanned<String>>,
    pub params: Option<Spanned<Entries<ParamDef>>>,
    pub world: Option<Spanned<World>>,
    #[serde(default)]
    pub particle: Tables<ParticleDef>,
    #[serde(default)]
    pub force: Tables<ForceDef>,
    #[serde(default)]
    pub constraint: Tables<ConstraintDef>,
    pub parametric: Option<Spanned<ParametricDef>>,
    pub run: Option<Spanned<RunDef>>,
    #[serde(default)]
    pub event: Tables<EventDef>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct World {
    pub gravity: Option<Spanned<NumVec>>,
    pub units: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ParticleDef {
    /// Repeat the table over integer ranges (see `template.rs`).
    #[serde(rename = "for")]
    pub repeat: Option<Spanned<Entries<RangeText>>>,
    pub name: Option<Spanned<String>>,
    pub mass: Option<Spanned<Num>>,
    pub position: Option<Spanned<NumVec>>,
    pub velocity: Option<Spanned<NumVec>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ForceDef {
    /// Repeat the table over integer ranges (see `template.rs`).
    #[serde(rename = "for")]
    pub repeat: Option<Spanned<Entries<RangeText>>>,
    pub kind: Option<Spanned<String>>,
    pub particle: Option<Spanned<String>>,
    pub between: Option<Spanned<Names>>,
    pub anchor: Option<Spanned<NumVec>>,
    pub vector: Option<Spanned<NumVec>>,
    pub stiffness: Option<Spanned<Num>>,
    pub rest_length: Option<Spanned<Num>>,
    pub coefficient: Option<Spanned<Num>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ConstraintDef {
    /// Repeat the table over integer ranges (see `template.rs`).
    #[serde(rename = "for")]
    pub repeat: Option<Spanned<Entries<RangeText>>>,
    pub kind: Option<Spanned<String>>,
    pub name: Option<Spanned<String>>,
    pub expr: Option<Spanned<String>>,
    pub particle: Option<Spanned<String>>,
    pub between: Option<Spanned<Names>>,
    pub anchor: Option<Spanned<NumVec>>,
    pub length: Option<Spanned<Num>>,
    /// `above` (C >= 0) or `below` (C <= 0): a unilateral constraint.
    pub side: Option<Spanned<String>>,
    /// A unilateral constraint's restitution coefficient e in [0, 1] (default 0).
    pub restitution: Option<Spanned<Num>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ParametricDef {
    pub coordinates: Option<Spanned<Names>>,
    pub initial: Option<Spanned<NumVec>>,
    pub rates: Option<Spanned<NumVec>>,
    pub positions: Option<Spanned<Entries<NumVec>>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RunDef {
    pub method: Option<Spanned<String>>,
    pub integrator: Option<Spanned<String>>,
    pub dt: Option<Spanned<Num>>,
    pub duration: Option<Spanned<Num>>,
    pub steps: Option<Spanned<Num>>,
    pub stabilize: Option<Spanned<Stabilize>>,
    pub stop_when: Option<Spanned<String>>,
    pub event_samples: Option<Spanned<Num>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct EventDef {
    pub expr: Option<Spanned<String>>,
    pub direction: Option<Spanned<Num>>,
    pub terminal: Option<Spanned<bool>>,
}

/// `stabilize = [ks, kd]` or `stabilize = { frequency = f, damping = zeta }`.
#[derive(Debug)]
pub(super) enum Stabilize {
    Gains(Vec<Spanned<Num>>),
    Frequency(StabilizeTable),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct StabilizeTable {
    pub frequency: Option<Spanned<Num>>,
    pub damping: Option<Spanned<Num>>,
}

/// A number: a TOML integer or float, or a string holding an expression.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Num {
    Value(f64),
    Expr(String),
}

/// A `[params]` entry: a number or expression, or a table with the value and what the
/// viewer shows of it.
#[derive(Debug)]
pub(super) enum ParamDef {
    Value(Num),
    Table(ParamTable),
}

/// `name = { value = ..., range = [lo, hi], unit = "...", description = "...", integer = true }`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ParamTable {
    pub value: Option<Spanned<Num>>,
    pub range: Option<Spanned<NumVec>>,
    pub unit: Option<Spanned<String>>,
    pub description: Option<Spanned<String>>,
    pub integer: Option<Spanned<bool>>,
}

/// A range of a `for` key: `"START..STOP"`, as written.
#[derive(Debug)]
pub(super) struct RangeText(pub String);

/// An array of [`Num`]s.
#[derive(Debug)]
pub(super) struct NumVec(pub Vec<Spanned<Num>>);

/// An array of strings.
#[derive(Debug)]
pub(super) struct Names(pub Vec<Spanned<String>>);

/// An array of tables (`[[name]]` sections).
#[derive(Debug)]
pub(super) struct Tables<T>(pub Vec<Spanned<T>>);

impl<T> Default for Tables<T> {
    fn default() -> Self {
        Tables(Vec::new())
    }
}

/// A table with free keys, entries in file order.
#[derive(Debug)]
pub(super) struct Entries<V>(pub Vec<(Spanned<String>, Spanned<V>)>);

/// The bytes of text a table's strings hold as written (names, references, expressions;
/// not its `for` ranges): what the loader expands and reads once per repetition.
pub(super) trait StringBytes {
    fn string_bytes(&self) -> usize;
}

impl StringBytes for String {
    fn string_bytes(&self) -> usize {
        self.len()
    }
}

impl StringBytes for Num {
    fn string_bytes(&self) -> usize {
        match self {
            Num::Value(_) => 0,
            Num::Expr(text) => text.len(),
        }
    }
}

impl StringBytes for NumVec {
    fn string_bytes(&self) -> usize {
        self.0.iter().map(|n| n.get_ref().string_bytes()).sum()
    }
}

impl StringBytes for Names {
    fn string_bytes(&self) -> usize {
        self.0.iter().map(|n| n.get_ref().len()).sum()
    }
}

impl<T: StringBytes> StringBytes for Option<Spanned<T>> {
    fn string_bytes(&self) -> usize {
        self.as_ref().map_or(0, |v| v.get_ref().string_bytes())
    }
}

impl StringBytes for ParticleDef {
    fn string_bytes(&self) -> usize {
        self.name.string_bytes()
            + self.mass.string_bytes()
            + self.position.string_bytes()
            + self.velocity.string_bytes()
    }
}

impl StringBytes for ForceDef {
    fn string_bytes(&self) -> usize {
        self.kind.string_bytes()
            + self.particle.string_bytes()
            + self.between.string_bytes()
            + self.anchor.string_bytes()
            + self.vector.string_bytes()
            + self.stiffness.string_bytes()
            + self.rest_length.string_bytes()
            + self.coefficient.string_bytes()
    }
}

impl StringBytes for ConstraintDef {
    fn string_bytes(&self) -> usize {
        self.kind.string_bytes()
            + self.name.string_bytes()
            + self.expr.string_bytes()
            + self.particle.string_bytes()
            + self.between.string_bytes()
            + self.anchor.string_bytes()
            + self.length.string_bytes()
    }
}

/// The span of an optional spanned value.
pub(super) fn span_of<T>(value: &Option<Spanned<T>>) -> Option<Range<usize>> {
    value.as_ref().map(|v| v.span())
}

impl<'de> Deserialize<'de> for Num {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl Visitor<'_> for V {
            type Value = Num;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number or an expression string")
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Num, E> {
                Ok(Num::Value(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Num, E> {
                Ok(Num::Value(v as f64))
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Num, E> {
                Ok(Num::Value(v))
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<Num, E> {
                Ok(Num::Expr(v.to_string()))
            }
        }
        d.deserialize_any(V)
    }
}

impl<'de> Deserialize<'de> for ParamDef {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = ParamDef;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number, an expression string or a table with `value`")
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<ParamDef, E> {
                Ok(ParamDef::Value(Num::Value(v as f64)))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<ParamDef, E> {
                Ok(ParamDef::Value(Num::Value(v as f64)))
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<ParamDef, E> {
                Ok(ParamDef::Value(Num::Value(v)))
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<ParamDef, E> {
                Ok(ParamDef::Value(Num::Expr(v.to_string())))
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<ParamDef, A::Error> {
                ParamTable::deserialize(de::value::MapAccessDeserializer::new(map))
                    .map(ParamDef::Table)
            }
        }
        d.deserialize_any(V)
    }
}

/// Deserialize a sequence of `T` with a custom "expected" text.
fn seq<'de, D, T>(d: D, expecting: &'static str) -> Result<Vec<T>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    struct V<T>(&'static str, PhantomData<T>);
    impl<'de, T: Deserialize<'de>> Visitor<'de> for V<T> {
        type Value = Vec<T>;
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str(self.0)
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<T>, A::Error> {
            let mut out = Vec::new();
            while let Some(x) = seq.next_element()? {
                out.push(x);
            }
            Ok(out)
        }
    }
    d.deserialize_seq(V(expecting, PhantomData))
}

impl<'de> Deserialize<'de> for RangeText {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl Visitor<'_> for V {
            type Value = RangeText;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a range as a string, \"START..STOP\"")
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<RangeText, E> {
                Ok(RangeText(v.to_string()))
            }
        }
        d.deserialize_str(V)
    }
}

impl<'de> Deserialize<'de> for NumVec {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        seq(d, "an array of numbers or expression strings").map(NumVec)
    }
}

impl<'de> Deserialize<'de> for Names {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        seq(d, "an array of strings").map(Names)
    }
}

impl<'de, T: Deserialize<'de>> Deserialize<'de> for Tables<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        seq(d, "an array of tables (`[[...]]` sections)").map(Tables)
    }
}

impl<'de, V: Deserialize<'de>> Deserialize<'de> for Entries<V> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Vis<V>(PhantomData<V>);
        impl<'de, V: Deserialize<'de>> Visitor<'de> for Vis<V> {
            type Value = Entries<V>;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a table")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Entries<V>, A::Error> {
                let mut out = Vec::new();
                while let Some(key) = map.next_key::<Spanned<String>>()? {
                    let value = map.next_value::<Spanned<V>>()?;
                    out.push((key, value));
                }
                // Without toml's `preserve_order` the keys arrive sorted; restore file order.
                out.sort_by_key(|(k, _)| k.span().start);
                Ok(Entries(out))
            }
        }
        d.deserialize_map(Vis(PhantomData))
    }
}

impl<'de> Deserialize<'de> for Stabilize {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Stabilize;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("`[ks, kd]` or `{ frequency = f, damping = zeta }`")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Stabilize, A::Error> {
                let mut out = Vec::new();
                while let Some(x) = seq.next_element()? {
                    out.push(x);
                }
                Ok(Stabilize::Gains(out))
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<Stabilize, A::Error> {
                StabilizeTable::deserialize(de::value::MapAccessDeserializer::new(map))
                    .map(Stabilize::Frequency)
            }
        }
        d.deserialize_any(V)
    }
}
