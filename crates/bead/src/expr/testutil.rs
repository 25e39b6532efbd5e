//! Helpers for the expression tests: a tiny deterministic RNG and random expressions.
use super::{Expr, Func};

/// xorshift64* generator (deterministic, dependency-free).
pub(crate) struct Rng(u64);

impl Rng {
    pub(crate) fn new(seed: u64) -> Rng {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub(crate) fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    pub(crate) fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
    /// Uniform in [lo, hi).
    pub(crate) fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }
}

/// A random expression over slots `0..n_vars`, of roughly `depth` levels, which is smooth
/// and finite for variables in [-2, 2] (functions are applied to safe arguments). Leaves are
/// drawn from `pool` too, so results share subexpressions.
pub(crate) fn random_expr(
    rng: &mut Rng,
    n_vars: usize,
    depth: usize,
    pool: &mut Vec<Expr>,
) -> Expr {
    if depth == 0 || rng.below(6) == 0 {
        return match rng.below(4) {
            0 => Expr::constant((rng.uniform(-3.0, 3.0) * 4.0).round() / 4.0),
            1 if !pool.is_empty() => pool[rng.below(pool.len())].clone(),
            _ => Expr::var(rng.below(n_vars)),
        };
    }
    let a = random_expr(rng, n_vars, depth - 1, pool);
    let one = || Expr::constant(1.0);
    let pos = |x: &Expr| one() + x.powi(2); // >= 1
    let e = match rng.below(26) {
        0 | 1 => &a + &random_expr(rng, n_vars, depth - 1, pool),
        2 | 3 => &a - &random_expr(rng, n_vars, depth - 1, pool),
        4 | 5 => &a * &random_expr(rng, n_vars, depth - 1, pool),
        6 => &a / &pos(&random_expr(rng, n_vars, depth - 1, pool)),
        7 => -a,
        8 => a.sin(),
        9 => a.cos(),
        10 => Expr::call(Func::Atan, vec![a]),
        11 => Expr::call(Func::Tanh, vec![a]),
        12 => Expr::call(Func::Exp, vec![Expr::call(Func::Sin, vec![a])]),
        13 => Expr::call(Func::Ln, vec![pos(&a)]),
        14 => pos(&a).sqrt(),
        15 => match rng.below(3) {
            0 => a.powi(rng.below(4) as i32) * 0.5,
            1 => pos(&a).powi(-(rng.below(3) as i32) - 1),
            _ => a.powi(17 + rng.below(2) as i32) / 1000.0,
        },
        16 => pos(&a).powf(&Expr::constant(0.75)),
        17 => Expr::call(
            Func::Atan2,
            vec![a, pos(&random_expr(rng, n_vars, depth - 1, pool))],
        ),
        18 => Expr::call(Func::Sinh, vec![Expr::call(Func::Tanh, vec![a])]),
        19 => Expr::call(Func::Cosh, vec![Expr::call(Func::Sin, vec![a])]),
        20 => Expr::call(Func::Asin, vec![Expr::call(Func::Tanh, vec![a]) * 0.9]),
        21 => Expr::call(Func::Tan, vec![Expr::call(Func::Tanh, vec![a])]),
        22 => Expr::call(Func::Acos, vec![Expr::call(Func::Tanh, vec![a]) * 0.9]),
        23 => Expr::call(Func::Log10, vec![pos(&a)]),
        24 => Expr::call(Func::Abs, vec![a]),
        _ => pos(&a).powf(&Expr::call(
            Func::Sin,
            vec![random_expr(rng, n_vars, depth - 1, pool)],
        )),
    };
    if rng.below(3) == 0 {
        pool.push(e.clone());
    }
    e
}
