//! Rust constraints traced into expressions: a [`Holonomic`]'s `value`, run once on a number
//! type that records its operations, becomes an [`Expr`] over the system's coordinates and t,
//! and then takes the path of a constraint typed in a scene file (symbolic derivatives, one
//! compiled tape, the fused acceleration) instead of dual numbers at every evaluation.
//!
//! The trace runs `value` at a sample point (the particles' initial positions, t = 0) on
//! [`Traced`] numbers, which carry the sample's value beside the node they recorded, so the
//! code runs exactly the path it runs on `f64`. A trace holds for every point only when that
//! path cannot depend on the values, so it is refused, and the constraint keeps its dual
//! numbers, when the code
//!
//! - compares a value that depends on x or t (`<`, `==`, `is_positive`, `signum`,
//!   `is_zero`...) or reads one out (`re()`, `Display`): it may branch on it (constants, made
//!   from numbers alone, may be compared and read);
//! - calls a function the expression language does not have with the same bits (`cbrt`,
//!   `exp2`, `exp_m1`, `ln_1p`, `log`, `log2`, the inverse hyperbolic functions, the spherical
//!   Bessel functions, a fused `mul_add`, `%`, `abs_sub`) on such a value;
//! - mixes numbers of two traces (kept from an earlier one, or from a constraint whose
//!   `value` declares another);
//! - gives, at the sample or at a second point near it (t = 0.01), a value other than the
//!   recorded expression's, beyond the rounding of the largest value the code computed
//!   there (a safety net against a recording rule that is wrong, and against code that
//!   reads state other than x and t, which a trace would freeze).
//!
//! The traced expression computes what `value::<f64>` computes, operation for operation, up
//! to the expression language's simplifications (`x * 1 = x`, `x + 0 = x`, `0 * x = 0`,
//! constants folded and merged: `2 * (3 * x) = 6 * x`), which may change a last bit, the sign
//! of a zero, or an infinity or NaN into a number, and its powers (`x^n` by `powi` for an
//! integer |n| <= 16, as `f64::powi`, by `powf` beyond; a `powf` exponent that is such an
//! integer is taken as one). Its derivatives are the symbolic ones, which may differ from the
//! dual numbers' in the last bits, and at a kink of `abs` (where sign(0) = 0 gives a zero
//! derivative, num-dual's +-1).

use std::cmp::Ordering;
use std::fmt;
use std::iter::{Product, Sum};
use std::ops::{
    Add, AddAssign, Div, DivAssign, Mul, MulAssign, Neg, Rem, RemAssign, Sub, SubAssign,
};
use std::sync::atomic::{AtomicU32, Ordering as Atomic};
use std::sync::Mutex;

use num_dual::{DualNum, DualStruct, Mappable};
use num_traits::{FromPrimitive, Inv, Num, One, ParseFloatError, Signed, Zero};

use super::Holonomic;
use crate::expr::{Expr, Func};

/// The node of a number that is a constant (its value alone, in no recording).
const CONSTANT: u32 = u32::MAX;
/// The node of a number whose trace had ended when it was made (see [`Traced::record`]).
const LOST: u32 = u32::MAX - 1;

/// One trace's recording: every node made so far and, once the code did something a trace
/// cannot follow, what it was.
struct Recording {
    trace: u32,
    nodes: Vec<Expr>,
    refused: Option<&'static str>,
    /// The largest magnitude of any value at the sample that depends on x or t (the scale of
    /// the code's rounding)
    scale: f64,
}

/// The traces in progress, by number: one at a time on most days, one per thread when
/// systems are built on several at once, and a trace inside a trace when a constraint's
/// `value` declares another. A number records in its own trace's, from any thread.
static RECORDINGS: Mutex<Vec<Recording>> = Mutex::new(Vec::new());
static NEXT_TRACE: AtomicU32 = AtomicU32::new(1);

/// A number that records the operations made on it (see the module): its value at the
/// sample point, its trace and its node in that trace's recording ([`CONSTANT`] for a
/// constant).
#[derive(Clone, Copy)]
pub(crate) struct Traced {
    re: f64,
    trace: u32,
    node: u32,
}

fn with_recording<R>(trace: u32, f: impl FnOnce(&mut Recording) -> R) -> Option<R> {
    let mut all = RECORDINGS.lock().unwrap_or_else(|e| e.into_inner());
    all.iter_mut().find(|r| r.trace == trace).map(f)
}

impl Traced {
    fn constant(re: f64) -> Traced {
        Traced {
            re,
            trace: 0,
            node: CONSTANT,
        }
    }

    fn is_constant(self) -> bool {
        self.node == CONSTANT
    }

