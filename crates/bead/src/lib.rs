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

/// `value` for messages: plain notation, or exponent notation when it is very large or very
/// small, so that no message prints a 300-digit number.
///
/// ```
/// assert_eq!(bead::readable(0.25), "0.25");
/// assert_eq!(bead::readable(1e300), "1e300");
/// assert_eq!(bead::readable(-5e-7), "-5e-7");
/// ```
pub fn readable(value: f64) -> String {
    let magnitude = value.abs();
    if magnitude != 0.0 && magnitude.is_finite() && !(1e-4..1e16).contains(&magnitude) {
        format!("{value:e}")
    } else {
        format!("{value}")
    }
}

/// The README's Rust examples, compiled and run as doctests.
#[doc = include_str!("../../../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;
