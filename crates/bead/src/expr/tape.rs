//! Straight-line compiled form.
//!
//! [`Tape::compile`] hash-conses the expression DAGs of all outputs (structural equality:
//! same operation, same operand slots, constants compared by bit pattern; `+` and `*` with
//! their operands sorted), so a subexpression that occurs several times — within one output
//! or across outputs, shared or built separately — is computed once. It then emits SSA
//! code: instruction `i` writes scratch slot `i` and reads only slots `< i`.
//!
//! Specialized instructions: constant operands are folded into the instruction
//! (`c + x`, `c * x`, `c - x`, `x / c`, `c / x`), `x*x` and `x^2` become a square,
//! `x^n` for a constant integer `|n| <= 16` becomes `powi`, another constant exponent `powf`,
//! and a product used only by one addition or subtraction is fused into it (`a*b + c`,
//! `a*b - c`, `c - a*b`, rounded twice exactly like the separate operations).
use super::ast::{int_exponent, sign_f64, topo, FastMap, Node};
use super::jit::{self, Native, NativeStatus};
use super::{Expr, Func};
use std::sync::Arc;

/// One instruction. Operands are scratch slots (`u32`); the result goes to the slot whose
/// index is the instruction's position. 16 bytes, `Copy`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Instr {
    Var(u32),
    Const(f64),
    Neg(u32),
    Add(u32, u32),
    Sub(u32, u32),
    Mul(u32, u32),
    Div(u32, u32),
    /// `a + c`
    AddC(u32, f64),
    /// `c - a`
    CSub(u32, f64),
    /// `c * a`
    MulC(u32, f64),
    /// `a / c`
    DivC(u32, f64),
    /// `c / a`
    CDiv(u32, f64),
    /// `a * a`
    Square(u32),
    /// `a.powi(n)`
    Powi(u32, i32),
    /// `a.powf(c)`
    Powf(u32, f64),
    /// `a.powf(b)`
    Pow(u32, u32),
    Sin(u32),
    Cos(u32),
    Tan(u32),
    Asin(u32),
    Acos(u32),
    Atan(u32),
    Sinh(u32),
    Cosh(u32),
    Tanh(u32),
    Exp(u32),
    Ln(u32),
    Log10(u32),
    Sqrt(u32),
    Abs(u32),
    Sign(u32),
    /// `atan2(y, x)`
    Atan2(u32, u32),
    /// `a*b + c` (two roundings, like the unfused pair)
    MulAdd(u32, u32, u32),
    /// `a*b - c`
    MulSub(u32, u32, u32),
    /// `c - a*b`
    SubMul(u32, u32, u32),
}

const _: () = assert!(std::mem::size_of::<Instr>() == 16);

/// Hash-consing key: (opcode, operand, operand, constant bits).
type Key = (u8, u32, u32, u64);

impl Instr {
    fn key(self) -> Key {
        use Instr::*;
        let c = |v: f64| v.to_bits();
        match self {
            Var(k) => (0, k, 0, 0),
            Const(v) => (1, 0, 0, c(v)),
            Neg(a) => (2, a, 0, 0),
            Add(a, b) => (3, a, b, 0),
            Sub(a, b) => (4, a, b, 0),
            Mul(a, b) => (5, a, b, 0),
            Div(a, b) => (6, a, b, 0),
            AddC(a, v) => (7, a, 0, c(v)),
            CSub(a, v) => (8, a, 0, c(v)),
            MulC(a, v) => (9, a, 0, c(v)),
            DivC(a, v) => (10, a, 0, c(v)),
            CDiv(a, v) => (11, a, 0, c(v)),
            Square(a) => (12, a, 0, 0),
            Powi(a, n) => (13, a, n as u32, 0),
            Powf(a, v) => (14, a, 0, c(v)),
            Pow(a, b) => (15, a, b, 0),
            Sin(a) => (16, a, 0, 0),
            Cos(a) => (17, a, 0, 0),
            Tan(a) => (18, a, 0, 0),
            Asin(a) => (19, a, 0, 0),
            Acos(a) => (20, a, 0, 0),
            Atan(a) => (21, a, 0, 0),
            Sinh(a) => (22, a, 0, 0),
            Cosh(a) => (23, a, 0, 0),
            Tanh(a) => (24, a, 0, 0),
            Exp(a) => (25, a, 0, 0),
            Ln(a) => (26, a, 0, 0),
            Log10(a) => (27, a, 0, 0),
            Sqrt(a) => (28, a, 0, 0),
            Abs(a) => (29, a, 0, 0),
            Sign(a) => (30, a, 0, 0),
            Atan2(a, b) => (31, a, b, 0),
            // Fused instructions come from `fuse` after hash-consing, or from a tape
            // appended whole (`TapeBuilder::append_with`), where sharing them is as exact.
            MulAdd(a, b, c) => (32, a, b, u64::from(c)),
            MulSub(a, b, c) => (33, a, b, u64::from(c)),
            SubMul(a, b, c) => (34, a, b, u64::from(c)),
        }
    }

    /// The constant this instruction carries, if any (what the machine code reads from the
    /// tape's constants, in instruction order: see `jit`).
    pub(super) fn constant(self) -> Option<f64> {
        use Instr::*;
        match self {
            Const(c)
            | AddC(_, c)
            | CSub(_, c)
            | MulC(_, c)
            | DivC(_, c)
            | CDiv(_, c)
            | Powf(_, c) => Some(c),
            _ => None,
        }
    }

    /// Everything but the carried constant: two tapes with equal shapes run the same machine
    /// code on their own constants.
    pub(super) fn shape(self) -> [u32; 4] {
        let (op, a, b, c) = self.key();
        let c = if self.constant().is_some() { 0 } else { c };
        [u32::from(op), a, b, c as u32]
    }

    /// The operand slots this instruction reads, mutably (for renumbering).
    fn operands_mut(&mut self) -> [Option<&mut u32>; 3] {
        use Instr::*;
        match self {
            Var(_) | Const(_) => [None, None, None],
            MulAdd(a, b, c) | MulSub(a, b, c) | SubMul(a, b, c) => [Some(a), Some(b), Some(c)],
            Add(a, b) | Sub(a, b) | Mul(a, b) | Div(a, b) | Pow(a, b) | Atan2(a, b) => {
                [Some(a), Some(b), None]
            }
            Neg(a)
            | AddC(a, _)
            | CSub(a, _)
            | MulC(a, _)
            | DivC(a, _)
            | CDiv(a, _)
            | Square(a)
            | Powi(a, _)
            | Powf(a, _)
            | Sin(a)
            | Cos(a)
            | Tan(a)
            | Asin(a)
            | Acos(a)
            | Atan(a)
            | Sinh(a)
            | Cosh(a)
            | Tanh(a)
            | Exp(a)
            | Ln(a)
            | Log10(a)
            | Sqrt(a)
            | Abs(a)
            | Sign(a) => [Some(a), None, None],
        }
    }