    /// The number of value `re` made from `args` by `expr` (given each argument's
    /// expression): a constant when every argument is one, else a node in their trace. When
    /// the arguments come from two traces, that trace is refused; when it has ended, the
    /// number is lost, and so is the trace that meets it.
    fn record(
        re: f64,
        args: &[Traced],
        expr: impl FnOnce(&dyn Fn(Traced) -> Expr) -> Expr,
    ) -> Traced {
        let mut traces = args.iter().filter(|a| !a.is_constant()).map(|a| a.trace);
        let Some(trace) = traces.next() else {
            return Traced::constant(re);
        };
        let mixed = traces.any(|other| other != trace);
        let node = with_recording(trace, |r| {
            if mixed {
                r.refused.get_or_insert("it mixes numbers of two traces");
            }
            let nodes = &r.nodes;
            let e = expr(&|a: Traced| match a.node {
                CONSTANT => Expr::constant(a.re),
                node if a.trace == trace => nodes
                    .get(node as usize)
                    .cloned()
                    .unwrap_or_else(|| Expr::constant(f64::NAN)),
                _ => Expr::constant(f64::NAN),
            });
            r.nodes.push(e);
            if re.is_finite() {
                r.scale = r.scale.max(re.abs());
            }
            u32::try_from(r.nodes.len() - 1).unwrap_or(LOST)
        });
        Traced {
            re,
            trace,
            node: node.unwrap_or(LOST),
        }
    }

    /// This number's value, noting that the traced code may branch on it (a constant's may
    /// be read).
    fn refuse(self, why: &'static str) -> f64 {
        if !self.is_constant() {
            with_recording(self.trace, |r| {
                r.refused.get_or_insert(why);
            });
        }
        self.re
    }

    /// The result `re` of a function the expression language has no exact form of, applied
    /// to `args`: a constant when they all are, else a refused trace.
    fn unsupported(name: &'static str, re: f64, args: &[Traced]) -> Traced {
        for a in args {
            a.refuse(name);
        }
        Traced::record(re, args, |_| Expr::constant(f64::NAN))
    }

    /// `f(self)`, its value computed as the tape computes it.
    fn unary(self, f: Func) -> Traced {
        let re = crate::expr::unary_f64(f, self.re);
        Traced::record(re, &[self], |e| Expr::call(f, vec![e(self)]))
    }

    fn binary(self, other: Traced, re: f64, op: fn(Expr, Expr) -> Expr) -> Traced {
        Traced::record(re, &[self, other], |e| op(e(self), e(other)))
    }
}

/// Removes a trace's recording when the trace ends, by a panic too.
struct Ending(u32);
impl Drop for Ending {
    fn drop(&mut self) {
        let mut all = RECORDINGS.lock().unwrap_or_else(|e| e.into_inner());
        all.retain(|r| r.trace != self.0);
    }
}

#[cfg(test)]
thread_local! {
    /// The last trace this thread started (for the tests, which run on several threads).
    static LAST_TRACE: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

/// Whether the last trace this thread started is still in progress (a trace that ended,
/// by a panic too, leaves nothing behind).
#[cfg(test)]
fn last_trace_in_progress() -> bool {
    let last = LAST_TRACE.get();
    let all = RECORDINGS.lock().unwrap_or_else(|e| e.into_inner());
    all.iter().any(|r| r.trace == last)
}

/// Trace `constraint` into C(x, t) over the system's variables: `vars[i]` is the variable of
/// its local coordinate i, `time` that of t; `x` (local) and t = 0 are the sample point.
/// Returns why it cannot be traced instead (see the module).
pub(crate) fn trace<H: Holonomic>(
    constraint: &H,
    x: &[f64],
    vars: &[usize],
    time: usize,
) -> Result<Expr, &'static str> {
    let trace = NEXT_TRACE.fetch_add(1, Atomic::Relaxed);
    #[cfg(test)]
    LAST_TRACE.set(trace);
    let _ending = Ending(trace);
    RECORDINGS
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .push(Recording {
            trace,
            nodes: Vec::new(),
            refused: None,
            scale: 0.0,
        });
    // Local slots: coordinate i is variable i, t is variable k (the system's afterwards).
    let k = x.len();
    let variable = |slot: usize, re: f64| {
        let number = Traced { re, trace, node: 0 };
        Traced::record(re, &[number], |_| Expr::var(slot))
    };
    let point: Vec<Traced> = x
        .iter()
        .enumerate()
        .map(|(i, &re)| variable(i, re))
        .collect();
    let t = variable(k, 0.0);
    let value = constraint.value(&point, t);
    let recording = {
        let mut all = RECORDINGS.lock().unwrap_or_else(|e| e.into_inner());
        let at = all.iter().position(|r| r.trace == trace);
        at.map(|at| all.swap_remove(at))
    };
    let recording = recording.ok_or("the trace was lost")?;
    if let Some(why) = recording.refused {
        return Err(why);
    }
    let expr = match value.node {
        CONSTANT => Expr::constant(value.re),
        node if value.trace == trace => recording
            .nodes
            .get(node as usize)
            .cloned()
            .ok_or("its value is a number lost by an ended trace")?,
        _ => return Err("its value is a number of another trace"),
    };
    // The safety net: the expression gives the value the code computes on f64, at the
    // sample and at a point near it (to the rounding of the largest value computed there:
    // an integer power by `powi` where the code calls `powf` may differ in the last bit).
    let tolerance = 1e-12 * recording.scale;
    let agree = |a: f64, b: f64| {
        a.to_bits() == b.to_bits() || (a - b).abs() <= tolerance || (a.is_nan() && b.is_nan())
    };
    let near: Vec<f64> = (x.iter().enumerate())
        .map(|(i, v)| v + if i % 2 == 0 { 1e-3 } else { -1e-3 } * (1.0 + v.abs()))
        .collect();
    for (at, t) in [(x, 0.0), (&near[..], 0.01)] {
        let exact = constraint.value(at, t);
        let slots: Vec<f64> = at.iter().copied().chain([t]).collect();
        let traced = expr.eval(&slots);
        if !agree(traced, exact) || (t == 0.0 && !agree(value.re, exact)) {
            return Err("its traced expression gives another value than its code");
        }
    }
    Ok(expr.substitute(&|slot| Expr::var(if slot < k { vars[slot] } else { time })))
}

