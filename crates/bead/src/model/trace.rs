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
//! - compares a value (`<`, `==`, `is_positive`, `signum`, `is_zero`...) or reads one out
//!   (`re()`): it may branch on it;
//! - calls a function the expression language does not have with the same bits (`cbrt`,
//!   `exp2`, `exp_m1`, `ln_1p`, `log`, `log2`, the inverse hyperbolic functions, the spherical
//!   Bessel functions, a fused `mul_add`, `%`);
//! - gives at the sample a value other than the recorded expression's (a safety net: the two
//!   must agree bit for bit).
//!
//! The traced expression computes what `value::<f64>` computes, operation for operation, up
//! to the expression language's exact simplifications (`x * 1 = x`, constants folded) and
//! its integer powers (`x^n` by `powi`, as `f64::powi`; a constant `powf` exponent that is an
//! integer is taken as one). Its derivatives are the symbolic ones, which may differ from
//! the dual numbers' in the last bits.

use std::cmp::Ordering;
use std::fmt;
use std::iter::{Product, Sum};
use std::ops::{
    Add, AddAssign, Div, DivAssign, Mul, MulAssign, Neg, Rem, RemAssign, Sub, SubAssign,
};
use std::sync::Mutex;

use num_dual::{DualNum, DualStruct, Mappable};
use num_traits::{FromPrimitive, Inv, Num, One, ParseFloatError, Signed, Zero};

use super::Holonomic;
use crate::expr::{Expr, Func};

/// The recording of the trace in progress: every node made so far and, once the code did
/// something a trace cannot follow, what it was.
struct Recording {
    nodes: Vec<Expr>,
    refused: Option<&'static str>,
    /// The largest magnitude of any value at the sample (the scale of its rounding)
    scale: f64,
}

/// The trace in progress (one at a time, see [`TURN`]); a number made on another thread of the
/// traced code records here too.
static RECORDING: Mutex<Option<Recording>> = Mutex::new(None);
/// Held for a whole trace, so that two systems built at once trace one after the other.
static TURN: Mutex<()> = Mutex::new(());