    /// The operand slots this instruction reads.
    pub(super) fn operands(mut self) -> [Option<u32>; 3] {
        self.operands_mut().map(|o| o.map(|s| *s))
    }
}

/// Fuse each product used only once, by an addition or subtraction, into that instruction
/// (`a*b + c`, `a*b - c`, `c - a*b`: the same two roundings as before), drop what no output
/// reads, then renumber.
fn fuse(code: Vec<Instr>, outputs: &mut [u32]) -> Vec<Instr> {
    let mut uses = vec![0u32; code.len()];
    for ins in &code {
        for s in ins.operands().into_iter().flatten() {
            uses[s as usize] += 1;
        }
    }
    for &o in outputs.iter() {
        uses[o as usize] += 1;
    }
    let mut code = code;
    let mut dead = vec![false; code.len()];
    for i in 0..code.len() {
        let single_mul = |s: u32, code: &[Instr]| match code[s as usize] {
            Instr::Mul(a, b) if uses[s as usize] == 1 => Some((a, b)),
            _ => None,
        };
        let fused = match code[i] {
            Instr::Add(x, y) => match (single_mul(x, &code), single_mul(y, &code)) {
                (Some((a, b)), _) => Some((Instr::MulAdd(a, b, y), x)),
                (None, Some((a, b))) => Some((Instr::MulAdd(a, b, x), y)),
                _ => None,
            },
            Instr::Sub(x, y) => match (single_mul(x, &code), single_mul(y, &code)) {
                (Some((a, b)), _) => Some((Instr::MulSub(a, b, y), x)),
                (None, Some((a, b))) => Some((Instr::SubMul(a, b, x), y)),
                _ => None,
            },
            _ => None,
        };
        if let Some((ins, gone)) = fused {
            code[i] = ins;
            dead[gone as usize] = true;
        }
    }
    // Dead code: what no output reaches (e.g. a fused tape's positions that only its
    // derivatives were built from).
    let mut live = vec![false; code.len()];
    for &o in outputs.iter() {
        live[o as usize] = true;
    }
    for i in (0..code.len()).rev() {
        if live[i] && !dead[i] {
            for s in code[i].operands().into_iter().flatten() {
                live[s as usize] = true;
            }
        }
        dead[i] |= !live[i];
    }
    let mut new_index = vec![u32::MAX; code.len()];
    let mut out = Vec::with_capacity(code.len());
    for (i, mut ins) in code.into_iter().enumerate() {
        if dead[i] {
            continue;
        }
        for s in ins.operands_mut().into_iter().flatten() {
            *s = new_index[*s as usize];
        }
        new_index[i] = out.len() as u32;
        out.push(ins);
    }
    for o in outputs.iter_mut() {
        *o = new_index[*o as usize];
    }
    out
}

/// The value of a compiled node: a constant not yet materialized, or a slot.
#[derive(Clone, Copy)]
enum Val {
    Const(f64),
    Slot(u32),
}

struct Builder {
    code: Vec<Instr>,
    memo: FastMap<Key, u32>,
}

impl Builder {
    fn emit(&mut self, ins: Instr) -> Val {
        let next = self.code.len() as u32;
        let slot = *self.memo.entry(ins.key()).or_insert(next);
        if slot == next {
            self.code.push(ins);
        }
        Val::Slot(slot)
    }

    fn slot(&mut self, v: Val) -> u32 {
        match v {
            Val::Slot(s) => s,
            Val::Const(c) => match self.emit(Instr::Const(c)) {
                Val::Slot(s) => s,
                Val::Const(_) => unreachable!("emit returns a slot"),
            },
        }
    }

    fn unary(&mut self, f: Func, a: Val) -> Val {
        let a = self.slot(a);
        self.emit(match f {
            Func::Sin => Instr::Sin(a),
            Func::Cos => Instr::Cos(a),
            Func::Tan => Instr::Tan(a),
            Func::Asin => Instr::Asin(a),
            Func::Acos => Instr::Acos(a),
            Func::Atan => Instr::Atan(a),
            Func::Sinh => Instr::Sinh(a),
            Func::Cosh => Instr::Cosh(a),
            Func::Tanh => Instr::Tanh(a),
            Func::Exp => Instr::Exp(a),
            Func::Ln => Instr::Ln(a),
            Func::Log10 => Instr::Log10(a),
            Func::Sqrt => Instr::Sqrt(a),
            Func::Abs => Instr::Abs(a),
            Func::Sign => Instr::Sign(a),
            Func::Atan2 | Func::Pow => Instr::Const(f64::NAN), // never unary nodes
        })
    }

    fn node(&mut self, n: &Node, a: Val, b: Val) -> Val {
        use Val::{Const as C, Slot as S};
        match n {
            Node::Const(c) => C(*c),
            Node::Var(k) => self.emit(Instr::Var(*k as u32)),
            Node::Neg(_) => match a {
                C(x) => C(-x),
                S(a) => self.emit(Instr::Neg(a)),
            },
            Node::Add(..) => match (a, b) {
                (C(x), C(y)) => C(x + y),
                (C(c), S(s)) | (S(s), C(c)) => self.emit(Instr::AddC(s, c)),
                (S(x), S(y)) => self.emit(Instr::Add(x.min(y), x.max(y))),
            },
            Node::Sub(..) => match (a, b) {
                (C(x), C(y)) => C(x - y),
                (C(c), S(s)) => self.emit(Instr::CSub(s, c)),
                // a - c = a + (-c) exactly
                (S(s), C(c)) => self.emit(Instr::AddC(s, -c)),
                (S(x), S(y)) => self.emit(Instr::Sub(x, y)),
            },
            Node::Mul(..) => match (a, b) {
                (C(x), C(y)) => C(x * y),
                (C(c), S(s)) | (S(s), C(c)) => self.emit(Instr::MulC(s, c)),
                (S(x), S(y)) if x == y => self.emit(Instr::Square(x)),
                (S(x), S(y)) => self.emit(Instr::Mul(x.min(y), x.max(y))),
            },
            Node::Div(..) => match (a, b) {
                (C(x), C(y)) => C(x / y),
                (C(c), S(s)) => self.emit(Instr::CDiv(s, c)),
                (S(s), C(c)) => self.emit(Instr::DivC(s, c)),
                (S(x), S(y)) => self.emit(Instr::Div(x, y)),
            },
            Node::Pow(..) => match (a, b) {
                (_, C(c)) => {
                    let s = self.slot(a);
                    match int_exponent(c) {
                        Some(2) => self.emit(Instr::Square(s)),
                        Some(n) => self.emit(Instr::Powi(s, n)),
                        None => self.emit(Instr::Powf(s, c)),
                    }
                }
                (_, S(e)) => {
                    let s = self.slot(a);
                    self.emit(Instr::Pow(s, e))
                }
            },
            Node::Unary(f, _) => self.unary(*f, a),
            Node::Atan2(..) => {
                let (y, x) = (self.slot(a), self.slot(b));
                self.emit(Instr::Atan2(y, x))
            }
        }
    }
}