// Arithmetic, as f64 does it, recorded.

macro_rules! binary_ops {
    ($($tr:ident $method:ident $assign_tr:ident $assign:ident $op:tt),*) => {$(
        impl $tr for Traced {
            type Output = Traced;
            fn $method(self, other: Traced) -> Traced {
                self.binary(other, self.re $op other.re, |a, b| a $op b)
            }
        }
        impl $tr<&Traced> for Traced {
            type Output = Traced;
            fn $method(self, other: &Traced) -> Traced {
                self $op *other
            }
        }
        impl $tr<f64> for Traced {
            type Output = Traced;
            fn $method(self, other: f64) -> Traced {
                self $op Traced::constant(other)
            }
        }
        impl $assign_tr for Traced {
            fn $assign(&mut self, other: Traced) {
                *self = *self $op other;
            }
        }
        impl $assign_tr<f64> for Traced {
            fn $assign(&mut self, other: f64) {
                *self = *self $op other;
            }
        }
    )*};
}

binary_ops!(
    Add add AddAssign add_assign +,
    Sub sub SubAssign sub_assign -,
    Mul mul MulAssign mul_assign *,
    Div div DivAssign div_assign /
);

impl Rem for Traced {
    type Output = Traced;
    fn rem(self, other: Traced) -> Traced {
        Traced::unsupported("%", self.re % other.re, &[self, other])
    }
}
impl Rem<&Traced> for Traced {
    type Output = Traced;
    fn rem(self, other: &Traced) -> Traced {
        self % *other
    }
}
impl Rem<f64> for Traced {
    type Output = Traced;
    fn rem(self, other: f64) -> Traced {
        Traced::unsupported("%", self.re % other, &[self])
    }
}
impl RemAssign for Traced {
    fn rem_assign(&mut self, other: Traced) {
        *self = *self % other;
    }
}
impl RemAssign<f64> for Traced {
    fn rem_assign(&mut self, other: f64) {
        *self = *self % other;
    }
}

impl Neg for Traced {
    type Output = Traced;
    fn neg(self) -> Traced {
        Traced::record(-self.re, &[self], |e| -e(self))
    }
}

impl Inv for Traced {
    type Output = Traced;
    fn inv(self) -> Traced {
        self.recip()
    }
}

impl Zero for Traced {
    fn zero() -> Traced {
        Traced::constant(0.0)
    }
    fn is_zero(&self) -> bool {
        self.refuse("is_zero") == 0.0
    }
}

impl One for Traced {
    fn one() -> Traced {
        Traced::constant(1.0)
    }
}

impl Num for Traced {
    type FromStrRadixErr = ParseFloatError;
    fn from_str_radix(text: &str, radix: u32) -> Result<Traced, ParseFloatError> {
        f64::from_str_radix(text, radix).map(Traced::constant)
    }
}

impl Signed for Traced {
    fn abs(&self) -> Traced {
        self.unary(Func::Abs)
    }
    fn abs_sub(&self, other: &Traced) -> Traced {
        let re = <f64 as Signed>::abs_sub(&self.re, &other.re);
        Traced::unsupported("abs_sub", re, &[*self, *other])
    }
    fn signum(&self) -> Traced {
        Traced::unsupported("signum", self.re.signum(), &[*self])
    }
    fn is_positive(&self) -> bool {
        <f64 as Signed>::is_positive(&self.refuse("is_positive"))
    }
    fn is_negative(&self) -> bool {
        <f64 as Signed>::is_negative(&self.refuse("is_negative"))
    }
}

impl Sum for Traced {
    fn sum<I: Iterator<Item = Traced>>(iter: I) -> Traced {
        iter.fold(Traced::zero(), |a, b| a + b)
    }
}
impl<'a> Sum<&'a Traced> for Traced {
    fn sum<I: Iterator<Item = &'a Traced>>(iter: I) -> Traced {
        iter.fold(Traced::zero(), |a, b| a + *b)
    }
}
impl Product for Traced {
    fn product<I: Iterator<Item = Traced>>(iter: I) -> Traced {
        iter.fold(Traced::one(), |a, b| a * b)
    }
}
impl<'a> Product<&'a Traced> for Traced {
    fn product<I: Iterator<Item = &'a Traced>>(iter: I) -> Traced {
        iter.fold(Traced::one(), |a, b| a * *b)
    }
}