thread_local! {
    /// Whether this thread is tracing: a constraint whose `value` builds a system with a
    /// Rust constraint of its own would otherwise wait for its own turn forever.
    static TRACING: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Marks this thread as tracing while it lives (cleared on a panic too).
struct Tracing;
impl Tracing {
    /// None when this thread traces already (which it leaves marked).
    fn start() -> Option<Tracing> {
        if TRACING.replace(true) {
            None
        } else {
            Some(Tracing)
        }
    }
}
impl Drop for Tracing {
    fn drop(&mut self) {
        TRACING.set(false);
    }
}

/// A number that records the operations made on it (see the module): its value at the
/// sample point and its node in the recording.
#[derive(Clone, Copy)]
pub(crate) struct Traced {
    re: f64,
    node: u32,
}

fn with_recording<R>(f: impl FnOnce(&mut Recording) -> R) -> Option<R> {
    let mut guard = RECORDING.lock().unwrap_or_else(|e| e.into_inner());
    guard.as_mut().map(f)
}

impl Traced {
    /// A new number of value `re` whose expression is `expr`. Outside a trace (which the
    /// crate never does), the node is a dangling index and the trace that reads it fails.
    fn record(re: f64, expr: impl FnOnce(&[Expr]) -> Expr) -> Traced {
        let node = with_recording(|r| {
            let e = expr(&r.nodes);
            r.nodes.push(e);
            if re.is_finite() {
                r.scale = r.scale.max(re.abs());
            }
            r.nodes.len() - 1
        })
        .and_then(|n| u32::try_from(n).ok())
        .unwrap_or(u32::MAX);
        Traced { re, node }
    }

    fn constant(re: f64) -> Traced {
        Traced::record(re, |_| Expr::constant(re))
    }

    fn expr(nodes: &[Expr], t: Traced) -> Expr {
        nodes
            .get(t.node as usize)
            .cloned()
            .unwrap_or_else(|| Expr::constant(f64::NAN))
    }

    /// This number's value, noting that the traced code may branch on it.
    fn refuse(self, why: &'static str) -> f64 {
        with_recording(|r| {
            r.refused.get_or_insert(why);
        });
        self.re
    }

    /// The result of a function the expression language has no exact form of: the value on
    /// f64, and a refused trace.
    fn unsupported(self, name: &'static str, re: f64) -> Traced {
        self.refuse(name);
        Traced::constant(re)
    }

    fn unary(self, re: f64, f: Func) -> Traced {
        Traced::record(re, |n| Expr::call(f, vec![Traced::expr(n, self)]))
    }

    fn binary(self, other: Traced, re: f64, op: fn(Expr, Expr) -> Expr) -> Traced {
        Traced::record(re, |n| op(Traced::expr(n, self), Traced::expr(n, other)))
    }
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
    let Some(_tracing) = Tracing::start() else {
        return Err("its value declares a Rust constraint of its own");
    };
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let fresh = Recording {
        nodes: Vec::new(),
        refused: None,
        scale: 0.0,
    };
    *RECORDING.lock().unwrap_or_else(|e| e.into_inner()) = Some(fresh);
    let point: Vec<Traced> = x
        .iter()
        .zip(vars)
        .map(|(&re, &k)| Traced::record(re, |_| Expr::var(k)))
        .collect();
    let t = Traced::record(0.0, |_| Expr::var(time));
    let value = constraint.value(&point, t);
    let recording = RECORDING.lock().unwrap_or_else(|e| e.into_inner()).take();
    let recording = recording.ok_or("the trace was lost")?;
    if let Some(why) = recording.refused {
        return Err(why);
    }
    let expr = recording
        .nodes
        .get(value.node as usize)
        .cloned()
        .ok_or("a number was made outside the trace")?;
    // The safety net: the expression gives the value the code computed on f64, to the
    // rounding of its largest intermediate (an integer power by `powi` where the code calls
    // `powf` may differ in the last bit), and the value recorded beside it.
    let exact = constraint.value(x, 0.0);
    let mut at = vec![0.0; vars.iter().chain([&time]).max().map_or(0, |m| m + 1)];
    for (&k, &v) in vars.iter().zip(x) {
        at[k] = v;
    }
    let traced = expr.eval(&at);
    let tolerance = 1e-12 * recording.scale;
    let agree = |a: f64, b: f64| a.to_bits() == b.to_bits() || (a - b).abs() <= tolerance;
    if !agree(traced, exact) || !agree(value.re, exact) {
        return Err("its traced expression gives another value than its code");
    }
    Ok(expr)
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
        other.refuse("%");
        self.unsupported("%", self.re % other.re)
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
        self.unsupported("%", self.re % other)
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
        Traced::record(-self.re, |n| -Traced::expr(n, self))
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
        self.unary(self.re.abs(), Func::Abs)
    }
    fn abs_sub(&self, other: &Traced) -> Traced {
        other.refuse("abs_sub");
        self.unsupported("abs_sub", <f64 as Signed>::abs_sub(&self.re, &other.re))
    }
    fn signum(&self) -> Traced {
        self.unsupported("signum", self.re.signum())
    }
    fn is_positive(&self) -> bool {
        self.refuse("is_positive").is_sign_positive()
    }
    fn is_negative(&self) -> bool {
        self.refuse("is_negative").is_sign_negative()
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

impl fmt::Display for Traced {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.re)
    }
}
impl fmt::Debug for Traced {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Traced({}, node {})", self.re, self.node)
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
        Traced::record(re, |nodes| Traced::expr(nodes, *self).powi(n))
    }
    fn powf(&self, n: f64) -> Traced {
        let re = crate::expr::pow_const_f64(self.re, n);
        Traced::record(re, |nodes| {
            Traced::expr(nodes, *self).powf(&Expr::constant(n))
        })
    }
    fn powd(&self, n: Traced) -> Traced {
        let re = self.re.powf(n.re);
        self.binary(n, re, |a, b| a.powf(&b))
    }
    fn sqrt(&self) -> Traced {
        self.unary(self.re.sqrt(), Func::Sqrt)
    }
    fn cbrt(&self) -> Traced {
        self.unsupported("cbrt", self.re.cbrt())
    }
    fn exp(&self) -> Traced {
        self.unary(self.re.exp(), Func::Exp)
    }
    fn exp2(&self) -> Traced {
        self.unsupported("exp2", self.re.exp2())
    }
    fn exp_m1(&self) -> Traced {
        self.unsupported("exp_m1", self.re.exp_m1())
    }
    fn ln(&self) -> Traced {
        self.unary(self.re.ln(), Func::Ln)
    }
    fn log(&self, base: f64) -> Traced {
        self.unsupported("log", self.re.log(base))
    }
    fn log2(&self) -> Traced {
        self.unsupported("log2", self.re.log2())
    }
    fn log10(&self) -> Traced {
        self.unary(self.re.log10(), Func::Log10)
    }
    fn ln_1p(&self) -> Traced {
        self.unsupported("ln_1p", self.re.ln_1p())
    }
    fn sin(&self) -> Traced {
        self.unary(self.re.sin(), Func::Sin)
    }
    fn cos(&self) -> Traced {
        self.unary(self.re.cos(), Func::Cos)
    }
    fn tan(&self) -> Traced {
        self.unary(self.re.tan(), Func::Tan)
    }
    fn sin_cos(&self) -> (Traced, Traced) {
        let (s, c) = self.re.sin_cos();
        if s.to_bits() != self.re.sin().to_bits() || c.to_bits() != self.re.cos().to_bits() {
            self.refuse("sin_cos");
        }
        (self.unary(s, Func::Sin), self.unary(c, Func::Cos))
    }
    fn asin(&self) -> Traced {
        self.unary(self.re.asin(), Func::Asin)
    }
    fn acos(&self) -> Traced {
        self.unary(self.re.acos(), Func::Acos)
    }
    fn atan(&self) -> Traced {
        self.unary(self.re.atan(), Func::Atan)
    }
    fn atan2(&self, other: Traced) -> Traced {
        let re = self.re.atan2(other.re);
        Traced::record(re, |n| {
            Expr::call(
                Func::Atan2,
                vec![Traced::expr(n, *self), Traced::expr(n, other)],
            )
        })
    }
    fn sinh(&self) -> Traced {
        self.unary(self.re.sinh(), Func::Sinh)
    }
    fn cosh(&self) -> Traced {
        self.unary(self.re.cosh(), Func::Cosh)
    }
    fn tanh(&self) -> Traced {
        self.unary(self.re.tanh(), Func::Tanh)
    }
    fn asinh(&self) -> Traced {
        self.unsupported("asinh", self.re.asinh())
    }
    fn acosh(&self) -> Traced {
        self.unsupported("acosh", self.re.acosh())
    }
    fn atanh(&self) -> Traced {
        self.unsupported("atanh", self.re.atanh())
    }
    fn sph_j0(&self) -> Traced {
        self.unsupported("sph_j0", self.re.sph_j0())
    }
    fn sph_j1(&self) -> Traced {
        self.unsupported("sph_j1", self.re.sph_j1())
    }
    fn sph_j2(&self) -> Traced {
        self.unsupported("sph_j2", self.re.sph_j2())
    }
    fn mul_add(&self, a: Traced, b: Traced) -> Traced {
        a.refuse("mul_add");
        b.refuse("mul_add");
        self.unsupported("mul_add", self.re.mul_add(a.re, b.re))
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
    /// inside it) does not wait for itself: the inner one keeps its dual numbers, and the
    /// outer one is traced.
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
            "Rust constraint (derivatives by dual numbers: its value declares a Rust \
             constraint of its own)"
        );
    }
}