/// Straight-line code for several outputs with common subexpressions shared.
///
/// Where the host allows, the tape also carries machine code for the same instructions (see
/// [`Tape::native_status`] and the `jit` module), shared by its clones and freed with the last
/// of them; the evaluations run it, with the same bits as the interpreter.
#[derive(Clone, Debug)]
pub struct Tape {
    code: Vec<Instr>,
    outputs: Vec<u32>,
    /// One more than the largest variable slot read (0 if none).
    n_vars: usize,
    /// The machine code, if compiled, and the constants it reads (instruction order).
    native: Option<Arc<Native>>,
    consts: Vec<f64>,
    status: NativeStatus,
}

impl Tape {
    /// Compile `outputs`; equal subexpressions (structurally) are computed once.
    ///
    /// # Panics
    /// If the tape would need more than `u32::MAX` slots or a variable slot exceeds
    /// `u32::MAX`.
    pub fn compile(outputs: &[Expr]) -> Tape {
        let t = topo(outputs);
        let mut b = Builder {
            code: Vec::new(),
            memo: FastMap::default(),
        };
        let mut vals: Vec<Val> = Vec::with_capacity(t.nodes.len());
        for (e, &[ia, ib]) in t.nodes.iter().zip(&t.kids) {
            let get = |i: u32| vals.get(i as usize).copied().unwrap_or(Val::Const(0.0));
            let (a, bv) = (get(ia), get(ib));
            if let Node::Var(k) = *e.0 {
                assert!(
                    u32::try_from(k).is_ok(),
                    "variable slot {k} too large for a tape"
                );
            }
            let v = b.node(&e.0, a, bv);
            vals.push(v);
        }
        let mut out: Vec<u32> = t.roots.iter().map(|&r| b.slot(vals[r as usize])).collect();
        Tape::assemble(b.code, &mut out)
    }

    /// The tape of `code` (SSA, hash-consed) with `outputs`: single-use products fused into
    /// their additions, then checked and sized.
    fn assemble(code: Vec<Instr>, outputs: &mut [u32]) -> Tape {
        let code = fuse(code, outputs);
        let out = outputs.to_vec();
        assert!(u32::try_from(code.len()).is_ok(), "tape too long");
        let n_vars = n_vars(&code);
        debug_assert!(code.iter().enumerate().all(|(i, ins)| ins
            .operands()
            .into_iter()
            .flatten()
            .all(|s| (s as usize) < i)));
        let (native, status) = jit::compile(&code, &out);
        let consts = if native.is_some() {
            jit::constants(&code)
        } else {
            Vec::new()
        };
        Tape {
            code,
            outputs: out,
            n_vars,
            native,
            consts,
            status,
        }
    }

    /// How this tape is evaluated: machine code (with its compile time) or the interpreter
    /// (switched off, nothing to compile, or why compiling failed).
    pub fn native_status(&self) -> &NativeStatus {
        &self.status
    }

    /// Whether the evaluations run machine code.
    pub fn is_native(&self) -> bool {
        self.native.is_some()
    }

    /// [`Tape::eval`] by the interpreter, whether or not the tape has machine code: the
    /// reference the machine code is tested against.
    ///
    /// # Panics
    /// As [`Tape::eval`].
    pub fn eval_interpreted(&self, vars: &[f64], scratch: &mut [f64], out: &mut [f64]) {
        self.interpret::<1>(vars, scratch, out);
    }

    /// [`Tape::eval_lanes`] by the interpreter, whether or not the tape has machine code.
    ///
    /// # Panics
    /// As [`Tape::eval_lanes`].
    pub fn eval_lanes_interpreted<const L: usize>(
        &self,
        vars: &[f64],
        scratch: &mut [f64],
        out: &mut [f64],
    ) {
        self.interpret::<L>(vars, scratch, out);
    }

    /// Length of the scratch buffer [`Tape::eval`] needs.
    pub fn n_slots(&self) -> usize {
        self.code.len()
    }

    /// Number of outputs.
    pub fn n_outputs(&self) -> usize {
        self.outputs.len()
    }

    /// The instructions and the output slots (for the machine code's tests).
    #[cfg(test)]
    pub(super) fn parts(&self) -> (&[Instr], &[u32]) {
        (&self.code, &self.outputs)
    }

    /// The most values the machine code holds at once (computed, still to be read): in the
    /// tape's order and in the order the four-chain vector code computes them in (for tests).
    #[cfg(test)]
    pub(crate) fn most_live_values(&self) -> (usize, usize) {
        super::jit::most_live_values(&self.code)
    }

    /// Number of instructions (for `bead check` and benchmarks).
    pub fn n_instructions(&self) -> usize {
        self.code.len()
    }

    /// The length `vars` must at least have: one more than the largest slot read.
    pub fn n_vars(&self) -> usize {
        self.n_vars
    }

    /// Evaluate all outputs. Allocation-free. `vars` must cover every slot the outputs read,
    /// `scratch.len() >= n_slots()`, `out.len() == n_outputs()`.
    ///
    /// The arithmetic is exactly that of [`Expr::eval`]: the results agree bit for bit
    /// (up to structural sharing, which never changes a value).
    ///
    /// # Panics
    /// If one of the length requirements above is violated.
    #[inline]
    pub fn eval(&self, vars: &[f64], scratch: &mut [f64], out: &mut [f64]) {
        self.eval_lanes::<1>(vars, scratch, out);
    }