impl FromPrimitive for Traced {
    fn from_i64(n: i64) -> Option<Traced> {
        f64::from_i64(n).map(Traced::constant)
    }
    fn from_u64(n: u64) -> Option<Traced> {
        f64::from_u64(n).map(Traced::constant)
    }
    fn from_i128(n: i128) -> Option<Traced> {
        f64::from_i128(n).map(Traced::constant)
    }
    fn from_u128(n: u128) -> Option<Traced> {
        f64::from_u128(n).map(Traced::constant)
    }
    fn from_f64(n: f64) -> Option<Traced> {
        Some(Traced::constant(n))
    }
}

impl From<f64> for Traced {
    fn from(re: f64) -> Traced {
        Traced::constant(re)
    }
}

impl DualStruct for Traced {
    type Real = f64;
    type Inner = f64;
    fn re(&self) -> f64 {
        self.refuse("re()")
    }
    fn from_inner(inner: &f64) -> Traced {
        Traced::constant(*inner)
    }
}

impl Mappable<Traced> for Traced {
    type Output<O> = O;
    fn map_dual<G: Fn(Traced) -> O, O>(self, g: G) -> O {
        g(self)
    }
}

// Comparisons answer as f64 does at the sample, and refuse the trace.

impl PartialEq for Traced {
    fn eq(&self, other: &Traced) -> bool {
        other.refuse("==");
        self.refuse("==") == other.re
    }
}
impl PartialEq<f64> for Traced {
    fn eq(&self, other: &f64) -> bool {
        self.refuse("==") == *other
    }
}
impl PartialOrd for Traced {
    fn partial_cmp(&self, other: &Traced) -> Option<Ordering> {
        other.refuse("a comparison");
        self.refuse("a comparison").partial_cmp(&other.re)
    }
}
impl PartialOrd<f64> for Traced {
    fn partial_cmp(&self, other: &f64) -> Option<Ordering> {
        self.refuse("a comparison").partial_cmp(other)
    }
}

// Printing reads the value out (code could parse it back): refused, as `re()` is.

impl fmt::Display for Traced {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.refuse("printing"))
    }
}
impl fmt::Debug for Traced {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.refuse("printing"))
    }
}

impl DualNum for Traced {
    type Primitive = f64;
    const NDERIV: usize = 0;
    type InnerDual = f64;

    fn from_re(re: f64) -> Traced {
        Traced::constant(re)
    }
    fn scale(self, factor: &f64) -> Traced {
        self * *factor
    }
    fn recip(&self) -> Traced {
        Traced::constant(1.0) / *self
    }
    fn powi(&self, n: i32) -> Traced {
        let re = crate::expr::pow_const_f64(self.re, f64::from(n));
        Traced::record(re, &[*self], |e| e(*self).powi(n))
    }
    fn powf(&self, n: f64) -> Traced {
        let re = crate::expr::pow_const_f64(self.re, n);
        Traced::record(re, &[*self], |e| e(*self).powf(&Expr::constant(n)))
    }
    fn powd(&self, n: Traced) -> Traced {
        let re = self.re.powf(n.re);
        self.binary(n, re, |a, b| a.powf(&b))
    }
    fn sqrt(&self) -> Traced {
        self.unary(Func::Sqrt)
    }
    fn cbrt(&self) -> Traced {
        Traced::unsupported("cbrt", self.re.cbrt(), &[*self])
    }
    fn exp(&self) -> Traced {
        self.unary(Func::Exp)
    }
    fn exp2(&self) -> Traced {
        Traced::unsupported("exp2", self.re.exp2(), &[*self])
    }
    fn exp_m1(&self) -> Traced {
        Traced::unsupported("exp_m1", self.re.exp_m1(), &[*self])
    }
    fn ln(&self) -> Traced {
        self.unary(Func::Ln)
    }
    fn log(&self, base: f64) -> Traced {
        Traced::unsupported("log", self.re.log(base), &[*self])
    }
    fn log2(&self) -> Traced {
        Traced::unsupported("log2", self.re.log2(), &[*self])
    }
    fn log10(&self) -> Traced {
        self.unary(Func::Log10)
    }
    fn ln_1p(&self) -> Traced {
        Traced::unsupported("ln_1p", self.re.ln_1p(), &[*self])
    }
    fn sin(&self) -> Traced {
        self.unary(Func::Sin)
    }
    fn cos(&self) -> Traced {
        self.unary(Func::Cos)
    }
    fn tan(&self) -> Traced {
        self.unary(Func::Tan)
    }
    fn sin_cos(&self) -> (Traced, Traced) {
        let (s, c) = self.re.sin_cos();
        if s.to_bits() != self.re.sin().to_bits() || c.to_bits() != self.re.cos().to_bits() {
            // f64's sin_cos is not sin and cos here: no exact form.
            let args = [*self];
            return (
                Traced::unsupported("sin_cos", s, &args),
                Traced::unsupported("sin_cos", c, &args),
            );
        }
        (self.unary(Func::Sin), self.unary(Func::Cos))
    }
    fn asin(&self) -> Traced {
        self.unary(Func::Asin)
    }
    fn acos(&self) -> Traced {
        self.unary(Func::Acos)
    }
    fn atan(&self) -> Traced {
        self.unary(Func::Atan)
    }
    fn atan2(&self, other: Traced) -> Traced {
        let re = self.re.atan2(other.re);
        Traced::record(re, &[*self, other], |e| {
            Expr::call(Func::Atan2, vec![e(*self), e(other)])
        })
    }
    fn sinh(&self) -> Traced {
        self.unary(Func::Sinh)
    }
    fn cosh(&self) -> Traced {
        self.unary(Func::Cosh)
    }
    fn tanh(&self) -> Traced {
        self.unary(Func::Tanh)
    }
    fn asinh(&self) -> Traced {
        Traced::unsupported("asinh", self.re.asinh(), &[*self])
    }
    fn acosh(&self) -> Traced {
        Traced::unsupported("acosh", self.re.acosh(), &[*self])
    }
    fn atanh(&self) -> Traced {
        Traced::unsupported("atanh", self.re.atanh(), &[*self])
    }
    fn sph_j0(&self) -> Traced {
        Traced::unsupported("sph_j0", self.re.sph_j0(), &[*self])
    }
    fn sph_j1(&self) -> Traced {
        Traced::unsupported("sph_j1", self.re.sph_j1(), &[*self])
    }
    fn sph_j2(&self) -> Traced {
        Traced::unsupported("sph_j2", self.re.sph_j2(), &[*self])
    }
    fn mul_add(&self, a: Traced, b: Traced) -> Traced {
        Traced::unsupported("mul_add", self.re.mul_add(a.re, b.re), &[*self, a, b])
    }
}

