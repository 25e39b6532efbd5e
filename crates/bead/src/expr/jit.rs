//! Machine code for tapes, with Cranelift.
//!
//! [`super::Tape::compile`] hands its instructions to [`compile`], which emits up to two
//! native functions per tape, of one signature:
//!
//! ```text
//! extern "C" fn(vars: *const f64, consts: *const f64, out: *mut f64)
//! ```
//!
//! The first evaluates one set of variables (the scalar evaluation, a single run's step); the
//! second [`VECTOR_LANES`] members laid out as [`super::Tape::eval_lanes`] lays them out (slot
//! k of lane l at `k * VECTOR_LANES + l`: a sweep's blocks), eight lanes per iteration as four
//! independent chains of `f64x2` vectors (two lanes per iteration for a tape with function
//! calls or longer than [`MAX_CHAINED_INSTRUCTIONS`], see [`vector_width`]), each packed IEEE
//! operation rounding each lane as the scalar one does, function calls made lane by lane.
//! Both lane counts are fixed when compiling, so that every variable and output is addressed
//! by an immediate offset (no address arithmetic per slot); other lane counts are
//! interpreted (the same bits). The first is compiled with the tape
//! (its time is the tape's compile time); the second on its first use (a sweep's first
//! block), so that a single run, which never evaluates lanes, does not pay for it. Each
//! computing SSA instruction becomes one Cranelift value (kept in registers, spilled by the
//! register allocator when needed; variables and constants are loaded where they are used):
//! no scratch array; where the tape's order would hold more values
//! than the registers, the instructions are emitted in one that holds fewer
//! ([`emission_order`]). The constants are not baked into the code but read
//! from `consts` (the tape's constants in instruction order, exact bits), so that tapes that
//! differ only by their constants — a sweep's members, whose parameters are constants of the
//! expressions — share their compiled functions (a process-wide cache of weak references keyed
//! by the tape's shape).
//!
//! **Same bits as the interpreter**: every IEEE basic operation is one Cranelift instruction
//! (`fadd`, `fsub`, `fmul`, `fdiv`, `fneg`, `fabs`, `sqrt`) with the interpreter's operand
//! order; fused products (`a*b + c`) are an `fmul` then an `fadd`, never an `fma` (Cranelift
//! only emits `fma` for its own `fma` instruction and does not contract); every other function
//! is a call of an `extern "C"` wrapper around exactly the Rust expression the interpreter
//! evaluates (`x.sin()`, `x.powi(n)` with `n` passed at run time, ...), so both reach the same
//! libm routine. The optimizer is off (`opt_level = none`): the tape is already CSE'd and
//! constant-folded, and no rewrite (e.g. `(-x)*(-y) -> x*y`, which changes a NaN's sign) can
//! touch the arithmetic.
//!
//! Anything that goes wrong (a host Cranelift does not support, a Cranelift error, a tape longer
//! than [`MAX_NATIVE_INSTRUCTIONS`]) leaves the tape to the interpreter with a note
//! ([`NativeStatus::Fallback`]): never a wrong number, never a panic.

use std::cell::Cell;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex, OnceLock, PoisonError, Weak};
use std::time::{Duration, Instant};

use super::tape::Instr;

/// The longest tape compiled to machine code. Cranelift's compile time grows with the function
/// (register allocation over one straight-line block of every live value), about 1-2 us per
/// instruction: 200k instructions is ~0.3 s, beyond which the compile can cost more than a
/// run saves, and a single function that large risks the code generator's own limits. Longer
/// tapes are interpreted (with a note).
pub const MAX_NATIVE_INSTRUCTIONS: usize = 200_000;

/// How a tape is evaluated: see [`super::Tape::native_status`].
#[derive(Clone, Debug, PartialEq)]
pub enum NativeStatus {
    /// Machine code. `time` is what compiling took (zero-ish when `shared`: the function was
    /// already compiled for a tape of the same shape, e.g. by another member of a sweep).
    Compiled {
        /// Compile time of this tape (code generation and linking).
        time: Duration,
        /// Whether the code was reused from an identically shaped tape.
        shared: bool,
    },
    /// Nothing to compile: the tape has no outputs.
    Empty,
    /// Interpreted because machine code is switched off ([`set_jit_enabled`], `BEAD_JIT=0`,
    /// `--no-jit`).
    Disabled,
    /// Interpreted because the tape could not be compiled; the note says why.
    Fallback(String),
}

/// How a set of tapes (a [`crate::model::System`]'s) is evaluated, for `bead check`:
/// see [`crate::model::System::machine_code`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NativeSummary {
    /// Tapes with machine code.
    pub compiled: usize,
    /// Of those, how many reused the code of an identically shaped tape.
    pub shared: usize,
    /// Instructions of the tapes with machine code.
    pub instructions: usize,
    /// Total compile time of those tapes.
    pub compile_time: Duration,
    /// Tapes interpreted because machine code is switched off.
    pub disabled: usize,
    /// Tapes interpreted because they could not be compiled, with why.
    pub fallbacks: Vec<String>,
}

impl NativeSummary {
    /// Count one tape (tapes without outputs count nowhere).
    pub fn add(&mut self, tape: &super::Tape) {
        match tape.native_status() {
            NativeStatus::Compiled { time, shared } => {
                self.compiled += 1;
                self.shared += usize::from(*shared);
                self.instructions += tape.n_instructions();
                self.compile_time += *time;
            }
            NativeStatus::Empty => {}
            NativeStatus::Disabled => self.disabled += 1,
            NativeStatus::Fallback(why) => self.fallbacks.push(why.clone()),
        }
    }
}