    /// Evaluate all outputs for `L` independent sets of variables at once (an ensemble's
    /// members, structure of arrays): variable k of lane l is `vars[k * L + l]`, output j of
    /// lane l goes to `out[j * L + l]`; `scratch.len() >= n_slots() * L`. Allocation-free.
    ///
    /// Each instruction runs over the L lanes before the next, so the interpretation costs
    /// once per L evaluations and the lane loops vectorize. Every lane's arithmetic is that
    /// of [`Tape::eval`] (the same code, instantiated for one lane there): results agree bit
    /// for bit with L separate evaluations.
    ///
    /// ```
    /// use bead::expr::{parse, Resolved, Tape};
    /// let x = |n: &str| if n == "x" { Ok(Resolved::Var(0)) } else { Err(format!("`{n}`?")) };
    /// let tape = Tape::compile(&[parse("x^2 + sin(x)", &x).unwrap()]);
    /// let vars = [0.5, 1.0, 2.0, -3.0];
    /// let mut scratch = vec![0.0; tape.n_slots() * 4];
    /// let mut out = [0.0; 4];
    /// tape.eval_lanes::<4>(&vars, &mut scratch, &mut out);
    /// for (v, o) in vars.iter().zip(out) {
    ///     let mut one = [0.0];
    ///     tape.eval(&[*v], &mut vec![0.0; tape.n_slots()], &mut one);
    ///     assert_eq!(o.to_bits(), one[0].to_bits());
    /// }
    /// ```
    ///
    /// # Panics
    /// If a length requirement is violated.
    #[inline]
    pub fn eval_lanes<const L: usize>(&self, vars: &[f64], scratch: &mut [f64], out: &mut [f64]) {
        match &self.native {
            // Machine code for one lane and for the sweep's blocks; other counts interpreted.
            Some(code) if jit::Native::runs(L) => {
                // The same requirements as the interpreter's, the scratch the code does
                // not use included.
                self.check_lengths::<L>(vars, scratch, out);
                if !code.run(vars, &self.consts, out, L) {
                    self.interpret::<L>(vars, scratch, out);
                }
            }
            _ => self.interpret::<L>(vars, scratch, out),
        }
    }

    /// The interpreter (the reference the machine code is tested against).
    fn interpret<const L: usize>(&self, vars: &[f64], scratch: &mut [f64], out: &mut [f64]) {
        self.check_lengths::<L>(vars, scratch, out);
        let scratch = &mut scratch[..self.code.len() * L];
        if L == 0 {
            return;
        }
        run_lanes::<L>(&self.code, vars, scratch);
        for (o, &slot) in out.chunks_exact_mut(L).zip(&self.outputs) {
            o.copy_from_slice(&scratch[slot as usize * L..][..L]);
        }
    }

    /// Panics unless `vars`, `scratch` and `out` have the lengths [`Tape::eval_lanes`] needs.
    #[inline]
    fn check_lengths<const L: usize>(&self, vars: &[f64], scratch: &[f64], out: &[f64]) {
        if L == 1 {
            assert!(
                vars.len() >= self.n_vars,
                "tape reads {} variable slots, got {}",
                self.n_vars,
                vars.len()
            );
        } else {
            assert!(
                vars.len() >= self.n_vars * L,
                "tape reads {} variable slots of {L} lanes, got {} values",
                self.n_vars,
                vars.len()
            );
        }
        assert_eq!(out.len(), self.outputs.len() * L, "wrong number of outputs");
        assert!(scratch.len() >= self.code.len() * L, "scratch too short");
    }
}

/// One more than the largest variable slot `code` reads (0 if none).
pub(super) fn n_vars(code: &[Instr]) -> usize {
    code.iter()
        .filter_map(|i| match *i {
            Instr::Var(k) => Some(k as usize + 1),
            _ => None,
        })
        .max()
        .unwrap_or(0)
}

/// A value while a tape is built by [`TapeBuilder`]: a constant (folded at build time) or a
/// scratch slot.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sym(Val);

impl std::fmt::Debug for Val {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Val::Const(c) => write!(f, "{c}"),
            Val::Slot(s) => write!(f, "%{s}"),
        }
    }
}

/// Builds a tape from elementary operations, for code beyond expressions (the fused
/// accelerations of [`crate::formulation`]): each method emits exactly the IEEE operation it
/// names, in the order called, so the tape computes the same bits as the same sequence of
/// `f64` operations in Rust. Constants are folded only where the fold is exact: both
/// operands constant (the build does the operation the run would do), and `x * 1`, `x / 1`,
/// `x + (-0)`, `x - 0`, which are x for every x (`x + 0` and `0 * x` are not, at x = -0,
/// negative, inf or NaN); common subexpressions are shared (an identical operation on
/// identical operands gives identical bits).
pub(crate) struct TapeBuilder {
    b: Builder,
}

impl TapeBuilder {
    pub(crate) fn new() -> Self {
        TapeBuilder {
            b: Builder {
                code: Vec::new(),
                memo: FastMap::default(),
            },
        }
    }

    /// Variable slot `k` of the tape's input.
    pub(crate) fn var(&mut self, k: usize) -> Sym {
        let k = u32::try_from(k).expect("variable slot too large for a tape");
        Sym(self.b.emit(Instr::Var(k)))
    }

    /// A constant.
    pub(crate) fn constant(&self, c: f64) -> Sym {
        Sym(Val::Const(c))
    }

    /// `tape`'s code, reading the same variable slots, appended: its outputs in order.
    pub(crate) fn append(&mut self, tape: &Tape) -> Vec<Sym> {
        let vars: Vec<Sym> = (0..tape.n_vars).map(|k| self.var(k)).collect();
        self.append_with(tape, &vars)
    }

    /// `tape`'s code appended with its variable k read from `vars[k]` (another evaluation of
    /// it inside this tape): its outputs in order. Where a variable is a constant, what it
    /// reaches is folded as the other methods fold (the same IEEE operations, done at build
    /// time where every operand is constant).
    pub(crate) fn append_with(&mut self, tape: &Tape, vars: &[Sym]) -> Vec<Sym> {
        let mut vals: Vec<Val> = Vec::with_capacity(tape.code.len());
        for &ins in &tape.code {
            let val = match ins {
                Instr::Var(k) => vars[k as usize].0,
                Instr::Const(c) => Val::Const(c),
                _ => self.fold(ins, &vals),
            };
            vals.push(val);
        }
        tape.outputs
            .iter()
            .map(|&o| Sym(vals[o as usize]))
            .collect()
    }