#[cfg(test)]
mod tests {
    use crate::model::{Holonomic, ParticleId, System, SystemBuilder};
    use crate::Scalar;

    /// A constraint on two particles in 3D that makes every operation a trace records, with
    /// t: each argument within its function's domain for coordinates in [0.5, 1.5].
    struct Everything(ParticleId, ParticleId);
    impl Holonomic for Everything {
        fn value<T: Scalar>(&self, x: &[T], t: T) -> T {
            everything(x, t)
        }
        fn particles(&self) -> Vec<ParticleId> {
            vec![self.0, self.1]
        }
    }

    /// `Everything`'s C (the operators taking `&T` are among what a trace records).
    #[allow(clippy::op_ref)]
    fn everything<T: Scalar>(x: &[T], t: T) -> T {
        let [a, b, c, d, e, f] = [x[0], x[1], x[2], x[3], x[4], x[5]];
        let mut sum = a + b * 2.0 - c / d + (e - &f) * &a;
        sum += t * 0.25;
        sum -= T::from(0.5) * t.cos();
        sum *= 1.0 + 0.1 * 0.0;
        sum /= 2.0;
        let powers = a.powi(3) + b.powf(2.5) + c.powd(d) + d.sqrt() + e.recip() + f.inv();
        let logs = a.exp() + b.ln() + c.log10() - (-d);
        let (s, k) = e.sin_cos();
        let trig = a.sin() * b.cos() + c.tan() + s * k + (d * 0.5).asin() + (e * 0.5).acos();
        let inverse = f.atan() + a.atan2(b) + (c - 1.0).abs();
        let hyperbolic = d.sinh() + e.cosh() - f.tanh();
        let folded: T = x.iter().copied().sum::<T>() + x.iter().copied().product::<T>();
        let scaled = a * 3.0 + T::zero() * b + T::one();
        sum + powers + logs + trig + inverse + hyperbolic + folded + scaled
    }

    fn two_particles() -> (SystemBuilder, ParticleId, ParticleId) {
        let mut b = SystemBuilder::new(&[0.0, 0.0, -9.81]);
        let p = b.particle("p", 1.0, &[1.0, 0.9, 1.1], &[0.0; 3]).unwrap();
        let q = b.particle("q", 2.0, &[0.8, 1.2, 0.7], &[0.0; 3]).unwrap();
        (b, p, q)
    }

    /// J as a dense row-major matrix, and C, Cdot and the bias, at (t, x, v).
    fn evaluated(system: &System, t: f64, x: &[f64], v: &[f64]) -> Vec<f64> {
        let set = system.constraints();
        let mut ws = set.workspace();
        set.evaluate(t, x, v, &mut ws);
        let n = x.len();
        let mut out = Vec::new();
        for r in 0..set.n_rows() {
            let mut row = vec![0.0; n];
            for (&k, e) in set.row_columns(r).iter().zip(set.row_entries(r)) {
                row[k] = ws.jacobian[e];
            }
            out.extend(row);
            out.extend([ws.value[r], ws.velocity[r], ws.bias[r]]);
        }
        out
    }