/// One line, e.g. `6 tapes, 41 instructions, compiled in 1.8 ms`, or `off (6 tapes
/// interpreted)`, with the fallbacks' notes.
impl std::fmt::Display for NativeSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let tapes = |n: usize| if n == 1 { "tape" } else { "tapes" };
        if self.compiled > 0 {
            write!(
                f,
                "{} {}, {} instructions, compiled in {:.1} ms",
                self.compiled,
                tapes(self.compiled),
                self.instructions,
                self.compile_time.as_secs_f64() * 1e3
            )?;
            if self.shared > 0 {
                write!(f, " ({} shared with identical tapes)", self.shared)?;
            }
        } else if self.disabled > 0 {
            write!(
                f,
                "off ({} {} interpreted)",
                self.disabled,
                tapes(self.disabled)
            )?;
        } else if self.fallbacks.is_empty() {
            write!(f, "none needed")?;
        }
        if self.compiled > 0 && self.disabled > 0 {
            write!(
                f,
                "; {} {} interpreted (switched off)",
                self.disabled,
                tapes(self.disabled)
            )?;
        }
        if !self.fallbacks.is_empty() {
            if self.compiled > 0 || self.disabled > 0 {
                write!(f, "; ")?;
            }
            let n = self.fallbacks.len();
            write!(f, "{n} {} interpreted: ", tapes(n))?;
            let mut notes = self.fallbacks.clone();
            notes.dedup();
            write!(f, "{}", notes.join("; "))?;
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// The switch

/// 0: not read yet, 1: on, 2: off.
static ENABLED: AtomicU8 = AtomicU8::new(0);

thread_local! {
    static OVERRIDE: Cell<Option<bool>> = const { Cell::new(None) };
    static FORCE_FAILURE: Cell<bool> = const { Cell::new(false) };
}

/// Whether tapes compiled from now on (on this thread) get machine code. On by default where
/// the JIT exists; the environment variable `BEAD_JIT=0` (or `off`, `false`), read once,
/// switches it off; [`set_jit_enabled`] sets it for the process, [`with_jit`] for one thread
/// and one closure.
pub fn jit_enabled() -> bool {
    if let Some(on) = OVERRIDE.with(Cell::get) {
        return on;
    }
    match ENABLED.load(Ordering::Relaxed) {
        1 => true,
        2 => false,
        _ => {
            let on = !matches!(
                std::env::var("BEAD_JIT").as_deref().map(str::trim),
                Ok("0" | "off" | "false" | "no")
            );
            // Only the first reader decides; a concurrent set_jit_enabled wins.
            let _ = ENABLED.compare_exchange(
                0,
                if on { 1 } else { 2 },
                Ordering::Relaxed,
                Ordering::Relaxed,
            );
            ENABLED.load(Ordering::Relaxed) == 1
        }
    }
}

/// Switch machine code on or off for the tapes compiled from now on, process-wide (tapes
/// already compiled keep what they have). The CLI's `--no-jit` calls this with `false`.
pub fn set_jit_enabled(on: bool) {
    ENABLED.store(if on { 1 } else { 2 }, Ordering::Relaxed);
}

/// Run `f` with machine code switched on or off for the tapes compiled by this thread inside
/// it (over the process-wide setting), e.g. to load one scene both ways in one test.
pub fn with_jit<R>(on: bool, f: impl FnOnce() -> R) -> R {
    struct Restore(Option<bool>);
    impl Drop for Restore {
        fn drop(&mut self) {
            OVERRIDE.with(|o| o.set(self.0));
        }
    }
    let _restore = Restore(OVERRIDE.with(|o| o.replace(Some(on))));
    f()
}

/// Test hook: inside `f`, every compile on this thread fails (as a Cranelift error would), so
/// that the fallback can be tested.
#[doc(hidden)]
pub fn with_forced_jit_failure<R>(f: impl FnOnce() -> R) -> R {
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            FORCE_FAILURE.with(|o| o.set(self.0));
        }
    }
    let _restore = Restore(FORCE_FAILURE.with(|o| o.replace(true)));
    f()
}

// ---------------------------------------------------------------------------------------------
// Compiled code

type TapeFn = unsafe extern "C" fn(*const f64, *const f64, *mut f64);

/// The lane count of the vector machine code (the sweep's blocks: `simulate::lanes::LANES`).
pub const VECTOR_LANES: usize = 16;

/// The longest tape whose vector function runs four `f64x2` chains per iteration.
const MAX_CHAINED_INSTRUCTIONS: usize = 4096;

/// Lanes per iteration of a tape's vector function (see [`codegen::build`]'s `body`): eight,
/// as four independent `f64x2` chains, for a tape of arithmetic alone (no function calls)
/// of up to [`MAX_CHAINED_INSTRUCTIONS`] instructions; else two. Such a tape is mostly one
/// chain of dependent operations (an RK4 step's stages wait on each other, a division on its
/// operands), whose latency the other chains fill: the article's fused step in the sweep
/// lanes ran 8-18% faster than with one chain. A call (sin, pow, ...) costs more than the
/// arithmetic around it and, clobbering every vector register, spills what the other chains
/// hold: with calls, four chains measured 2-6% slower to 2% faster on the shipped scenes'
/// sweeps, and compiled 2-3x as long. A long tape has independent work of its own,
/// and its compile time (about proportional to the operations emitted) would grow fourfold.
fn vector_width(code: &[Instr]) -> i64 {
    if code.len() <= MAX_CHAINED_INSTRUCTIONS && !code.iter().any(|&ins| is_call(ins)) {
        8
    } else {
        2
    }
}

/// Vector registers the machine code can keep values in (x86-64 has 16; a few go to the
/// loads and splats of operands; aarch64 has 32).
#[cfg(not(target_arch = "wasm32"))]
const VALUE_REGISTERS: usize = if cfg!(target_arch = "aarch64") {
    28
} else {
    12
};

/// The order in which the machine code computes `code`'s instructions (every one but the
/// `Var`s and `Const`s, which it loads where they are used) for `chains` interleaved chains
/// of lanes. The tape's own order where its values fit in the registers; else a topological
/// order that keeps fewer values live, so that fewer are spilled to the stack. Greedy list
/// scheduling: of the instructions whose operands are computed, the one that is the last use
/// of the most operands (it frees their registers) if any is, else the first in tape order;
/// ties go to tape order. Each instruction keeps its operands and their order, so the order
/// changes no bit. RK4's update `x0 + h/6 (k1 + 2 k2 + 2 k3 + k4)` is where it pays: each
/// partial sum is taken as soon as its stage is, instead of every stage's slope waiting for
/// the end (the article's implicit step: 16 values live at most in the tape's order, 9 in
/// this one; four chains of lanes hold four times as many).
#[cfg(not(target_arch = "wasm32"))]
pub(super) fn emission_order(code: &[Instr], chains: usize) -> Vec<usize> {
    let n = code.len();
    let tape_order: Vec<usize> = (0..n).filter(|&s| is_computed(code[s])).collect();
    if most_live(code, &tape_order) * chains <= VALUE_REGISTERS {
        return tape_order;
    }
    least_live_order(code)
}

/// The greedy order of [`emission_order`].
#[cfg(not(target_arch = "wasm32"))]
fn least_live_order(code: &[Instr]) -> Vec<usize> {
    let n = code.len();
    let operands: Vec<Vec<usize>> = (0..n)
        .map(|i| computed_operands(code, i).collect())
        .collect();
    let mut users: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (i, o) in operands.iter().enumerate() {
        for &s in o {
            users[s].push(i);
        }
    }
    // Users of a slot not yet emitted; operands of an instruction not yet computed; operands
    // of which it is the last user left.
    let mut remaining: Vec<usize> = users.iter().map(Vec::len).collect();
    let mut waiting: Vec<usize> = operands.iter().map(Vec::len).collect();
    let mut frees = vec![0usize; n];
    for users in &users {
        if let [only] = users[..] {
            frees[only] += 1;
        }
    }
    // The ready instructions by how many operands they free (at most 3), in tape order.
    let mut ready: [std::collections::BTreeSet<usize>; 4] = Default::default();
    for i in (0..n).filter(|&i| is_computed(code[i]) && waiting[i] == 0) {
        ready[frees[i]].insert(i);
    }
    let mut emitted = vec![false; n];
    let mut order = Vec::with_capacity(n);
    while let Some(bucket) = (0..4).rev().find(|&k| !ready[k].is_empty()) {
        let i = ready[bucket].pop_first().expect("not empty");
        emitted[i] = true;
        order.push(i);
        for &s in &operands[i] {
            remaining[s] -= 1;
            if remaining[s] == 1 {
                // Its one user left now frees it.
                let last = *users[s].iter().find(|&&u| !emitted[u]).expect("one left");
                if waiting[last] == 0 && ready[frees[last]].remove(&last) {
                    ready[frees[last] + 1].insert(last);
                }
                frees[last] += 1;
            }
        }
        for &u in &users[i] {
            waiting[u] -= 1;
            if waiting[u] == 0 {
                ready[frees[u]].insert(u);
            }
        }
    }
    order
}

