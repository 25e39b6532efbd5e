//! Symbolic derivatives of every built-in function and operator, checked against forward-mode
//! automatic differentiation with num-dual (first derivatives with `Dual64`, second with
//! `Dual2_64`, mixed second partials with `HyperDual64`), through both `Expr::eval` and the
//! compiled `Tape`; and the forms `bead check` prints (`Expr::for_display`), parsed back.
use bead::expr::{parse, Expr, ExprError, Func, Resolved, Tape};
use num_dual::{Dual2_64, Dual64, HyperDual64};

/// x = slot 0, y = slot 1, `L` = 1.5 (a scene parameter).
fn resolve(name: &str) -> Result<Resolved, String> {
    match name {
        "x" => Ok(Resolved::Var(0)),
        "y" => Ok(Resolved::Var(1)),
        "L" => Ok(Resolved::Value(1.5)),
        _ => Err(format!("unknown name `{name}`")),
    }
}

fn p(src: &str) -> Expr {
    parse(src, &resolve).unwrap_or_else(|e: ExprError| panic!("{e}\n{}", e.caret(src)))
}

fn assert_close(got: f64, want: f64, what: &str) {
    let tol = 1e-12 * (1.0 + want.abs());
    assert!(
        (got - want).abs() <= tol,
        "{what}: symbolic {got} vs dual {want}"
    );
}

/// First and second derivatives in x and y and the mixed partial, for `src` at `(x, y)`,
/// compared with dual numbers, through `eval` and through a tape holding all of them.
fn check(src: &str, x: f64, y: f64) {
    let f = p(src);
    let fx = f.derivative(0);
    let fy = f.derivative(1);
    let fxx = fx.derivative(0);
    let fyy = fy.derivative(1);
    let fxy = fx.derivative(1);
    let fyx = fy.derivative(0);
    let at = format!("{src} at ({x}, {y})");

    let dx = f.eval_generic(&[Dual64::new(x, 1.0), Dual64::new(y, 0.0)]);
    let dy = f.eval_generic(&[Dual64::new(x, 0.0), Dual64::new(y, 1.0)]);
    let d2x = f.eval_generic(&[Dual2_64::new(x, 1.0, 0.0), Dual2_64::new(y, 0.0, 0.0)]);
    let d2y = f.eval_generic(&[Dual2_64::new(x, 0.0, 0.0), Dual2_64::new(y, 1.0, 0.0)]);
    let hxy = f.eval_generic(&[
        HyperDual64::new(x, 1.0, 0.0, 0.0),
        HyperDual64::new(y, 0.0, 1.0, 0.0),
    ]);
    let v = [x, y];
    assert_close(f.eval(&v), dx.re, &format!("value of {at}"));
    assert_close(fx.eval(&v), dx.eps, &format!("d/dx {at}"));
    assert_close(fy.eval(&v), dy.eps, &format!("d/dy {at}"));
    assert_close(fxx.eval(&v), d2x.v2, &format!("d2/dx2 {at}"));
    assert_close(fyy.eval(&v), d2y.v2, &format!("d2/dy2 {at}"));
    assert_close(fxy.eval(&v), hxy.eps1eps2, &format!("d2/dxdy {at}"));
    assert_close(fyx.eval(&v), hxy.eps1eps2, &format!("d2/dydx {at}"));

    // What `bead check` prints, parsed back, has the same values.
    for (e, want, what) in [
        (&fx, dx.eps, "d/dx"),
        (&fy, dy.eps, "d/dy"),
        (&fxx, d2x.v2, "d2/dx2"),
        (&fyy, d2y.v2, "d2/dy2"),
        (&fxy, hxy.eps1eps2, "d2/dxdy"),
    ] {
        let shown = printed(e);
        assert_close(
            p(&shown).eval(&v),
            want,
            &format!("{what} {at} printed as {shown}"),
        );
    }

    let outputs = [f, fx, fy, fxx, fyy, fxy];
    let tape = Tape::compile(&outputs);
    let mut scratch = vec![0.0; tape.n_slots()];
    let mut out = [0.0; 6];
    tape.eval(&v, &mut scratch, &mut out);
    for (o, e) in out.iter().zip(&outputs) {
        let want = e.eval(&v);
        assert!(
            *o == want || (o - want).abs() <= 1e-14 * want.abs(),
            "tape vs eval for {at}: {o} vs {want}"
        );
    }
}