    /// Every operation a trace records gives, as an expression with symbolic derivatives,
    /// the value, velocity, bias and gradient the dual numbers give, at 50 random points
    /// (to 1e-13 of each figure's size): an independent check of every rule the trace
    /// writes, since the dual numbers run the Rust code itself.
    #[test]
    fn a_traced_constraint_gives_what_its_dual_numbers_give() {
        let (mut traced, p, q) = two_particles();
        traced.holonomic("everything", Everything(p, q));
        let (mut duals, p, q) = two_particles();
        duals.holonomic_by_dual_numbers("everything", Everything(p, q));
        let (traced, duals) = (traced.build().unwrap(), duals.build().unwrap());
        assert!(traced.constraints().only_taped(), "the trace is taken");
        assert!(traced.constraints().is_time_dependent(0), "C reads t");
        assert!(!duals.constraints().only_taped());
        assert_eq!(
            traced.constraint_description(0),
            "Rust constraint (traced into an expression: symbolic derivatives)"
        );
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut uniform = |lo: f64, hi: f64| {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            lo + (hi - lo) * ((seed >> 11) as f64 / (1u64 << 53) as f64)
        };
        for _ in 0..50 {
            let x: Vec<f64> = (0..6).map(|_| uniform(0.5, 1.5)).collect();
            let v: Vec<f64> = (0..6).map(|_| uniform(-1.0, 1.0)).collect();
            let t = uniform(0.0, 1.0);
            let (a, b) = (evaluated(&traced, t, &x, &v), evaluated(&duals, t, &x, &v));
            assert_eq!(a.len(), b.len());
            for (i, (a, b)) in a.iter().zip(&b).enumerate() {
                let tolerance = 1e-13 * (1.0 + b.abs());
                assert!(
                    (a - b).abs() <= tolerance,
                    "figure {i}: {a} vs {b} at {x:?}, t = {t}"
                );
            }
        }
    }

    /// Code that compares or reads a value, or calls a function the expression language has
    /// no exact form of, keeps its dual numbers, says why, and still runs: its system's
    /// figures are the dual-number system's, bit for bit.
    #[test]
    fn code_a_trace_cannot_follow_keeps_its_dual_numbers() {
        type Case = fn(&mut SystemBuilder, ParticleId, bool);
        macro_rules! case {
            ($why:literal, |$x:ident| $body:expr) => {{
                struct One(ParticleId);
                impl Holonomic for One {
                    fn particles(&self) -> Vec<ParticleId> {
                        vec![self.0]
                    }
                    fn value<T: Scalar>(&self, $x: &[T], _t: T) -> T {
                        $body
                    }
                }
                let declare: Case = |b, p, traced| {
                    if traced {
                        b.holonomic("c", One(p));
                    } else {
                        b.holonomic_by_dual_numbers("c", One(p));
                    }
                };
                ($why, declare)
            }};
        }
        let cases = [
            case!("a comparison", |x| if x[0] > x[1] {
                x[0] * x[0] + x[1]
            } else {
                x[1]
            }),
            case!("a comparison", |x| if x[0] > 0.0 {
                x[0] * x[0] + x[1]
            } else {
                x[1]
            }),
            case!("==", |x| if x[0] == x[1] {
                x[1]
            } else {
                x[0] * x[0] + x[1]
            }),
            case!("re()", |x| x[0] * x[0].re() + x[1]),
            case!("is_positive", |x| if x[0].is_positive() {
                x[0] * x[0] + x[1]
            } else {
                x[1]
            }),
            case!("signum", |x| x[0] * x[0].signum() + x[1]),
            case!("cbrt", |x| x[0].cbrt() + x[1]),
            case!("exp2", |x| x[0].exp2() + x[1]),
            case!("log2", |x| x[0].log2() + x[1]),
            case!("asinh", |x| x[0].asinh() + x[1]),
            case!("mul_add", |x| x[0].mul_add(x[0], x[1])),
            case!("is_zero", |x| if x[0].is_zero() {
                x[1]
            } else {
                x[0] * x[0] + x[1]
            }),
            case!("is_negative", |x| if x[0].is_negative() {
                x[1]
            } else {
                x[0] * x[0] + x[1]
            }),
            case!("abs_sub", |x| x[0].abs_sub(&x[1]) + x[1]),
            // `One::is_one`'s default compares with `==`, `!=` is `==`'s, `<=` `partial_cmp`'s.
            case!("==", |x| if x[0].is_one() {
                x[1]
            } else {
                x[0] * x[0] + x[1]
            }),
            case!("==", |x| if x[0] != x[1] {
                x[0] * x[0] + x[1]
            } else {
                x[1]
            }),
            case!("a comparison", |x| if x[0] <= x[1] {
                x[1]
            } else {
                x[0] * x[0] + x[1]
            }),
            case!("exp_m1", |x| x[0].exp_m1() + x[1]),
            case!("ln_1p", |x| x[0].ln_1p() + x[1]),
            case!("log", |x| x[0].log(3.0) + x[1]),
            case!("acosh", |x| x[0].acosh() + x[1]),
            case!("atanh", |x| (x[0] * 0.5).atanh() + x[1]),
            case!("sph_j0", |x| x[0].sph_j0() + x[1]),
            case!("printing", |x| x[0] * x[0]
                + x[1] * format!("{}", x[0]).len() as f64),
        ];
        for (why, declare) in cases {
            let system = |traced: bool| {
                let mut b = SystemBuilder::new(&[0.0, 9.81]);
                let p = b.particle("p", 1.0, &[1.2, -0.7], &[0.3, 0.1]).unwrap();
                declare(&mut b, p, traced);
                b.build().unwrap()
            };
            let (a, b) = (system(true), system(false));
            assert_eq!(
                a.constraint_description(0),
                format!("Rust constraint (derivatives by dual numbers: {why})"),
            );
            assert!(!a.constraints().only_taped(), "{why}");
            let (x, v) = ([1.1, -0.4], [0.2, -0.5]);
            let (ea, eb) = (evaluated(&a, 0.3, &x, &v), evaluated(&b, 0.3, &x, &v));
            assert!(crate::same_bits(&ea, &eb), "{why}");
        }
    }