/// Whether the machine code computes `ins` (rather than loading it where it is used: a
/// `Var` or a `Const`).
#[cfg(not(target_arch = "wasm32"))]
fn is_computed(ins: Instr) -> bool {
    !matches!(ins, Instr::Var(_) | Instr::Const(_))
}

/// The distinct computed operands of instruction `i`.
#[cfg(not(target_arch = "wasm32"))]
fn computed_operands(code: &[Instr], i: usize) -> impl Iterator<Item = usize> {
    let mut distinct = [0; 3];
    let mut count = 0;
    for s in code[i].operands().into_iter().flatten().map(|s| s as usize) {
        if is_computed(code[s]) && !distinct[..count].contains(&s) {
            distinct[count] = s;
            count += 1;
        }
    }
    distinct.into_iter().take(count)
}

/// [`most_live`] in the tape's order and in the order of four chains (for tests).
#[cfg(test)]
pub(super) fn most_live_values(code: &[Instr]) -> (usize, usize) {
    let tape_order: Vec<usize> = (0..code.len()).filter(|&s| is_computed(code[s])).collect();
    let emitted = emission_order(code, 4);
    (most_live(code, &tape_order), most_live(code, &emitted))
}

/// The most values the machine code holds at once (computed and still to be read) when
/// it computes `code` in `order`.
#[cfg(not(target_arch = "wasm32"))]
fn most_live(code: &[Instr], order: &[usize]) -> usize {
    let distinct = |i: usize| computed_operands(code, i);
    let mut reads = vec![0usize; code.len()];
    for &i in order {
        for s in distinct(i) {
            reads[s] += 1;
        }
    }
    let (mut live, mut most) = (0usize, 0usize);
    for &i in order {
        for s in distinct(i) {
            reads[s] -= 1;
            live -= usize::from(reads[s] == 0);
        }
        live += usize::from(reads[i] > 0);
        most = most.max(live);
    }
    most
}

/// Whether the machine code computes `ins` by calling a function (see `codegen::body`).
fn is_call(ins: Instr) -> bool {
    use Instr::*;
    match ins {
        Powi(..) | Powf(..) | Pow(..) | Sin(_) | Cos(_) | Tan(_) | Asin(_) | Acos(_) | Atan(_)
        | Sinh(_) | Cosh(_) | Tanh(_) | Exp(_) | Ln(_) | Log10(_) | Sign(_) | Atan2(..) => true,
        Var(_) | Const(_) | Neg(_) | Add(..) | Sub(..) | Mul(..) | Div(..) | AddC(..)
        | CSub(..) | MulC(..) | DivC(..) | CDiv(..) | Square(_) | Sqrt(_) | Abs(_) | MulAdd(..)
        | MulSub(..) | SubMul(..) => false,
    }
}

/// One compiled function and the module that owns its memory, freed with it.
pub(super) struct Code {
    func: TapeFn,
    /// Owns the code's memory. Behind a mutex only to be `Sync`: it is never used after
    /// compiling except to free the memory.
    #[cfg(not(target_arch = "wasm32"))]
    module: Mutex<Option<cranelift_jit::JITModule>>,
}

impl Drop for Code {
    fn drop(&mut self) {
        #[cfg(not(target_arch = "wasm32"))]
        if let Some(module) = self
            .module
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner)
            .take()
        {
            // SAFETY: the last reference to this code is going away: no tape can call it
            // any more, and a call in progress would hold a reference.
            #[allow(unsafe_code)]
            unsafe {
                module.free_memory()
            };
        }
    }
}

/// One tape's machine code, freed when the last tape holding it is dropped.
pub(super) struct Native {
    /// One lane
    scalar: Code,
    /// [`VECTOR_LANES`] lanes in `f64x2` vectors ([`vector_width`]), compiled on first use
    /// (a sweep's first block), so that a single run never pays for it; `None` if that
    /// compile failed (the lanes are then interpreted, with the same bits).
    vector: OnceLock<Option<Code>>,
    /// What the vector function is compiled from.
    code: Box<[Instr]>,
    outputs: Box<[u32]>,
    /// What the code reads and writes: one more than the largest variable slot, the number
    /// of constants and outputs.
    n_vars: usize,
    n_consts: usize,
    n_outputs: usize,
}

impl std::fmt::Debug for Native {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Native")
    }
}

impl Native {
    /// Whether the code can evaluate `lanes` lanes at once (1 or [`VECTOR_LANES`]).
    #[inline]
    pub(super) fn runs(lanes: usize) -> bool {
        lanes == 1 || lanes == VECTOR_LANES
    }

    /// Run the code over `lanes` lanes (see [`Self::runs`]): `vars` holds at least `n_vars *
    /// lanes` values (slot k of lane l at `k * lanes + l`), `out` exactly `n_outputs *
    /// lanes`, `consts` the constants ([`constants`]) of a tape of the shape this code was
    /// compiled for. False, nothing written, when there is no code for that many lanes
    /// (the vector function failed to compile): the caller interprets.
    ///
    /// # Panics
    /// If a length does not match what the code was compiled for.
    #[inline]
    pub(super) fn run(&self, vars: &[f64], consts: &[f64], out: &mut [f64], lanes: usize) -> bool {
        assert!(
            Self::runs(lanes)
                && vars.len() >= self.n_vars * lanes
                && out.len() == self.n_outputs * lanes
                && consts.len() == self.n_consts,
            "machine code called with the wrong lengths"
        );
        let func = if lanes == 1 {
            self.scalar.func
        } else {
            match self.vector() {
                Some(code) => code.func,
                None => return false,
            }
        };
        // SAFETY: the code reads variable slots `< n_vars` of `lanes` lanes, constants
        // `< n_consts`, and writes `n_outputs` outputs of `lanes` lanes (all checked above),
        // for the lane count it was compiled for (`scalar`: 1, `vector`: VECTOR_LANES).
        #[allow(unsafe_code)]
        unsafe {
            func(vars.as_ptr(), consts.as_ptr(), out.as_mut_ptr())
        };
        true
    }

    /// The vector function, compiled the first time it is asked for.
    #[cold]
    #[inline(never)]
    fn compile_vector(&self) -> Option<Code> {
        codegen::build(&self.code, &self.outputs, vector_width(&self.code)).ok()
    }

    /// Whether the vector function has been asked for (compiled or failed).
    #[cfg(test)]
    pub(super) fn vector_asked_for(&self) -> bool {
        self.vector.get().is_some()
    }

    #[inline]
    fn vector(&self) -> Option<&Code> {
        self.vector.get_or_init(|| self.compile_vector()).as_ref()
    }
}

/// The constants the compiled code reads, in instruction order.
pub(super) fn constants(code: &[Instr]) -> Vec<f64> {
    code.iter().filter_map(|i| i.constant()).collect()
}