/// `e` as `bead check` prints it (collected, for reading), without its length limit.
fn printed(e: &Expr) -> String {
    let names = |k: usize| ["x", "y"][k].to_string();
    let tidy = e.for_display();
    let shown = tidy.display_bounded(&names, usize::MAX).to_string();
    shown
}

/// Points (x, y) with x in (-1, 1) \ {0} and y > 0, so every function below is smooth.
const POINTS: [(f64, f64); 5] = [
    (0.3, 1.7),
    (-0.45, 0.6),
    (0.8, 2.3),
    (-0.9, 1.1),
    (0.05, 0.35),
];

#[test]
fn every_function_of_x() {
    // Each function of a plain variable and of an inner expression (chain rule).
    let funcs = [
        "sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "exp", "abs",
    ];
    for f in funcs {
        assert!(Func::from_name(f).is_some());
        for (x, y) in POINTS {
            check(&format!("{f}(x)"), x, y);
            check(&format!("{f}(0.5*x*y)"), x, y);
        }
    }
    // Functions that need a positive argument.
    for f in ["ln", "log10", "sqrt"] {
        for (x, y) in POINTS {
            check(&format!("{f}(y)"), x, y);
            check(&format!("{f}(x^2 + y)"), x, y);
            check(&format!("{f}(y)*x"), x, y);
        }
    }
}

#[test]
fn two_argument_functions_and_powers() {
    for (x, y) in POINTS {
        for src in [
            "atan2(y, x)",
            "atan2(x, y)",
            "atan2(x*y, 1 + x^2)",
            "pow(y, x)",
            "pow(y, 2.5)",
            "pow(2, x)",
            "y^x",
            "y^(x*y)",
            "(x + y)^y",
            "x^2",
            "x^3",
            "x^-2",
            "y^-1",
            "x^16",
            "x^17",
            "y^0.5",
            "y^-0.5",
            "x^2*y^3",
        ] {
            check(src, x, y);
        }
    }
}

#[test]
fn arithmetic_and_sign() {
    for (x, y) in POINTS {
        for src in [
            "x + y",
            "x - y",
            "x*y",
            "x/y",
            "y/x",
            "-x/y^2",
            "-(x + y)*(x - y)",
            "1/(1 + x^2 + y^2)",
            "sign(x)*y",
            "sign(x*y)",
            "abs(x)*y + sign(y)",
            "x*y/(x + y)",
            "L*x^2 + 100*y",
            "pi*e*x",
        ] {
            check(src, x, y);
        }
    }
}

#[test]
fn physics_like_constraints() {
    // A bead on a circle of radius L, a curve, and a pendulum-in-polar form.
    for (x, y) in POINTS {
        for src in [
            "x^2 + y^2 - L^2",
            "sqrt(x^2 + y^2) - L",
            "y - cosh(x)",
            "atan2(y, x) - 0.25*pi",
            "L*sin(x)*cos(y) + exp(-x^2/2)*tanh(y)",
            "sin(x)^2 + cos(x)^2",
            "ln(1 + x^2) - log10(y)*asin(x/2)",
        ] {
            check(src, x, y);
        }
    }
}