    /// `ins` with its operands read from `vals` (by the appended tape's slot numbers).
    fn fold(&mut self, ins: Instr, vals: &[Val]) -> Val {
        use Val::{Const as C, Slot as S};
        let operands = ins.operands().map(|o| o.map(|s| vals[s as usize]));
        let present = || operands.iter().flatten();
        if present().all(|v| matches!(v, S(_))) {
            let mut ins = ins;
            for s in ins.operands_mut().into_iter().flatten() {
                let S(slot) = vals[*s as usize] else {
                    unreachable!("checked above")
                };
                *s = slot;
            }
            return self.b.emit(ins);
        }
        if present().all(|v| matches!(v, C(_))) {
            // The interpreter's own operation on the constants.
            let mut code: Vec<Instr> = present()
                .map(|v| match v {
                    C(c) => Instr::Const(*c),
                    S(_) => unreachable!("checked above"),
                })
                .collect();
            let mut ins = ins;
            for (k, s) in ins.operands_mut().into_iter().flatten().enumerate() {
                *s = k as u32;
            }
            code.push(ins);
            let mut scratch = vec![0.0; code.len()];
            run_lanes::<1>(&code, &[], &mut scratch);
            return C(scratch[code.len() - 1]);
        }
        let [a, b, c] = operands.map(|o| Sym(o.unwrap_or(C(f64::NAN))));
        match ins {
            Instr::Add(..) => self.add(a, b).0,
            Instr::Sub(..) => self.sub(a, b).0,
            Instr::Mul(..) => self.mul(a, b).0,
            Instr::Div(..) => self.div(a, b).0,
            // x y + z, x y - z, z - x y: two roundings, as the fused instructions do.
            Instr::MulAdd(..) => {
                let p = self.mul(a, b);
                self.add(p, c).0
            }
            Instr::MulSub(..) => {
                let p = self.mul(a, b);
                self.sub(p, c).0
            }
            Instr::SubMul(..) => {
                let p = self.mul(a, b);
                self.sub(c, p).0
            }
            // Pow, Atan2: the constant operand into a slot.
            _ => {
                let mut ins = ins;
                for s in ins.operands_mut().into_iter().flatten() {
                    *s = self.b.slot(vals[*s as usize]);
                }
                self.b.emit(ins)
            }
        }
    }

    /// `a + b`
    pub(crate) fn add(&mut self, a: Sym, b: Sym) -> Sym {
        use Val::{Const as C, Slot as S};
        Sym(match (a.0, b.0) {
            (C(x), C(y)) => C(x + y),
            // x + (-0) == x for every x.
            (C(c), S(s)) | (S(s), C(c)) if is_negative_zero(c) => S(s),
            (C(c), S(s)) | (S(s), C(c)) => self.b.emit(Instr::AddC(s, c)),
            (S(x), S(y)) => self.b.emit(Instr::Add(x.min(y), x.max(y))),
        })
    }
    /// `a - b`
    pub(crate) fn sub(&mut self, a: Sym, b: Sym) -> Sym {
        use Val::{Const as C, Slot as S};
        Sym(match (a.0, b.0) {
            (C(x), C(y)) => C(x - y),
            (C(c), S(s)) => self.b.emit(Instr::CSub(s, c)),
            // x - 0 == x + (-0) == x for every x.
            (S(s), C(c)) if c.to_bits() == 0 => S(s),
            // x - c == x + (-c) exactly.
            (S(s), C(c)) => self.b.emit(Instr::AddC(s, -c)),
            (S(x), S(y)) => self.b.emit(Instr::Sub(x, y)),
        })
    }
    /// `a * b`
    pub(crate) fn mul(&mut self, a: Sym, b: Sym) -> Sym {
        use Val::{Const as C, Slot as S};
        Sym(match (a.0, b.0) {
            (C(x), C(y)) => C(x * y),
            // x * 1 == x for every x.
            (C(c), S(s)) | (S(s), C(c)) if c == 1.0 => S(s),
            (C(c), S(s)) | (S(s), C(c)) => self.b.emit(Instr::MulC(s, c)),
            (S(x), S(y)) if x == y => self.b.emit(Instr::Square(x)),
            (S(x), S(y)) => self.b.emit(Instr::Mul(x.min(y), x.max(y))),
        })
    }
    /// `a / b`
    pub(crate) fn div(&mut self, a: Sym, b: Sym) -> Sym {
        use Val::{Const as C, Slot as S};
        Sym(match (a.0, b.0) {
            (C(x), C(y)) => C(x / y),
            (C(c), S(s)) => self.b.emit(Instr::CDiv(s, c)),
            // x / 1 == x for every x.
            (S(s), C(1.0)) => S(s),
            (S(s), C(c)) => self.b.emit(Instr::DivC(s, c)),
            (S(x), S(y)) => self.b.emit(Instr::Div(x, y)),
        })
    }
    /// `-a`
    pub(crate) fn neg(&mut self, a: Sym) -> Sym {
        Sym(match a.0 {
            Val::Const(c) => Val::Const(-c),
            Val::Slot(s) => self.b.emit(Instr::Neg(s)),
        })
    }

    /// The tape computing `outputs`, its variables the slots read by [`Self::var`] and the
    /// appended tapes.
    pub(crate) fn finish(mut self, outputs: &[Sym]) -> Tape {
        let mut out: Vec<u32> = outputs.iter().map(|o| self.b.slot(o.0)).collect();
        Tape::assemble(self.b.code, &mut out)
    }
}

/// Whether `c` is -0.0 (the additive identity of IEEE arithmetic: x + (-0) == x, where
/// x + 0 turns -0 into +0).
fn is_negative_zero(c: f64) -> bool {
    c.to_bits() == (-0.0f64).to_bits()
}