/// The tape's shape: everything but the constants' values (which the code reads at run time).
fn shape(code: &[Instr], outputs: &[u32]) -> Vec<u32> {
    let mut key = Vec::with_capacity(4 * code.len() + outputs.len() + 1);
    for ins in code {
        key.extend(ins.shape());
    }
    key.push(u32::MAX);
    key.extend_from_slice(outputs);
    key
}

type Cache = Mutex<HashMap<Vec<u32>, Weak<Native>>>;

fn cache() -> &'static Cache {
    static CACHE: OnceLock<Cache> = OnceLock::new();
    CACHE.get_or_init(Default::default)
}

/// How many of the most recently compiled functions stay alive with no tape holding them.
const KEPT_RECENT: usize = 16;

/// Keep `native` alive among the [`KEPT_RECENT`] most recently compiled functions: a sweep
/// whose members each load their equations again, one after another (each dropping its
/// tapes before the next compiles the same shapes), compiles each shape once, not once per
/// member. Bounded: a few functions' code.
fn keep_recent(native: &Arc<Native>) {
    static RECENT: OnceLock<Mutex<std::collections::VecDeque<Arc<Native>>>> = OnceLock::new();
    let mut recent = RECENT
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(PoisonError::into_inner);
    if recent.len() == KEPT_RECENT {
        recent.pop_front();
    }
    recent.push_back(Arc::clone(native));
}

/// Compile `code` (or reuse the code of a tape of the same shape), or say why not.
pub(super) fn compile(code: &[Instr], outputs: &[u32]) -> (Option<Arc<Native>>, NativeStatus) {
    if outputs.is_empty() {
        return (None, NativeStatus::Empty);
    }
    if !jit_enabled() {
        return (None, NativeStatus::Disabled);
    }
    if cfg!(target_arch = "wasm32") {
        // No code generation inside wasm32 (and no clock to time it by).
        return (
            None,
            NativeStatus::Fallback(
                "no machine code on wasm32 (the interpreter evaluates the tapes)".into(),
            ),
        );
    }
    if FORCE_FAILURE.with(Cell::get) {
        return (
            None,
            NativeStatus::Fallback("compile failure forced by a test".into()),
        );
    }
    if code.len() > MAX_NATIVE_INSTRUCTIONS {
        return (
            None,
            NativeStatus::Fallback(format!(
                "{} instructions, more than the {MAX_NATIVE_INSTRUCTIONS} compiled to machine code",
                code.len()
            )),
        );
    }
    let start = Instant::now();
    let key = shape(code, outputs);
    if let Some(native) = cache()
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .get(&key)
        .and_then(Weak::upgrade)
    {
        return (
            Some(native),
            NativeStatus::Compiled {
                time: start.elapsed(),
                shared: true,
            },
        );
    }
    match codegen::build(code, outputs, 1) {
        Ok(scalar) => {
            let native = Arc::new(Native {
                scalar,
                vector: OnceLock::new(),
                code: code.into(),
                outputs: outputs.into(),
                n_vars: super::tape::n_vars(code),
                n_consts: constants(code).len(),
                n_outputs: outputs.len(),
            });
            keep_recent(&native);
            let mut map = cache().lock().unwrap_or_else(PoisonError::into_inner);
            if map.len() >= 256 && map.len().is_power_of_two() {
                map.retain(|_, w| w.strong_count() > 0);
            }
            map.insert(key, Arc::downgrade(&native));
            (
                Some(native),
                NativeStatus::Compiled {
                    time: start.elapsed(),
                    shared: false,
                },
            )
        }
        Err(why) => (None, NativeStatus::Fallback(why)),
    }
}

#[cfg(target_arch = "wasm32")]
mod codegen {
    use super::{Code, Instr};
    pub(super) fn build(_: &[Instr], _: &[u32], _: i64) -> Result<Code, String> {
        Err("no machine code on wasm32 (the interpreter evaluates the tapes)".into())
    }
}

#[cfg(not(target_arch = "wasm32"))]
mod codegen {
    use std::sync::{Mutex, OnceLock};