    /// The article's parabola as a Rust type.
    struct Parabola(ParticleId);
    impl Holonomic for Parabola {
        fn particles(&self) -> Vec<ParticleId> {
            vec![self.0]
        }
        fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
            x[0] * x[0] + x[1] * 100.0
        }
        fn time_dependent(&self) -> bool {
            false
        }
    }

    /// A traced Rust constraint is the constraint typed as text: the article's parabola as
    /// a Rust type runs, through `Simulation` with rk4 (express steps) and RATTLE, 600 steps
    /// to the same bits as `x*x + y*100` typed in a scene, energy and constraint error
    /// included; and it now takes the compiled paths the text takes.
    #[test]
    fn a_traced_constraint_runs_as_the_same_constraint_typed() {
        use crate::integrate::IntegratorKind;
        use crate::simulate::{Simulation, SimulationConfig};
        let system = |rust: bool| {
            let mut b = SystemBuilder::new(&[0.0, 500.0]);
            let bead = b
                .particle("bead", 1.0, &[150.0, -225.0], &[0.0, 0.0])
                .unwrap();
            if rust {
                b.holonomic("parabola", Parabola(bead));
            } else {
                b.constraint_expr("bead.x*bead.x + bead.y*100").unwrap();
            }
            std::sync::Arc::new(b.build().unwrap())
        };
        let (rust, text) = (system(true), system(false));
        assert!(rust.constraints().only_taped());
        for integrator in [IntegratorKind::Rk4, IntegratorKind::Rattle] {
            let config = SimulationConfig {
                integrator,
                ..SimulationConfig::default()
            };
            let mut a = Simulation::new(rust.clone(), config).unwrap();
            let mut b = Simulation::new(text.clone(), config).unwrap();
            for _ in 0..600 {
                assert_eq!(format!("{:?}", a.step()), format!("{:?}", b.step()));
            }
            let end = |s: &Simulation| {
                let head = [s.t(), s.energy(), s.constraint_error()];
                head.iter()
                    .chain(s.q())
                    .chain(s.qdot())
                    .map(|v| v.to_bits())
                    .collect::<Vec<_>>()
            };
            assert_eq!(end(&a), end(&b), "{integrator:?}");
            assert!(a.q()[0] != 150.0, "it moved");
        }
    }

    /// A constraint whose value declares a Rust constraint of its own (a system built
    /// inside it) does not wait for itself: both are traced, each in its own recording.
    #[test]
    fn a_trace_inside_a_trace_does_not_wait_for_itself() {
        static INNER: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());
        struct Inner(ParticleId);
        impl Holonomic for Inner {
            fn particles(&self) -> Vec<ParticleId> {
                vec![self.0]
            }
            fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
                x[0] - x[1]
            }
        }
        struct Outer(ParticleId);
        impl Holonomic for Outer {
            fn particles(&self) -> Vec<ParticleId> {
                vec![self.0]
            }
            fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
                let mut b = SystemBuilder::new(&[0.0, 0.0]);
                let p = b.particle("p", 1.0, &[1.0, 1.0], &[0.0, 0.0]).unwrap();
                b.holonomic("inner", Inner(p));
                let inner = b.build().unwrap().constraint_description(0);
                INNER.lock().unwrap().push(inner);
                x[0] + x[1]
            }
        }
        let mut b = SystemBuilder::new(&[0.0, 0.0]);
        let p = b.particle("p", 1.0, &[1.0, 1.0], &[0.0, 0.0]).unwrap();
        b.holonomic("outer", Outer(p));
        let system = b.build().unwrap();
        assert!(system.constraints().only_taped(), "the outer one is traced");
        // `time_dependent` says true (the default), but the expression does not read t.
        assert!(!system.constraints().is_time_dependent(0));
        let inner = INNER.lock().unwrap();
        assert_eq!(
            inner[0],
            "Rust constraint (traced into an expression: symbolic derivatives)"
        );
    }

    /// A trace: refused with `%` (whose dual numbers num-dual leaves unimplemented, so the
    /// table above cannot hold it), and kept with comparisons and reads of constants, which
    /// do not depend on x or t.
    #[test]
    fn remainders_refuse_and_constants_may_be_compared() {
        struct Remainder;
        impl Holonomic for Remainder {
            fn particles(&self) -> Vec<ParticleId> {
                vec![]
            }
            fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
                x[0] % 2.0 + x[1]
            }
        }
        struct Constants;
        impl Holonomic for Constants {
            fn particles(&self) -> Vec<ParticleId> {
                vec![]
            }
            fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
                let two = T::from(2.0);
                let scale = if two > T::zero() && two.re() == 2.0 && !two.is_one() {
                    two.sqrt()
                } else {
                    two
                };
                x[0] * scale + x[1] * format!("{two}").len() as f64
            }
        }
        let (x, vars) = ([1.2, -0.7], [4, 5]);
        assert_eq!(super::trace(&Remainder, &x, &vars, 9).unwrap_err(), "%");
        let expr = super::trace(&Constants, &x, &vars, 9).expect("traced");
        let mut at = [0.0; 10];
        at[4] = 1.5;
        at[5] = 2.0;
        assert_eq!(expr.eval(&at), 1.5 * 2f64.sqrt() + 2.0);
        assert!(!super::last_trace_in_progress());
    }

    /// The safety net: code that reads state other than x and t (here a counter of its
    /// calls) gives another value when it runs again, and a trace, which would freeze that
    /// state, is refused.
    #[test]
    fn code_that_reads_other_state_is_not_traced() {
        use std::sync::atomic::{AtomicU64, Ordering};
        struct Counting(ParticleId, AtomicU64);
        impl Holonomic for Counting {
            fn particles(&self) -> Vec<ParticleId> {
                vec![self.0]
            }
            fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
                let calls = self.1.fetch_add(1, Ordering::Relaxed) as f64;
                x[0] * x[0] + x[1] + T::from(calls)
            }
        }
        let mut b = SystemBuilder::new(&[0.0, 9.81]);
        let p = b.particle("p", 1.0, &[1.2, -0.7], &[0.0, 0.0]).unwrap();
        b.holonomic("counting", Counting(p, AtomicU64::new(0)));
        assert_eq!(
            b.build().unwrap().constraint_description(0),
            "Rust constraint (derivatives by dual numbers: its traced expression gives \
             another value than its code)"
        );
    }

    /// A number kept from an ended trace and met in another refuses that one, whatever the
    /// order of the operands.
    #[test]
    fn numbers_of_an_ended_trace_refuse_the_next() {
        use std::any::Any;
        use std::cell::RefCell;
        thread_local! {
            static KEPT: RefCell<Option<Box<dyn Any>>> = const { RefCell::new(None) };
        }
        struct Keeping(ParticleId, bool);
        impl Holonomic for Keeping {
            fn particles(&self) -> Vec<ParticleId> {
                vec![self.0]
            }
            fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
                let kept =
                    KEPT.with_borrow(|k| k.as_ref().and_then(|k| k.downcast_ref::<T>().copied()));
                KEPT.with_borrow_mut(|k| *k = Some(Box::new(x[0])));
                match kept {
                    Some(old) if self.1 => old + x[0] * x[0] + x[1],
                    Some(old) => x[0] * x[0] + x[1] + old,
                    None => x[0] * x[0] + x[1],
                }
            }
        }
        for kept_first in [true, false] {
            KEPT.with_borrow_mut(|k| *k = None);
            let mut b = SystemBuilder::new(&[0.0, 9.81]);
            let p = b.particle("p", 1.0, &[1.2, -0.7], &[0.0, 0.0]).unwrap();
            b.holonomic("first", Keeping(p, kept_first));
            b.holonomic("second", Keeping(p, kept_first));
            let system = b.build().unwrap();
            let second = system.constraint_description(1);
            assert!(
                second.starts_with("Rust constraint (derivatives by dual numbers: "),
                "{second}"
            );
        }
    }

    /// A trace whose code panics leaves nothing behind, and the next trace is taken.
    #[test]
    fn a_panic_in_a_trace_leaves_nothing_behind() {
        struct Panicking(ParticleId);
        impl Holonomic for Panicking {
            fn particles(&self) -> Vec<ParticleId> {
                vec![self.0]
            }
            fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
                let _ = x[0] * x[0];
                panic!("a constraint that panics")
            }
        }
        let mut b = SystemBuilder::new(&[0.0, 9.81]);
        let p = b.particle("p", 1.0, &[1.2, -0.7], &[0.0, 0.0]).unwrap();
        let panicked = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            b.holonomic("panics", Panicking(p));
        }));
        assert!(panicked.is_err());
        assert!(!super::last_trace_in_progress());
        b.holonomic("parabola", Parabola(p));
        assert!(b.build().unwrap().constraints().only_taped());
    }

    /// Systems built on several threads at once each trace their own constraints, to the
    /// same expression as built alone; and a constraint naming a particle the system does
    /// not have is an error of `build`, not a panic.
    #[test]
    fn traces_on_several_threads_and_an_unknown_particle() {
        let build = || {
            let (mut b, p, q) = two_particles();
            b.holonomic("everything", Everything(p, q));
            b.build().unwrap()
        };
        let alone = evaluated(&build(), 0.3, &[1.0; 6], &[0.5; 6]);
        std::thread::scope(|scope| {
            let threads: Vec<_> = (0..4)
                .map(|_| {
                    scope.spawn(|| {
                        (0..20)
                            .map(|_| evaluated(&build(), 0.3, &[1.0; 6], &[0.5; 6]))
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            for thread in threads {
                for figures in thread.join().unwrap() {
                    assert!(crate::same_bits(&figures, &alone));
                }
            }
        });
        let mut b = SystemBuilder::new(&[0.0, 9.81]);
        b.particle("p", 1.0, &[1.2, -0.7], &[0.0, 0.0]).unwrap();
        b.holonomic("nowhere", Parabola(ParticleId(7)));
        let error = b.build().unwrap_err().to_string();
        assert!(error.contains('7') || error.contains("particle"), "{error}");
    }
}
