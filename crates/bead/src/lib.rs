//! bead: constrained particle dynamics.
#![forbid(unsafe_code)]
pub mod expr;
pub mod formulation;
pub mod integrate;
pub mod linalg;
pub mod model;
pub mod output;
pub mod scene;
pub mod simulate;

/// A number type the engine can differentiate through: `f64` and num-dual's dual numbers.
/// Constraints written as Rust types are generic over it (see [`model::Holonomic`]).
pub trait Scalar: num_dual::DualNum<Primitive = f64> + Copy {}
impl<T: num_dual::DualNum<Primitive = f64> + Copy> Scalar for T {}

/// The README's Rust examples, compiled and run as doctests.
#[doc = include_str!("../../../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;