/// Run `code` over L lanes: slot i of lane l is `s[i * L + l]`. One function for the scalar
/// evaluation (L = 1) and the lanes, so that both round alike.
#[inline(always)]
fn run_lanes<const L: usize>(code: &[Instr], vars: &[f64], s: &mut [f64]) {
    for (i, &ins) in code.iter().enumerate() {
        let (done, rest) = s.split_at_mut(i * L);
        let dst = &mut rest[..L];
        let get = |a: u32| -> &[f64] { &done[a as usize * L..][..L] };
        macro_rules! unary {
            ($a:expr, |$x:ident| $e:expr) => {{
                let a = get($a);
                for l in 0..L {
                    let $x = a[l];
                    dst[l] = $e;
                }
            }};
        }
        macro_rules! binary {
            ($a:expr, $b:expr, |$x:ident, $y:ident| $e:expr) => {{
                let (a, b) = (get($a), get($b));
                for l in 0..L {
                    let ($x, $y) = (a[l], b[l]);
                    dst[l] = $e;
                }
            }};
        }
        macro_rules! ternary {
            ($a:expr, $b:expr, $c:expr, |$x:ident, $y:ident, $z:ident| $e:expr) => {{
                let (a, b, c) = (get($a), get($b), get($c));
                for l in 0..L {
                    let ($x, $y, $z) = (a[l], b[l], c[l]);
                    dst[l] = $e;
                }
            }};
        }
        match ins {
            Instr::Var(k) => dst.copy_from_slice(&vars[k as usize * L..][..L]),
            Instr::Const(c) => dst.fill(c),
            Instr::Neg(a) => unary!(a, |x| -x),
            Instr::Add(a, b) => binary!(a, b, |x, y| x + y),
            Instr::Sub(a, b) => binary!(a, b, |x, y| x - y),
            Instr::Mul(a, b) => binary!(a, b, |x, y| x * y),
            Instr::Div(a, b) => binary!(a, b, |x, y| x / y),
            Instr::AddC(a, c) => unary!(a, |x| c + x),
            Instr::CSub(a, c) => unary!(a, |x| c - x),
            Instr::MulC(a, c) => unary!(a, |x| c * x),
            Instr::DivC(a, c) => unary!(a, |x| x / c),
            Instr::CDiv(a, c) => unary!(a, |x| c / x),
            Instr::Square(a) => unary!(a, |x| x * x),
            Instr::Powi(a, n) => unary!(a, |x| x.powi(n)),
            Instr::Powf(a, c) => unary!(a, |x| x.powf(c)),
            Instr::Pow(a, b) => binary!(a, b, |x, y| x.powf(y)),
            Instr::Sin(a) => unary!(a, |x| x.sin()),
            Instr::Cos(a) => unary!(a, |x| x.cos()),
            Instr::Tan(a) => unary!(a, |x| x.tan()),
            Instr::Asin(a) => unary!(a, |x| x.asin()),
            Instr::Acos(a) => unary!(a, |x| x.acos()),
            Instr::Atan(a) => unary!(a, |x| x.atan()),
            Instr::Sinh(a) => unary!(a, |x| x.sinh()),
            Instr::Cosh(a) => unary!(a, |x| x.cosh()),
            Instr::Tanh(a) => unary!(a, |x| x.tanh()),
            Instr::Exp(a) => unary!(a, |x| x.exp()),
            Instr::Ln(a) => unary!(a, |x| x.ln()),
            Instr::Log10(a) => unary!(a, |x| x.log10()),
            Instr::Sqrt(a) => unary!(a, |x| x.sqrt()),
            Instr::Abs(a) => unary!(a, |x| x.abs()),
            Instr::Sign(a) => unary!(a, |x| sign_f64(x)),
            Instr::Atan2(a, b) => binary!(a, b, |x, y| x.atan2(y)),
            Instr::MulAdd(a, b, c) => ternary!(a, b, c, |x, y, z| x * y + z),
            Instr::MulSub(a, b, c) => ternary!(a, b, c, |x, y, z| x * y - z),
            Instr::SubMul(a, b, c) => ternary!(a, b, c, |x, y, z| z - x * y),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::testutil::{random_expr, Rng};
    use crate::expr::{parse, Resolved};

    fn p(src: &str) -> Expr {
        let r = |n: &str| match n {
            "x" => Ok(Resolved::Var(0)),
            "y" => Ok(Resolved::Var(1)),
            "z" => Ok(Resolved::Var(2)),
            _ => Err(format!("unknown name `{n}`")),
        };
        parse(src, &r).unwrap()
    }

    fn run(tape: &Tape, vars: &[f64]) -> Vec<f64> {
        let mut scratch = vec![f64::NAN; tape.n_slots()];
        let mut out = vec![0.0; tape.n_outputs()];
        tape.eval(vars, &mut scratch, &mut out);
        out
    }

    fn close(a: f64, b: f64) -> bool {
        a == b || (a.is_nan() && b.is_nan()) || (a - b).abs() <= 1e-14 * a.abs().max(b.abs())
    }

    #[test]
    fn instruction_is_small() {
        assert_eq!(std::mem::size_of::<Instr>(), 16);
    }

    #[test]
    fn specialized_instructions() {
        let c = p("x^2 + 100*y");
        let t = Tape::compile(&[c.clone(), c.derivative(0)]);
        assert_eq!(
            t.code,
            [
                Instr::Var(0),
                Instr::Square(0),
                Instr::Var(1),
                Instr::MulC(2, 100.0),
                Instr::Add(1, 3),
                Instr::MulC(0, 2.0),
            ]
        );
        assert_eq!(run(&t, &[3.0, -0.09]), [9.0 - 9.0, 6.0]);
        // x*x written with two separate variable nodes is still a square; x^3 is powi;
        // x^2.5 powf; constants fold into the instruction.
        let t = Tape::compile(&[
            p("x*x"),
            p("x^3"),
            p("x^2.5"),
            p("1 - x"),
            p("x - 1"),
            p("2/x"),
            p("x/2"),
            p("x^y"),
            p("2^x"),
        ]);
        assert_eq!(
            t.code,
            [
                Instr::Var(0),
                Instr::Square(0),
                Instr::Powi(0, 3),
                Instr::Powf(0, 2.5),
                Instr::CSub(0, 1.0),
                Instr::AddC(0, -1.0),
                Instr::CDiv(0, 2.0),
                Instr::DivC(0, 2.0),
                Instr::Var(1),
                Instr::Pow(0, 8),
                Instr::Const(2.0),
                Instr::Pow(10, 0),
            ]
        );
        let x: f64 = 1.7;
        let want = [
            x * x,
            x.powi(3),
            x.powf(2.5),
            1.0 - x,
            x - 1.0,
            2.0 / x,
            x / 2.0,
            x.powf(0.3),
            2f64.powf(x),
        ];
        assert_eq!(run(&t, &[x, 0.3]), want);
    }

    #[test]
    fn single_use_products_fuse_into_add_and_sub() {
        let t = Tape::compile(&[p("x*y + z"), p("x*z - y"), p("y - z*(2*x)")]);
        assert_eq!(
            t.code,
            [
                Instr::Var(0),
                Instr::Var(1),
                Instr::Var(2),
                Instr::MulAdd(0, 1, 2),
                Instr::MulSub(0, 2, 1),
                Instr::MulC(0, 2.0),
                Instr::SubMul(2, 5, 1),
            ]
        );
        let v = [0.3, -1.7, 2.9];
        let want: Vec<f64> = ["x*y + z", "x*z - y", "y - z*(2*x)"]
            .iter()
            .map(|s| p(s).eval(&v))
            .collect();
        assert_eq!(run(&t, &v), want);
        // A product that is also used elsewhere (or is an output) is kept.
        let t = Tape::compile(&[p("x*y + z"), p("x*y")]);
        assert_eq!(
            t.code,
            [
                Instr::Var(0),
                Instr::Var(1),
                Instr::Mul(0, 1),
                Instr::Var(2),
                Instr::Add(2, 3),
            ]
        );
        assert_eq!(run(&t, &v), [0.3 * -1.7 + 2.9, 0.3 * -1.7]);
    }

    #[test]
    fn common_subexpressions_are_shared_across_outputs() {
        // Built separately (no shared nodes), but structurally equal.
        let a = p("sin(x*y) + 1");
        let b = p("sin(y*x) * 2"); // commutative operands are sorted
        let t = Tape::compile(&[a.clone(), b.clone()]);
        // x, y, x*y, sin, +1, *2
        assert_eq!(t.n_instructions(), 6);
        let v = [0.4, 1.3];
        assert_eq!(run(&t, &v), [a.eval(&v), b.eval(&v)]);
    }

    #[test]
    fn constant_and_variable_outputs() {
        let t = Tape::compile(&[
            Expr::constant(3.5),
            Expr::var(2),
            Expr::var(2),
            Expr::constant(3.5),
        ]);
        assert_eq!(t.n_instructions(), 2);
        assert_eq!(t.n_outputs(), 4);
        assert_eq!(t.n_vars(), 3);
        assert_eq!(run(&t, &[0.0, 0.0, -1.25]), [3.5, -1.25, -1.25, 3.5]);
        // No outputs at all.
        let t = Tape::compile(&[]);
        assert_eq!((t.n_instructions(), t.n_outputs(), t.n_vars()), (0, 0, 0));
        assert_eq!(run(&t, &[]), Vec::<f64>::new());
        // Non-finite constants (never folded into `Expr` constants) still work.
        let t = Tape::compile(&[p("1/0"), p("0/0 + x"), p("-(1/0)")]);
        let out = run(&t, &[1.0]);
        assert_eq!(out[0], f64::INFINITY);
        assert!(out[1].is_nan());
        assert_eq!(out[2], f64::NEG_INFINITY);
    }

    #[test]
    fn every_function_matches_eval() {
        let srcs = [
            "sin(x)",
            "cos(x)",
            "tan(x)",
            "asin(x)",
            "acos(x)",
            "atan(x)",
            "sinh(x)",
            "cosh(x)",
            "tanh(x)",
            "exp(x)",
            "ln(x)",
            "log10(x)",
            "sqrt(x)",
            "abs(x)",
            "sign(x)",
            "atan2(x, y)",
            "pow(x, y)",
            "-x",
            "x + y",
            "x - y",
            "x*y",
            "x/y",
            "x^-2",
            "x^16",
            "x^17",
            "x^0.5",
            "sign(x - x)",
            "abs(x - x)",
        ];
        let exprs: Vec<Expr> = srcs.iter().map(|s| p(s)).collect();
        let t = Tape::compile(&exprs);
        for v in [[0.3, 1.7], [-0.8, 0.2], [0.0, -1.0], [2.5, -3.0]] {
            let out = run(&t, &v);
            for ((e, s), o) in exprs.iter().zip(srcs).zip(out) {
                let want = e.eval(&v);
                assert!(
                    o.to_bits() == want.to_bits() || (o.is_nan() && want.is_nan()),
                    "{s} at {v:?}: {o} vs {want}"
                );
            }
        }
    }

    /// Four outputs drawn from one pool, so they share subexpressions, plus their
    /// derivatives (which share with the originals), and their tape.
    fn random_outputs(rng: &mut Rng, round: usize) -> (Vec<Expr>, Tape) {
        let mut pool = Vec::new();
        let mut outs: Vec<Expr> = (0..4)
            .map(|_| random_expr(rng, 3, 4 + round % 3, &mut pool))
            .collect();
        let ds: Vec<Expr> = outs.iter().map(|e| e.derivative(round % 3)).collect();
        outs.extend(ds);
        let t = Tape::compile(&outs);
        (outs, t)
    }

    #[test]
    fn random_expressions_match_eval() {
        let mut rng = Rng::new(1);
        for round in 0..60 {
            let (outs, t) = random_outputs(&mut rng, round);
            let distinct: usize = super::topo(&outs).nodes.len();
            assert!(t.n_instructions() <= distinct);
            for _ in 0..5 {
                let v = [
                    rng.uniform(-2.0, 2.0),
                    rng.uniform(-2.0, 2.0),
                    rng.uniform(-2.0, 2.0),
                ];
                let got = run(&t, &v);
                for (e, g) in outs.iter().zip(got) {
                    let want = e.eval(&v);
                    assert!(close(g, want), "{g} vs {want}");
                }
            }
        }
    }

    /// Lanes evaluate bit for bit as separate scalar evaluations, every instruction kind
    /// included (random expressions use every function), NaN and infinities too.
    #[test]
    fn lanes_match_scalar_evaluations_bit_for_bit() {
        const L: usize = 8;
        let mut rng = Rng::new(7);
        for round in 0..60 {
            let (_, t) = random_outputs(&mut rng, round);
            let mut lanes = [[0.0; 3]; L];
            for (l, v) in lanes.iter_mut().enumerate() {
                for c in v.iter_mut() {
                    *c = rng.uniform(-2.0, 2.0);
                }
                match l {
                    0 => v[0] = 0.0,
                    1 => v[1] = f64::NAN,
                    2 => v[2] = f64::INFINITY,
                    _ => {}
                }
            }
            let mut vars = vec![0.0; 3 * L];
            for (l, v) in lanes.iter().enumerate() {
                for (k, &c) in v.iter().enumerate() {
                    vars[k * L + l] = c;
                }
            }
            let mut scratch = vec![f64::NAN; t.n_slots() * L];
            let mut out = vec![0.0; t.n_outputs() * L];
            t.eval_lanes::<L>(&vars, &mut scratch, &mut out);
            for (l, v) in lanes.iter().enumerate() {
                let want = run(&t, v);
                for (j, w) in want.iter().enumerate() {
                    assert_eq!(
                        out[j * L + l].to_bits(),
                        w.to_bits(),
                        "round {round}, lane {l}, output {j}"
                    );
                }
            }
        }
    }

    /// A tape appended with some variables constant (1, -0 and +0, the identities of the
    /// folds, and infinities, NaN, random values) gives the bits of the original tape run
    /// with those values, every instruction kind included; and the identities do vanish.
    #[test]
    fn appending_with_constants_folds_exactly() {
        let mut rng = Rng::new(11);
        let specials = [1.0, -0.0, 0.0, -1.0, f64::INFINITY, f64::NAN, 2.5];
        for round in 0..80 {
            let (_, t) = random_outputs(&mut rng, round);
            for trial in 0..8 {
                let mut values = [0.0; 3];
                for v in values.iter_mut() {
                    *v = rng.uniform(-2.0, 2.0);
                }
                // One or two variables constant: specials on the first five trials, random
                // values on the rest; from trial 4 on, the other variables specials too.
                let constant = [trial % 3 == 0, trial % 2 == 0, trial % 3 == 1];
                for (k, v) in values.iter_mut().enumerate() {
                    if (constant[k] && trial < 5) || (!constant[k] && trial >= 4) {
                        *v = specials[(round + 2 * k + trial) % specials.len()];
                    }
                }
                let mut b = TapeBuilder::new();
                let vars: Vec<Sym> = (0..3)
                    .map(|k| match constant[k] {
                        true => b.constant(values[k]),
                        false => b.var(k),
                    })
                    .collect();
                let folded_outputs = b.append_with(&t, &vars);
                let folded = b.finish(&folded_outputs);
                let (want, got) = (run(&t, &values), run(&folded, &values));
                for (j, (w, g)) in want.iter().zip(&got).enumerate() {
                    let same = w.to_bits() == g.to_bits() || (w.is_nan() && g.is_nan());
                    assert!(same, "round {round}, trial {trial}, output {j}: {g} vs {w}");
                }
            }
        }
        // x * y + z - w / y with y = 1, z = -0, w = 0: x alone (x - 0 == x).
        let t = Tape::compile(&[
            Expr::var(0) * Expr::var(1) + Expr::var(2) - Expr::var(3) / Expr::var(1)
        ]);
        let mut b = TapeBuilder::new();
        let x = b.var(0);
        let vars = [x, b.constant(1.0), b.constant(-0.0), b.constant(0.0)];
        let out = b.append_with(&t, &vars);
        let folded = b.finish(&out);
        assert_eq!(folded.code, vec![Instr::Var(0)]);
        // x + 0, x - (-0) and 0 * x are not x (nor 0) at x = -0, inf or NaN: they stay.
        for (source, zero) in [("x + y", 0.0), ("x - y", -0.0), ("y * x", 0.0)] {
            let t = Tape::compile(&[p(source)]);
            let mut b = TapeBuilder::new();
            let vars = [b.var(0), b.constant(zero)];
            let out = b.append_with(&t, &vars);
            let folded = b.finish(&out);
            assert_eq!(folded.code.len(), 2, "{source}: {:?}", folded.code);
            for x in [-0.0, 0.0, -1.5, f64::INFINITY] {
                let (want, got) = (run(&t, &[x, zero])[0], run(&folded, &[x, 0.0])[0]);
                assert_eq!(got.to_bits(), want.to_bits(), "{source} at {x}");
            }
        }
    }

    #[test]
    fn heavy_sharing_compiles_linearly() {
        let mut e = Expr::var(0);
        for _ in 0..40 {
            e = (&e * &e.sin()) + &e.cos();
        }
        let d = e.derivative(0);
        let t = Tape::compile(&[e.clone(), d.clone()]);
        assert!(t.n_instructions() < 20 * 41);
        let out = run(&t, &[0.1]);
        assert!(close(out[0], e.eval(&[0.1])) && close(out[1], d.eval(&[0.1])));
    }

    #[test]
    #[should_panic(expected = "tape reads 3 variable slots, got 2")]
    fn too_few_variables_panics() {
        let t = Tape::compile(&[Expr::var(2)]);
        run(&t, &[0.0, 0.0]);
    }

    #[test]
    fn vector_machine_code_is_compiled_on_first_use() {
        // A shape no other test compiles: the code is shared by every tape of one shape.
        let t = Tape::compile(&[p("(x * y + 1) / (x - 7) - y * y * y")]);
        let Some(native) = &t.native else {
            return; // no machine code on this host or with BEAD_JIT=0
        };
        let fresh = matches!(t.status, NativeStatus::Compiled { shared: false, .. });
        // A single evaluation does not compile the vector function.
        let mut scratch = vec![0.0; t.n_slots() * 16];
        t.eval(&[2.0, 3.0], &mut scratch, &mut [0.0]);
        if fresh {
            assert!(!native.vector_asked_for());
        }
        let vars: Vec<f64> = (0..32).map(f64::from).collect();
        let mut out = [0.0; 16];
        t.eval_lanes::<16>(&vars, &mut scratch, &mut out);
        assert!(native.vector_asked_for());
        for (l, o) in out.iter().enumerate() {
            let (x, y) = (vars[l], vars[16 + l]);
            let want = (x * y + 1.0) / (x - 7.0) - y * y * y;
            assert_eq!(o.to_bits(), want.to_bits(), "lane {l}");
        }
    }

    #[test]
    #[should_panic]
    fn too_small_scratch_panics() {
        let t = Tape::compile(&[p("x + y")]);
        t.eval(&[1.0, 2.0], &mut [0.0; 2], &mut [0.0]);
    }
}