    use cranelift_codegen::ir::condcodes::IntCC;
    use cranelift_codegen::ir::{
        types, AbiParam, InstBuilder, MemFlagsData, SigRef, Signature, UserFuncName, Value,
    };
    use cranelift_codegen::isa::OwnedTargetIsa;
    use cranelift_codegen::settings::{self, Configurable};
    use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext};
    use cranelift_jit::{JITBuilder, JITModule};
    use cranelift_module::{Linkage, Module};

    use super::{Code, Instr, TapeFn};
    use crate::expr::ast::sign_f64;

    /// A slot loaded where it is used (at each use in the vector code, at the first in the
    /// scalar code): variable k, or the constant at this byte offset.
    #[derive(Clone, Copy)]
    enum Deferred {
        Var(u32),
        Const(i32),
    }

    // The functions the code calls: exactly the interpreter's Rust expressions, so that both
    // reach the same routines (libm's sin, compiler-rt's __powidf2 with a run-time n, ...).
    extern "C" fn bead_sin(x: f64) -> f64 {
        x.sin()
    }
    extern "C" fn bead_cos(x: f64) -> f64 {
        x.cos()
    }
    extern "C" fn bead_tan(x: f64) -> f64 {
        x.tan()
    }
    extern "C" fn bead_asin(x: f64) -> f64 {
        x.asin()
    }
    extern "C" fn bead_acos(x: f64) -> f64 {
        x.acos()
    }
    extern "C" fn bead_atan(x: f64) -> f64 {
        x.atan()
    }
    extern "C" fn bead_sinh(x: f64) -> f64 {
        x.sinh()
    }
    extern "C" fn bead_cosh(x: f64) -> f64 {
        x.cosh()
    }
    extern "C" fn bead_tanh(x: f64) -> f64 {
        x.tanh()
    }
    extern "C" fn bead_exp(x: f64) -> f64 {
        x.exp()
    }
    extern "C" fn bead_ln(x: f64) -> f64 {
        x.ln()
    }
    extern "C" fn bead_log10(x: f64) -> f64 {
        x.log10()
    }
    extern "C" fn bead_sign(x: f64) -> f64 {
        sign_f64(x)
    }
    extern "C" fn bead_powi(x: f64, n: i32) -> f64 {
        x.powi(n)
    }
    extern "C" fn bead_powf(x: f64, y: f64) -> f64 {
        x.powf(y)
    }
    extern "C" fn bead_atan2(y: f64, x: f64) -> f64 {
        y.atan2(x)
    }

    /// The host's ISA, built once (or why there is none).
    fn host_isa() -> Result<OwnedTargetIsa, String> {
        static ISA: OnceLock<Result<OwnedTargetIsa, String>> = OnceLock::new();
        ISA.get_or_init(|| {
            let mut flags = settings::builder();
            let set = |flags: &mut settings::Builder, k: &str, v: &str| {
                flags
                    .set(k, v)
                    .map_err(|e| format!("Cranelift setting {k}={v}: {e}"))
            };
            // No optimizer: nothing may rewrite the arithmetic (see the module's doc).
            set(&mut flags, "opt_level", "none")?;
            set(&mut flags, "use_colocated_libcalls", "false")?;
            set(&mut flags, "is_pic", "false")?;
            let verify = if cfg!(debug_assertions) {
                "true"
            } else {
                "false"
            };
            set(&mut flags, "enable_verifier", verify)?;
            let isa = cranelift_native::builder()
                .map_err(|e| format!("host not supported by Cranelift: {e}"))?;
            isa.finish(settings::Flags::new(flags))
                .map_err(|e| format!("Cranelift ISA: {e}"))
        })
        .clone()
    }

    /// The function of `code` for `width` lanes per iteration (1: one lane; 2, 4, 8: the
    /// [`super::VECTOR_LANES`] lanes in 1, 2 or 4 chains of `f64x2`, see [`body`]).
    pub(super) fn build(code: &[Instr], outputs: &[u32], width: i64) -> Result<Code, String> {
        let isa = host_isa()?;
        let mut module = JITModule::new(JITBuilder::with_isa(
            isa,
            cranelift_module::default_libcall_names(),
        ));
        let ptr = module.target_config().pointer_type();
        let mut sig = module.make_signature();
        for _ in 0..3 {
            sig.params.push(AbiParam::new(ptr));
        }
        let name = if width == 1 { "tape" } else { "tape_lanes" };
        let id = module
            .declare_function(name, Linkage::Local, &sig)
            .map_err(|e| format!("Cranelift: {e}"))?;
        let mut ctx = module.make_context();
        ctx.func.signature = sig;
        ctx.func.name = UserFuncName::user(0, id.as_u32());
        let mut fctx = FunctionBuilderContext::new();
        let n_consts = body(
            FunctionBuilder::new(&mut ctx.func, &mut fctx),
            code,
            outputs,
            width,
            ptr,
            module.target_config(),
        )?;
        debug_assert_eq!(n_consts, super::constants(code).len());
        module
            .define_function(id, &mut ctx)
            .map_err(|e| format!("Cranelift: {e:?}"))?;
        module.clear_context(&mut ctx);
        module
            .finalize_definitions()
            .map_err(|e| format!("Cranelift: {e}"))?;
        // SAFETY: the function was declared with this signature (three pointer-sized integer
        // parameters, no result) in the host's default calling convention, which is the C
        // one on every host Cranelift supports.
        #[allow(unsafe_code)]
        let func =
            unsafe { std::mem::transmute::<*const u8, TapeFn>(module.get_finalized_function(id)) };
        Ok(Code {
            func,
            module: Mutex::new(Some(module)),
        })
    }

    /// The function's body: for `width` 1 one lane in scalar `f64`; for `width` 2k a loop over
    /// [`VECTOR_LANES`] lanes, 2k per iteration as k independent `f64x2` chains (each IEEE
    /// operation on two lanes at once, which rounds each lane as the scalar operation does;
    /// calls are made lane by lane). The chains give the processor independent work to
    /// overlap, where one chain's operations wait on each other (a division's latency is many
    /// of its cycles). Slot k of the lane is at byte `8 k lanes` from the lane's first: an
    /// immediate offset. Returns the number of constants read.
    fn body(
        mut b: FunctionBuilder,
        code: &[Instr],
        outputs: &[u32],
        width: i64,
        ptr: types::Type,
        config: cranelift_codegen::isa::TargetFrontendConfig,
    ) -> Result<usize, String> {
        let call_conv = config.default_call_conv;
        let ty = if width == 1 { types::F64 } else { types::F64X2 };
        // Independent chains per iteration, and the bytes between them.
        let chains = if width == 1 { 1 } else { (width / 2) as usize };
        let chain_offset = |c: usize| 16 * c as i32;
        let signature = |params: &[types::Type]| {
            let mut s = Signature::new(call_conv);
            s.params.extend(params.iter().map(|&t| AbiParam::new(t)));
            s.returns.push(AbiParam::new(types::F64));
            s
        };
        let sig1 = b.import_signature(signature(&[types::F64]));
        let sig2 = b.import_signature(signature(&[types::F64, types::F64]));
        let sigi = b.import_signature(signature(&[types::F64, types::I32]));

        let entry = b.create_block();
        b.append_block_params_for_function_params(entry);
        let body = b.create_block();
        let lane = b.append_block_param(body, ptr);
        let exit = b.create_block();

        b.switch_to_block(entry);
        let &[vars, consts, out] = b.block_params(entry) else {
            return Err("Cranelift: unexpected parameters".into());
        };
        let lanes: i64 = if width == 1 {
            1
        } else {
            super::VECTOR_LANES as i64
        };
        if width < 1 || lanes % width != 0 {
            return Err(format!("{lanes} lanes are not whole iterations of {width}"));
        }
        // Bytes between consecutive slots of one lane, and the offset of slot k.
        let stride = 8 * lanes;
        let offset_of = |k: i64| {
            i32::try_from(k * stride).map_err(|_| "too many slots for one function".to_string())
        };
        let zero = b.ins().iconst(ptr, 0);
        b.ins().jump(body, &[zero.into()]);

        b.switch_to_block(body);
        let (vars_l, out_l) = if width == 1 {
            (vars, out)
        } else {
            (b.ins().iadd(vars, lane), b.ins().iadd(out, lane))
        };
        // Lanes are 8-byte aligned only: no alignment promised for f64x2.
        let flags = if width == 1 {
            MemFlagsData::trusted()
        } else {
            MemFlagsData::new().with_notrap()
        };
        let mut n_const: i64 = 0;
        // Slot values, one per chain, in the order of `emission_order`; a variable or
        // constant slot is loaded where it is used, not at its place in the tape (which lists
        // them first), so that it does not occupy a register, or a spill slot, from the top.
        let mut v: Vec<Option<Vec<Value>>> = Vec::with_capacity(code.len());
        let mut deferred: Vec<Option<Deferred>> = vec![None; code.len()];
        // The output indices of each slot: stored as soon as the slot is computed, so that a
        // value computed early does not stay live to the end.
        let mut stored_as: Vec<Vec<usize>> = vec![Vec::new(); code.len()];
        for (j, &s) in outputs.iter().enumerate() {
            stored_as[s as usize].push(j);
        }
        // The constant at byte `offset`, in every lane (`spread`) or as one scalar.
        let load_const = |b: &mut FunctionBuilder, offset: i32, spread: bool| -> Value {
            let c = b
                .ins()
                .load(types::F64, MemFlagsData::trusted(), consts, offset);
            if width == 1 || !spread {
                c
            } else {
                b.ins().splat(ty, c)
            }
        };
        let load_deferred =
            |b: &mut FunctionBuilder, what: Deferred| -> Result<Vec<Value>, String> {
                Ok(match what {
                    Deferred::Var(k) => {
                        let offset = offset_of(i64::from(k))?;
                        (0..chains)
                            .map(|c| b.ins().load(ty, flags, vars_l, offset + chain_offset(c)))
                            .collect()
                    }
                    Deferred::Const(offset) => vec![load_const(b, offset, true); chains],
                })
            };
        // `v` itself, which instruction selection cannot fold into its user as a load.
        let in_register = |b: &mut FunctionBuilder, v: Value| {
            let ty = b.func.dfg.value_type(v);
            b.ins().bitcast(ty, MemFlagsData::new(), v)
        };
        let store = |b: &mut FunctionBuilder, value: &[Value], j: usize| -> Result<(), String> {
            let offset = offset_of(i64::try_from(j).map_err(|e| e.to_string())?)?;
            for (c, &value) in value.iter().enumerate() {
                b.ins().store(flags, value, out_l, offset + chain_offset(c));
            }
            Ok(())
        };
        // f(args) of every lane of a chain: one call per lane, the results put back together.
        let call = |b: &mut FunctionBuilder, sig: SigRef, f: usize, args: &[Value]| {
            let addr = b.ins().iconst(ptr, f as i64);
            if width == 1 {
                let inst = b.ins().call_indirect(sig, addr, args);
                return b.inst_results(inst)[0];
            }
            let mut result: Option<Value> = None;
            for l in 0..2u8 {
                let lane_args: Vec<Value> = args
                    .iter()
                    .map(|&a| {
                        if b.func.dfg.value_type(a) == types::F64X2 {
                            b.ins().extractlane(a, l)
                        } else {
                            a
                        }
                    })
                    .collect();
                let inst = b.ins().call_indirect(sig, addr, &lane_args);
                let r = b.inst_results(inst)[0];
                result = Some(match result {
                    None => b.ins().scalar_to_vector(types::F64X2, r),
                    Some(vector) => b.ins().insertlane(vector, r, l),
                });
            }
            result.expect("two lanes")
        };
        // Constants' offsets in tape order (a `Const` slot's, an instruction's own).
        let mut const_at: Vec<i32> = vec![0; code.len()];
        for (index, &ins) in code.iter().enumerate() {
            match ins {
                Instr::Var(k) => deferred[index] = Some(Deferred::Var(k)),
                Instr::Const(_) => {
                    let offset = i32::try_from(n_const * 8)
                        .map_err(|_| "too many constants for one function".to_string())?;
                    n_const += 1;
                    deferred[index] = Some(Deferred::Const(offset));
                }
                _ if ins.constant().is_some() => {
                    const_at[index] = i32::try_from(n_const * 8)
                        .map_err(|_| "too many constants for one function".to_string())?;
                    n_const += 1;
                }
                _ => {}
            }
            v.push(None);
        }
        for index in super::emission_order(code, chains) {
            let ins = code[index];
            // A variable or constant operand is loaded here: in the vector code for this
            // instruction alone (a load costs what a spilled value's reload would, and keeps
            // no register across the chains'), in the scalar code once (registers to spare).
            // The left operand of `fadd` or `fmul` must not be a load: x64's instruction
            // selection folds a load into the instruction, and for a load on the left it swaps
            // the operands to do so, which changes which NaN comes out when both are NaN.
            // A bitcast to the same type (no instruction) puts it in a register first.
            let left = match ins {
                Instr::Add(x, _)
                | Instr::Mul(x, _)
                | Instr::MulAdd(x, ..)
                | Instr::MulSub(x, ..)
                | Instr::SubMul(x, ..) => Some(x),
                _ => None,
            };
            let mut loaded: Vec<(u32, Vec<Value>)> = Vec::new();
            for s in ins.operands().into_iter().flatten() {
                if let Some(what) = deferred[s as usize] {
                    if !loaded.iter().any(|(l, _)| *l == s) && v[s as usize].is_none() {
                        let mut values = load_deferred(&mut b, what)?;
                        if left == Some(s) {
                            values = values.into_iter().map(|v| in_register(&mut b, v)).collect();
                        }
                        if width == 1 {
                            v[s as usize] = Some(values);
                        } else {
                            loaded.push((s, values));
                        }
                    }
                }
            }
            // The instruction's constant, read once for every chain: in every lane, or as
            // one scalar for the exponent of `powf` (the same in every lane).
            let konst = match ins.constant() {
                Some(_) => {
                    let k = load_const(&mut b, const_at[index], !matches!(ins, Instr::Powf(..)));
                    // On the left of `fadd` and `fmul` (see `left`): a scalar is the load.
                    let left = matches!(ins, Instr::AddC(..) | Instr::MulC(..));
                    Some(if width == 1 && left {
                        in_register(&mut b, k)
                    } else {
                        k
                    })
                }
                None => None,
            };
            let k = || konst.expect("the instruction carries a constant");
            let mut val = Vec::with_capacity(chains);
            for c in 0..chains {
                let get = |s: u32| match loaded.iter().find(|(l, _)| *l == s) {
                    Some((_, values)) => values[c],
                    None => v[s as usize].as_ref().expect("computed before it is read")[c],
                };
                let unary = |b: &mut FunctionBuilder, f: extern "C" fn(f64) -> f64, a: u32| {
                    call(b, sig1, f as usize, &[get(a)])
                };
                val.push(match ins {
                    Instr::Var(_) | Instr::Const(_) => unreachable!("deferred above"),
                    Instr::Neg(a) => b.ins().fneg(get(a)),
                    Instr::Add(x, y) => b.ins().fadd(get(x), get(y)),
                    Instr::Sub(x, y) => b.ins().fsub(get(x), get(y)),
                    Instr::Mul(x, y) => b.ins().fmul(get(x), get(y)),
                    Instr::Div(x, y) => b.ins().fdiv(get(x), get(y)),
                    Instr::AddC(a, _) => b.ins().fadd(k(), get(a)),
                    Instr::CSub(a, _) => b.ins().fsub(k(), get(a)),
                    Instr::MulC(a, _) => b.ins().fmul(k(), get(a)),
                    Instr::DivC(a, _) => b.ins().fdiv(get(a), k()),
                    Instr::CDiv(a, _) => b.ins().fdiv(k(), get(a)),
                    Instr::Square(a) => b.ins().fmul(get(a), get(a)),
                    Instr::Powi(a, n) => {
                        // The immediate of an i32 constant is its bits, zero-extended.
                        let n = b.ins().iconst(types::I32, i64::from(n as u32));
                        call(&mut b, sigi, bead_powi as *const () as usize, &[get(a), n])
                    }
                    Instr::Powf(a, _) => call(
                        &mut b,
                        sig2,
                        bead_powf as *const () as usize,
                        &[get(a), k()],
                    ),
                    Instr::Pow(x, y) => call(
                        &mut b,
                        sig2,
                        bead_powf as *const () as usize,
                        &[get(x), get(y)],
                    ),
                    Instr::Sin(a) => unary(&mut b, bead_sin, a),
                    Instr::Cos(a) => unary(&mut b, bead_cos, a),
                    Instr::Tan(a) => unary(&mut b, bead_tan, a),
                    Instr::Asin(a) => unary(&mut b, bead_asin, a),
                    Instr::Acos(a) => unary(&mut b, bead_acos, a),
                    Instr::Atan(a) => unary(&mut b, bead_atan, a),
                    Instr::Sinh(a) => unary(&mut b, bead_sinh, a),
                    Instr::Cosh(a) => unary(&mut b, bead_cosh, a),
                    Instr::Tanh(a) => unary(&mut b, bead_tanh, a),
                    Instr::Exp(a) => unary(&mut b, bead_exp, a),
                    Instr::Ln(a) => unary(&mut b, bead_ln, a),
                    Instr::Log10(a) => unary(&mut b, bead_log10, a),
                    Instr::Sqrt(a) => b.ins().sqrt(get(a)),
                    Instr::Abs(a) => b.ins().fabs(get(a)),
                    Instr::Sign(a) => unary(&mut b, bead_sign, a),
                    Instr::Atan2(y, x) => call(
                        &mut b,
                        sig2,
                        bead_atan2 as *const () as usize,
                        &[get(y), get(x)],
                    ),
                    Instr::MulAdd(x, y, z) => {
                        let p = b.ins().fmul(get(x), get(y));
                        b.ins().fadd(p, get(z))
                    }
                    Instr::MulSub(x, y, z) => {
                        let p = b.ins().fmul(get(x), get(y));
                        b.ins().fsub(p, get(z))
                    }
                    Instr::SubMul(x, y, z) => {
                        let p = b.ins().fmul(get(x), get(y));
                        b.ins().fsub(get(z), p)
                    }
                });
            }
            for &j in &stored_as[index] {
                store(&mut b, &val, j)?;
            }
            v[index] = Some(val);
        }
        // Outputs that are a variable or a constant slot themselves.
        for (j, &s) in outputs.iter().enumerate() {
            if let Some(what) = deferred[s as usize] {
                let value = load_deferred(&mut b, what)?;
                store(&mut b, &value, j)?;
            }
        }
        if width == 1 {
            b.ins().jump(exit, &[]);
        } else {
            let next = b.ins().iadd_imm_u(lane, 8 * width);
            let more = b.ins().icmp_imm_u(IntCC::UnsignedLessThan, next, stride);
            b.ins().brif(more, body, &[next.into()], exit, &[]);
        }
        b.switch_to_block(exit);
        b.ins().return_(&[]);
        b.seal_all_blocks();
        b.finalize(config);
        usize::try_from(n_const).map_err(|e| e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::testutil::{random_expr, Rng};
    use crate::expr::{Expr, Tape};

    const L: usize = 16;

    /// Values that exercise the corners of every operation.
    const SPECIAL: [f64; 16] = [
        0.0,
        -0.0,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NAN,
        -f64::NAN,
        f64::from_bits(0x7ff8_0000_dead_beef),
        1e300,
        -1e300,
        1e-300,
        -1e-300,
        5e-324,
        f64::MAX,
        f64::MIN_POSITIVE,
        1.0,
        -1.0,
    ];

    fn point(rng: &mut Rng, n: usize) -> Vec<f64> {
        (0..n)
            .map(|_| match rng.below(3) {
                0 => SPECIAL[rng.below(SPECIAL.len())],
                _ => rng.uniform(-2.0, 2.0),
            })
            .collect()
    }

    fn assert_same_bits(got: &[f64], want: &[f64], what: &str) {
        for (j, (g, w)) in got.iter().zip(want).enumerate() {
            assert_eq!(
                g.to_bits(),
                w.to_bits(),
                "{what}, output {j}: {g:e} ({:#x}) vs {w:e} ({:#x})",
                g.to_bits(),
                w.to_bits()
            );
        }
    }

    /// Compiled and interpreted evaluations of 10^4 random expressions (every instruction kind,
    /// shared subexpressions, their derivatives) agree bit for bit, NaN payloads included, at
    /// random points that include zeros of both signs, infinities, NaN, huge and subnormal
    /// values: scalar and 16 lanes.
    #[test]
    fn compiled_tapes_match_the_interpreter_bit_for_bit() {
        let mut rng = Rng::new(2026);
        let mut expressions = 0;
        let mut round = 0;
        while expressions < 10_000 {
            let mut pool = Vec::new();
            let mut outs: Vec<Expr> = (0..4)
                .map(|_| random_expr(&mut rng, 3, 3 + round % 4, &mut pool))
                .collect();
            let ds: Vec<Expr> = outs.iter().map(|e| e.derivative(round % 3)).collect();
            outs.extend(ds);
            expressions += outs.len();
            round += 1;
            let t = with_jit(true, || Tape::compile(&outs));
            assert!(t.is_native(), "round {round}: {:?}", t.native_status());
            let n = t.n_outputs();
            let mut scratch = vec![0.0; t.n_slots() * L];
            for _ in 0..4 {
                let v = point(&mut rng, 3);
                let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
                t.eval(&v, &mut scratch, &mut a);
                t.eval_interpreted(&v, &mut scratch, &mut b);
                assert_same_bits(&a, &b, &format!("round {round} at {v:?}"));
            }
            let vars: Vec<f64> = point(&mut rng, 3 * L);
            let (mut a, mut b) = (vec![0.0; n * L], vec![0.0; n * L]);
            t.eval_lanes::<L>(&vars, &mut scratch, &mut a);
            t.eval_lanes_interpreted::<L>(&vars, &mut scratch, &mut b);
            assert_same_bits(&a, &b, &format!("round {round}, lanes"));
        }
    }

    /// The vector function at every width `build` takes (one, two and four chains of
    /// `f64x2`; `vector_width` picks one or four) agrees with the interpreter bit for bit
    /// over 16 lanes, at points with zeros, infinities and NaN.
    #[test]
    fn every_vector_width_matches_the_interpreter() {
        let mut rng = Rng::new(77);
        for round in 0..400 {
            let mut pool = Vec::new();
            let outs: Vec<Expr> = (0..3)
                .map(|_| random_expr(&mut rng, 3, 3 + round % 4, &mut pool))
                .collect();
            let t = with_jit(false, || Tape::compile(&outs));
            let (code, outputs) = t.parts();
            let consts = constants(code);
            let n = t.n_outputs();
            let vars: Vec<f64> = point(&mut rng, t.n_vars().max(1) * L);
            let mut want = vec![0.0; n * L];
            let mut scratch = vec![0.0; t.n_slots() * L];
            t.eval_lanes_interpreted::<L>(&vars, &mut scratch, &mut want);
            for width in [2, 4, 8] {
                let compiled = codegen::build(code, outputs, width).expect("compiles");
                let mut got = vec![f64::NAN; n * L];
                // SAFETY: the function reads `n_vars` slots of 16 lanes, the tape's
                // constants, and writes its `n` outputs of 16 lanes.
                #[allow(unsafe_code)]
                unsafe {
                    (compiled.func)(vars.as_ptr(), consts.as_ptr(), got.as_mut_ptr())
                };
                assert_same_bits(&got, &want, &format!("round {round}, width {width}"));
            }
        }
    }

    /// Every computed instruction once, after its operands, on 2000 random tapes (so that
    /// `body` finds every operand computed; the bits are the bit-for-bit tests').
    #[test]
    fn the_emission_order_computes_each_instruction_once_after_its_operands() {
        let mut rng = Rng::new(5);
        for round in 0..2000 {
            let mut pool = Vec::new();
            let outs: Vec<Expr> = (0..1 + round % 4)
                .map(|_| random_expr(&mut rng, 3, 2 + round % 5, &mut pool))
                .collect();
            let t = with_jit(false, || Tape::compile(&outs));
            let code = t.parts().0;
            let order = least_live_order(code);
            let mut at = vec![usize::MAX; code.len()];
            for (k, &i) in order.iter().enumerate() {
                assert_eq!(at[i], usize::MAX, "round {round}: {i} twice");
                at[i] = k;
            }
            for (i, ins) in code.iter().enumerate() {
                let computed = !matches!(ins, Instr::Var(_) | Instr::Const(_));
                assert_eq!(at[i] != usize::MAX, computed, "round {round}: {ins:?}");
                for s in ins.operands().into_iter().flatten().map(|s| s as usize) {
                    if at[s] != usize::MAX {
                        assert!(at[s] < at[i], "round {round}: {i} before its operand {s}");
                    }
                }
            }
        }
    }

    /// An RK4 step of the article's bead (the implicit form's acceleration written out):
    /// the stages' slopes are summed as they come instead of all waiting for the update.
    #[test]
    fn the_emission_order_sums_rk4s_slopes_as_they_come() {
        // (x, y, u, w) = (x, y, xdot, ydot); h/2, h and h/6 as variables, as the step's.
        let [x, y, u, w, half, h, sixth] = [0, 1, 2, 3, 4, 5, 6].map(Expr::var);
        let accel = |x: &Expr, u: &Expr| {
            let lambda = (u.clone() * u.clone() * -2.0 - 5e4) / (x.clone() * x.clone() * 4.0 + 1e4);
            (x.clone() * 2.0 * lambda.clone(), lambda * 100.0 + 500.0)
        };
        // The state a stage starts from: (x, u, w) + dt (v, a, b).
        let stage = |dt: &Expr, v: &Expr, a: &Expr, b: &Expr| {
            let ahead = |q: &Expr, rate: &Expr| q.clone() + dt.clone() * rate.clone();
            (ahead(&x, v), ahead(&u, a), ahead(&w, b))
        };
        let (a1, b1) = accel(&x, &u);
        let (x2, u2, w2) = stage(&half, &u, &a1, &b1);
        let (a2, b2) = accel(&x2, &u2);
        let (x3, u3, w3) = stage(&half, &u2, &a2, &b2);
        let (a3, b3) = accel(&x3, &u3);
        let (x4, u4, w4) = stage(&h, &u3, &a3, &b3);
        let (a4, b4) = accel(&x4, &u4);
        let update = |q: &Expr, k: [&Expr; 4]| {
            q.clone()
                + sixth.clone()
                    * (k[0].clone() + k[1].clone() * 2.0 + k[2].clone() * 2.0 + k[3].clone())
        };
        // The stages first, then the update, in the tape as in a compiled step's.
        let step = [
            a4.clone(),
            b4.clone(),
            update(&x, [&u, &u2, &u3, &u4]),
            update(&y, [&w, &w2, &w3, &w4]),
            update(&u, [&a1, &a2, &a3, &a4]),
            update(&w, [&b1, &b2, &b3, &b4]),
        ];
        let t = with_jit(false, || Tape::compile(&step));
        let (tape_order, emitted) = t.most_live_values();
        assert!(
            emitted + 2 <= tape_order,
            "{emitted} live at most, against {tape_order} in tape order"
        );
    }

    /// Four chains for a short tape of arithmetic alone (the article's step), one for a
    /// tape with a call or a long one (see `vector_width`).
    #[test]
    fn chains_go_to_short_arithmetic_tapes() {
        let x = Expr::var(0);
        let width = |e: Expr| {
            let t = with_jit(false, || Tape::compile(&[e]));
            vector_width(t.parts().0)
        };
        let lambda = (x.clone() * x.clone() * 2.0 + 1e4).sqrt() / (x.clone() * 4.0 - 3.0);
        assert_eq!(width(lambda.clone()), 8);
        assert_eq!(width(lambda.clone() * x.clone().sin()), 2);
        let long = (0..MAX_CHAINED_INSTRUCTIONS).fold(x.clone(), |e, k| e * (x.clone() + k as f64));
        assert_eq!(width(long), 2);
    }

    #[test]
    fn the_switch_switches() {
        let e = [Expr::var(0).sin() * 2.0];
        let on = with_jit(true, || Tape::compile(&e));
        let off = with_jit(false, || Tape::compile(&e));
        assert!(on.is_native());
        assert!(matches!(on.native_status(), NativeStatus::Compiled { .. }));
        assert!(!off.is_native());
        assert_eq!(off.native_status(), &NativeStatus::Disabled);
        // The override ends with the closure.
        with_jit(false, || assert!(!jit_enabled()));
        let (mut a, mut b) = ([0.0], [0.0]);
        on.eval(&[0.7], &mut [0.0; 4], &mut a);
        off.eval(&[0.7], &mut [0.0; 4], &mut b);
        assert_eq!(a[0].to_bits(), b[0].to_bits());
        assert_eq!(a[0], 0.7f64.sin() * 2.0);
        // No outputs: nothing to compile.
        assert_eq!(
            with_jit(true, || Tape::compile(&[])).native_status(),
            &NativeStatus::Empty
        );
    }

    #[test]
    fn a_failed_compile_falls_back_to_the_interpreter_with_a_note() {
        let e = [Expr::var(0).sin() + Expr::var(1)];
        let t = with_jit(true, || with_forced_jit_failure(|| Tape::compile(&e)));
        assert!(!t.is_native());
        match t.native_status() {
            NativeStatus::Fallback(why) => assert!(why.contains("forced"), "{why}"),
            s => panic!("{s:?}"),
        }
        let mut out = [0.0];
        t.eval(&[0.5, 2.0], &mut [0.0; 8], &mut out);
        assert_eq!(out[0], 0.5f64.sin() + 2.0);
        // Too long: interpreted, with the limit in the note.
        let mut long = Expr::var(0);
        for i in 0..MAX_NATIVE_INSTRUCTIONS {
            long = &long + &Expr::var(i % 7 + 1).sin();
            if i % 1000 == 0 {
                long = long.sin();
            }
        }
        let t = with_jit(true, || Tape::compile(&[long]));
        assert!(t.n_instructions() > MAX_NATIVE_INSTRUCTIONS);
        match t.native_status() {
            NativeStatus::Fallback(why) => assert!(why.contains("more than"), "{why}"),
            s => panic!("{s:?}"),
        }
    }

    /// Tapes that differ only by their constants share one function, each with its own
    /// constants; clones share it too, and it outlives the tape that compiled it.
    #[test]
    fn same_shape_tapes_share_code_with_their_own_constants() {
        let f = |c: f64, d: f64| [&(Expr::var(0) * c) + &Expr::constant(d)];
        let a = with_jit(true, || Tape::compile(&f(3.25, 11.0)));
        let b = with_jit(true, || Tape::compile(&f(-0.5, 7.0)));
        assert!(matches!(a.native_status(), NativeStatus::Compiled { .. }));
        assert!(matches!(
            b.native_status(),
            NativeStatus::Compiled { shared: true, .. }
        ));
        let c = b.clone();
        drop(b);
        drop(a);
        let mut out = [0.0];
        c.eval(&[2.0], &mut [0.0; 4], &mut out);
        assert_eq!(out[0], 2.0 * -0.5 + 7.0);
        fn shared<T: Send + Sync + Clone>() {}
        shared::<Tape>();
    }
}