#[test]
fn heavy_sharing_differentiates_quickly() {
    // f = x^(2^40) built by 40 squarings, and g with each level used three times.
    let mut f = Expr::var(0);
    let mut g = Expr::var(0);
    for _ in 0..40 {
        f = &f * &f;
        g = &(&g * &g.sin()) + &g.cos();
    }
    let start = std::time::Instant::now();
    let df = f.derivative(0);
    let d2f = df.derivative(0);
    let dg = g.derivative(0);
    let d2g = dg.derivative(0);
    let tape = Tape::compile(&[df.clone(), d2f.clone(), dg.clone(), d2g.clone()]);
    assert!(
        start.elapsed().as_secs_f64() < 2.0,
        "took {:?}",
        start.elapsed()
    );
    assert!(tape.n_instructions() < 2000, "{}", tape.n_instructions());
    assert_eq!(df.eval(&[1.0]), 2f64.powi(40));

    let x = 0.1;
    let d2 = g.eval_generic(&[Dual2_64::new(x, 1.0, 0.0)]);
    assert!((dg.eval(&[x]) - d2.v1).abs() <= 1e-9 * d2.v1.abs());
    assert!((d2g.eval(&[x]) - d2.v2).abs() <= 1e-9 * d2.v2.abs());
    let mut scratch = vec![0.0; tape.n_slots()];
    let mut out = [0.0; 4];
    tape.eval(&[x], &mut scratch, &mut out);
    assert!((out[2] - d2.v1).abs() <= 1e-9 * d2.v1.abs());
    assert!((out[3] - d2.v2).abs() <= 1e-9 * d2.v2.abs());
}

#[test]
fn derivative_of_non_dependent_parts_is_exactly_zero() {
    let f = p("sin(y)*exp(y^2) + L");
    let d = f.derivative(0);
    assert_eq!(d.as_constant(), Some(0.0));
    assert_eq!(p("x*y").derivative(7).as_constant(), Some(0.0));
}

#[test]
fn printed_derivatives_fold_constant_factors() {
    // d/dx sqrt(x^2 + y^2) is built as 2*x/(2*sqrt(...)); printed without the 2s.
    let r = p("sqrt(x^2 + y^2)");
    assert_eq!(printed(&r.derivative(0)), "x/sqrt(x^2 + y^2)");
    // The half-square form of a distance constraint.
    let c = p("(x^2 + y^2 - L^2)/2");
    assert_eq!(printed(&c), "(x^2 + y^2 - 2.25)/2");
    assert_eq!(printed(&c.derivative(0)), "x");
    assert_eq!(printed(&p("-(2*x/100)")), "-0.02*x");
    assert_eq!(printed(&p("x*x*3").derivative(0)), "3*(x + x)");
    assert_eq!(printed(&p("1/x").derivative(0)), "-1/x^2");
}

#[test]
fn printing_a_long_product_is_bounded() {
    // C = y - prod_k (1 + x/k), 800 factors: the DAG of the second derivative is linear in
    // the number of factors, the tree written out cubic.
    let n = 800;
    let product = (1..=n)
        .map(|k| format!("(1 + x/{k})"))
        .collect::<Vec<_>>()
        .join("*");
    let c = p(&format!("y - {product}"));
    let cx = c.derivative(0);
    let cxx = cx.derivative(0);
    let names = |k: usize| ["x", "y"][k].to_string();
    for e in [&c, &cx, &cxx] {
        let tidy = e.for_display();
        assert!(tidy.node_count() <= 2 * e.node_count() + 10);
        let shown = tidy.display_bounded(&names, 400).to_string();
        assert!(shown.len() < 500, "{} characters", shown.len());
        assert!(shown.ends_with(" more characters)"), "{shown}");
    }
    // The printed prefix is the start of the full form.
    let short = p("y - (1 + x/1)*(1 + x/2)*(1 + x/3)")
        .derivative(0)
        .for_display();
    let full = short.display_bounded(&names, usize::MAX).to_string();
    let cut = short.display_bounded(&names, 20).to_string();
    let prefix = cut.split(" ... (").next().unwrap();
    assert!(full.starts_with(prefix), "{full} / {cut}");
    let rest: usize = cut
        .split(" ... (")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap();
    assert_eq!(prefix.len() + rest, full.len());
}
