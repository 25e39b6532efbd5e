//! The machine code's cache keeps the most recently compiled functions alive: a tape of a
//! shape compiled before shares that code even after every tape holding it was dropped (a
//! sweep whose members load their equations one after another), until 16 newer functions
//! pushed it out. One test in its own binary, so that no other test compiles in between.

use bead::expr::{with_jit, Expr, NativeStatus, Tape};

/// sin(x) c + x^3 for the constant c: one shape for every c.
fn tape(c: f64) -> Tape {
    let x = Expr::var(0);
    with_jit(true, || {
        Tape::compile(&[&(&x.sin() * &Expr::constant(c)) + &(&(&x * &x) * &x)])
    })
}

/// A tape of another shape for each k (k + 1 terms).
fn other(k: usize) -> Tape {
    let mut e = Expr::var(0).cos();
    for i in 0..=k {
        e = &e + &(&Expr::var(0) * &Expr::constant(i as f64 + 0.5)).sin();
    }
    with_jit(true, || Tape::compile(&[e]))
}

fn shared(tape: &Tape) -> bool {
    match tape.native_status() {
        NativeStatus::Compiled { shared, .. } => *shared,
        status => panic!("not compiled: {status:?}"),
    }
}

#[test]
fn a_shape_compiled_again_after_its_tapes_were_dropped_shares_the_recent_code() {
    let first = tape(2.0);
    assert!(!shared(&first));
    let at = |t: &Tape, x: f64| {
        let mut out = [0.0];
        t.eval(&[x], &mut vec![0.0; t.n_slots()], &mut out);
        out[0]
    };
    assert_eq!(at(&first, 0.7), 0.7f64.sin() * 2.0 + 0.7 * 0.7 * 0.7);
    drop(first);
    let again = tape(3.0);
    assert!(
        shared(&again),
        "compiled again after its tapes were dropped"
    );
    assert_eq!(at(&again, 0.7), 0.7f64.sin() * 3.0 + 0.7 * 0.7 * 0.7);
    drop(again);
    // 16 functions of other shapes compiled since: this one is no longer kept.
    for k in 0..16 {
        assert!(!shared(&other(k)), "shape {k} is new");
    }
    assert!(!shared(&tape(4.0)), "kept beyond the 16 most recent");
}
