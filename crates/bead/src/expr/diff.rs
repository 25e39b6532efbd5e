//! Symbolic differentiation.
//!
//! [`derivative`] sorts the DAG once (iteratively), marks the nodes that contain the
//! variable, and builds each marked node's derivative from its children's, in dependency
//! order, with the simplifying constructors. Each distinct node is differentiated at most once
//! (memoization on node identity), so shared subexpressions cost linear, not exponential,
//! time; a node that does not contain the variable gets the shared constant-0 node and
//! contributes nothing further.
//!
//! Rules, for subexpressions `a`, `b` with derivatives `a'`, `b'` (see also [`Func`]):
//!
//! | expression     | derivative                                   |
//! |----------------|----------------------------------------------|
//! | `c`, `x_j`     | `0` (`1` for `x_k` itself)                   |
//! | `-a`           | `-a'`                                        |
//! | `a ± b`        | `a' ± b'`                                    |
//! | `a b`          | `a' b + a b'`                                |
//! | `q = a / b`    | `(a' - q b') / b`  (reuses `q`)              |
//! | `a^c`          | `c a^(c-1) a'`  (`b` free of `x_k`)          |
//! | `p = a^b`      | `p (b' ln(a) + b a'/a)`; `p ln(a) b'` if `a` is free of `x_k` |
//! | `sin a`        | `cos(a) a'`                                  |
//! | `cos a`        | `-sin(a) a'`                                 |
//! | `t = tan a`    | `(1 + t^2) a'`                               |
//! | `asin a`       | `a' / sqrt(1 - a^2)`                         |
//! | `acos a`       | `-a' / sqrt(1 - a^2)`                        |
//! | `atan a`       | `a' / (1 + a^2)`                             |
//! | `sinh a`       | `cosh(a) a'`                                 |
//! | `cosh a`       | `sinh(a) a'`                                 |
//! | `t = tanh a`   | `(1 - t^2) a'`                               |
//! | `E = exp a`    | `E a'`                                       |
//! | `ln a`         | `a' / a`                                     |
//! | `log10 a`      | `a' / (ln(10) a)`                            |
//! | `s = sqrt a`   | `a' / (2 s)`                                 |
//! | `abs a`        | `sign(a) a'`                                 |
//! | `sign a`       | `0`                                          |
//! | `atan2(y, x)`  | `(x y' - y x') / (x^2 + y^2)`                |
//!
//! [`Func`]: super::Func
use super::ast::{self, topo, Node, NO_CHILD};
use super::{Expr, Func};

/// The partial derivative of `root` with respect to variable slot `k`.
pub(crate) fn derivative(root: &Expr, k: usize) -> Expr {
    derivatives(root, &[k]).swap_remove(0)
}

/// The partial derivatives of `root` with respect to each of the slots `ks`: each one the
/// expression [`derivative`] gives, with the DAG sorted once for all of them (a constraint
/// row takes one derivative per coordinate it reads, on a DAG whose sort costs as much as
/// a derivative).
pub(crate) fn derivatives(root: &Expr, ks: &[usize]) -> Vec<Expr> {
    if matches!(&*root.0, Node::Var(_) | Node::Const(_)) {
        return ks.iter().map(|&k| derivative_of_leaf(root, k)).collect();
    }
    let t = topo([root]);
    ks.iter().map(|&k| derivative_sorted(&t, k)).collect()
}

/// The derivative of a variable or constant node.
fn derivative_of_leaf(root: &Expr, k: usize) -> Expr {
    match &*root.0 {
        Node::Var(j) if *j == k => Expr::constant(1.0),
        _ => Expr::constant(0.0),
    }
}

/// The derivative with respect to slot `k` of the root of `t` (not a leaf).
fn derivative_sorted(t: &ast::Topo<'_>, k: usize) -> Expr {
    let zero = Expr::constant(0.0);
    let n = t.nodes.len();
    let mut depends = vec![false; n];
    let mut d: Vec<Expr> = Vec::with_capacity(n);
    for (i, (e, &[ia, ib])) in t.nodes.iter().zip(&t.kids).enumerate() {
        let dep = |c: u32| c != NO_CHILD && depends[c as usize];
        let dep_a = dep(ia);
        let dep_b = dep(ib);
        let here = match &*e.0 {
            Node::Var(j) => *j == k,
            _ => dep_a || dep_b,
        };
        depends[i] = here;
        if !here {
            d.push(zero.clone());
            continue;
        }
        // Derivatives of the children (the shared zero node when independent).
        let child = |c: u32| if c == NO_CHILD { &zero } else { &d[c as usize] };
        let de = rule(e, child(ia), child(ib), dep_a, dep_b);
        d.push(de);
    }
    d.swap_remove(t.roots[0] as usize)
}

/// The partial derivatives of each root with respect to every variable slot it contains for
/// which `wanted` holds, ascending by slot, in one forward pass over the DAG of all roots.
///
/// Each node carries the derivatives with respect to the wanted slots below it, built from its
/// children's by the same rules as [`derivative`], so every entry is the expression
/// `derivative(root, slot)` builds (a constant 0 where it simplifies to one: the list is the
/// structural dependence). The cost is the sum over nodes of the number of wanted slots below
/// each, instead of one walk over the whole root per slot: for x_i = x_(i-1) + sin(q_i), all
/// partials of all x_i cost O(N^2), where one [`derivative`] per (i, slot) costs O(N^3).
pub(crate) fn gradients(roots: &[Expr], wanted: &dyn Fn(usize) -> bool) -> Vec<Vec<(usize, Expr)>> {
    let t = topo(roots);
    let n = t.nodes.len();
    let zero = Expr::constant(0.0);
    // A child's list is dropped once its last parent has been built (roots are kept).
    let mut parents = vec![0u32; n];
    for kids in &t.kids {
        for &c in kids.iter().filter(|&&c| c != NO_CHILD) {
            parents[c as usize] += 1;
        }
    }
    let mut is_root = vec![false; n];
    for &r in &t.roots {
        is_root[r as usize] = true;
    }
    let mut grads: Vec<Vec<(usize, Expr)>> = Vec::with_capacity(n);
    for (e, &[ia, ib]) in t.nodes.iter().zip(&t.kids) {
        let g = match &*e.0 {
            Node::Const(_) => Vec::new(),
            Node::Var(j) if wanted(*j) => vec![(*j, Expr::constant(1.0))],
            Node::Var(_) => Vec::new(),
            _ => {
                let empty = Vec::new();
                let list = |c: u32| {
                    if c == NO_CHILD {
                        &empty
                    } else {
                        &grads[c as usize]
                    }
                };
                let (ga, gb) = (list(ia), list(ib));
                let mut g = Vec::with_capacity(ga.len().max(gb.len()));
                let (mut i, mut j) = (0, 0);
                // Merge the children's ascending slot lists.
                while i < ga.len() || j < gb.len() {
                    let sa = ga.get(i).map_or(usize::MAX, |p| p.0);
                    let sb = gb.get(j).map_or(usize::MAX, |p| p.0);
                    let slot = sa.min(sb);
                    let da = (sa == slot).then(|| &ga[i].1);
                    let db = (sb == slot).then(|| &gb[j].1);
                    let de = rule(
                        e,
                        da.unwrap_or(&zero),
                        db.unwrap_or(&zero),
                        da.is_some(),
                        db.is_some(),
                    );
                    g.push((slot, de));
                    i += usize::from(da.is_some());
                    j += usize::from(db.is_some());
                }
                g
            }
        };
        grads.push(g);
        for &c in [ia, ib].iter().filter(|&&c| c != NO_CHILD) {
            let c = c as usize;
            parents[c] -= 1;
            if parents[c] == 0 && !is_root[c] {
                grads[c] = Vec::new();
            }
        }
    }
    t.roots.iter().map(|&r| grads[r as usize].clone()).collect()
}

/// The derivative of the non-leaf node `e` from its children's derivatives `da`, `db` (the
/// constant 0 for an absent child or one that does not contain the variable; `dep_a`, `dep_b`
/// say whether each does).
fn rule(e: &Expr, da: &Expr, db: &Expr, dep_a: bool, dep_b: bool) -> Expr {
    let one = || Expr::constant(1.0);
    let da = || da.clone();
    let db = || db.clone();
    let me = || e.clone();
    match &*e.0 {
        Node::Const(_) => Expr::constant(0.0),
        Node::Var(_) => one(),
        Node::Neg(_) => ast::neg(da()),
        Node::Add(..) => ast::add(da(), db()),
        Node::Sub(..) => ast::sub(da(), db()),
        Node::Mul(a, b) => ast::add(ast::mul(da(), b.clone()), ast::mul(a.clone(), db())),
        Node::Div(_, b) => {
            // (a/b)' = (a' - (a/b) b') / b
            ast::div(ast::sub(da(), ast::mul(me(), db())), b.clone())
        }
        Node::Pow(a, b) => {
            if !dep_b {
                // b a^(b-1) a'
                let b1 = ast::sub(b.clone(), one());
                ast::mul(ast::mul(b.clone(), ast::pow(a.clone(), b1)), da())
            } else if !dep_a {
                // a^b ln(a) b'
                ast::mul(ast::mul(me(), ast::unary(Func::Ln, a.clone())), db())
            } else {
                // a^b (b' ln(a) + b a'/a)
                let t1 = ast::mul(db(), ast::unary(Func::Ln, a.clone()));
                let t2 = ast::div(ast::mul(b.clone(), da()), a.clone());
                ast::mul(me(), ast::add(t1, t2))
            }
        }
        Node::Unary(f, a) => {
            let a = a.clone();
            let square = |x: Expr| ast::pow(x, Expr::constant(2.0));
            match f {
                Func::Sin => ast::mul(ast::unary(Func::Cos, a), da()),
                Func::Cos => ast::neg(ast::mul(ast::unary(Func::Sin, a), da())),
                Func::Tan => ast::mul(ast::add(one(), square(me())), da()),
                Func::Asin => ast::div(da(), ast::unary(Func::Sqrt, ast::sub(one(), square(a)))),
                Func::Acos => ast::neg(ast::div(
                    da(),
                    ast::unary(Func::Sqrt, ast::sub(one(), square(a))),
                )),
                Func::Atan => ast::div(da(), ast::add(one(), square(a))),
                Func::Sinh => ast::mul(ast::unary(Func::Cosh, a), da()),
                Func::Cosh => ast::mul(ast::unary(Func::Sinh, a), da()),
                Func::Tanh => ast::mul(ast::sub(one(), square(me())), da()),
                Func::Exp => ast::mul(me(), da()),
                Func::Ln => ast::div(da(), a),
                Func::Log10 => ast::div(da(), ast::mul(Expr::constant(std::f64::consts::LN_10), a)),
                Func::Sqrt => ast::div(da(), ast::mul(Expr::constant(2.0), me())),
                Func::Abs => ast::mul(ast::unary(Func::Sign, a), da()),
                Func::Sign => Expr::constant(0.0),
                // Never stored as unary nodes.
                Func::Atan2 | Func::Pow => Expr::constant(f64::NAN),
            }
        }
        Node::Atan2(y, x) => {
            // (x y' - y x') / (x^2 + y^2)
            let two = || Expr::constant(2.0);
            let num = ast::sub(ast::mul(x.clone(), da()), ast::mul(y.clone(), db()));
            let den = ast::add(ast::pow(x.clone(), two()), ast::pow(y.clone(), two()));
            ast::div(num, den)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::testutil::{random_expr, Rng};
    use crate::expr::{parse, Resolved};
    use std::sync::Arc;

    const NAMES: [&str; 3] = ["x", "y", "t"];

    fn p(src: &str) -> Expr {
        let r = |n: &str| match NAMES.iter().position(|&m| m == n) {
            Some(k) => Ok(Resolved::Var(k)),
            None => Err(format!("unknown name `{n}`")),
        };
        parse(src, &r).unwrap()
    }

    fn d(src: &str, k: usize) -> String {
        p(src)
            .derivative(k)
            .display_with(&|k| NAMES[k].to_string())
            .to_string()
    }

    #[test]
    fn rules_simplified() {
        assert_eq!(d("x", 0), "1");
        assert_eq!(d("x", 1), "0");
        assert_eq!(d("3", 0), "0");
        assert_eq!(d("x^2 + 100*y", 0), "2*x");
        assert_eq!(d("x^2 + 100*y", 1), "100");
        assert_eq!(d("x^3", 0), "3*x^2");
        assert_eq!(d("x^y", 0), "y*x^(y - 1)");
        assert_eq!(d("2^x", 0), "0.6931471805599453*2^x");
        assert_eq!(d("x^x", 0), "x^x*(ln(x) + x/x)");
        assert_eq!(d("x*y", 0), "y");
        assert_eq!(d("x*y", 1), "x");
        assert_eq!(d("x/y", 0), "1/y");
        assert_eq!(d("x/y", 1), "-(x/y/y)");
        assert_eq!(d("-x", 0), "-1");
        assert_eq!(d("sin(x)", 0), "cos(x)");
        assert_eq!(d("cos(x)", 0), "-sin(x)");
        assert_eq!(d("tan(x)", 0), "1 + tan(x)^2");
        assert_eq!(d("asin(x)", 0), "1/sqrt(1 - x^2)");
        assert_eq!(d("acos(x)", 0), "-1/sqrt(1 - x^2)");
        assert_eq!(d("atan(x)", 0), "1/(1 + x^2)");
        assert_eq!(d("sinh(x)", 0), "cosh(x)");
        assert_eq!(d("cosh(x)", 0), "sinh(x)");
        assert_eq!(d("tanh(x)", 0), "1 - tanh(x)^2");
        assert_eq!(d("exp(x)", 0), "exp(x)");
        assert_eq!(d("ln(x)", 0), "1/x");
        assert_eq!(d("log10(x)", 0), "1/(2.302585092994046*x)");
        assert_eq!(d("sqrt(x)", 0), "1/(2*sqrt(x))");
        assert_eq!(d("abs(x)", 0), "sign(x)");
        assert_eq!(d("sign(x)", 0), "0");
        assert_eq!(d("atan2(y, x)", 0), "-(y/(x^2 + y^2))");
        assert_eq!(d("atan2(y, x)", 1), "x/(x^2 + y^2)");
        assert_eq!(d("sin(x^2)", 0), "cos(x^2)*(2*x)");
        assert_eq!(d("sin(3*x)", 0), "3*cos(3*x)");
        assert_eq!(d("sin(t)*x + cos(y)", 0), "sin(t)");
    }

    #[test]
    fn reuses_nodes_of_the_original() {
        for f in ["sqrt", "exp", "tan", "tanh"] {
            let e = p(&format!("{f}(x*y)"));
            let de = e.derivative(0);
            // The derivative contains the very node `e`.
            let t = topo([&de]);
            assert!(
                t.nodes.iter().any(|n| Arc::ptr_eq(&n.0, &e.0)),
                "{f}: {de:?}"
            );
        }
        // A quotient's derivative reuses the quotient.
        let q = p("x/sin(x)");
        let dq = q.derivative(0);
        assert!(topo([&dq]).nodes.iter().any(|n| n.ptr_eq(&q)));
    }

    #[test]
    fn independent_subtrees_give_the_zero_node() {
        let e = p("sin(y)*exp(t) + y^2");
        let de = e.derivative(0);
        assert_eq!(de.as_constant(), Some(0.0));
        assert_eq!(de.node_count(), 1);
    }

    #[test]
    fn heavy_sharing_is_linear() {
        // f = x^(2^40) by 40 squarings, and g with two uses of each level: g_{n+1} = g_n*g_n
        // written with different operators so nothing collapses.
        let mut f = Expr::var(0);
        let mut g = Expr::var(0);
        for _ in 0..40 {
            f = f.powi(2);
            g = (&g * &g.sin()) + &g.cos();
        }
        let start = std::time::Instant::now();
        let df = f.derivative(0);
        let dg = g.derivative(0);
        let d2g = dg.derivative(0);
        assert!(start.elapsed().as_secs_f64() < 1.0);
        assert!(df.node_count() < 10 * f.node_count());
        assert!(dg.node_count() < 10 * g.node_count());
        assert!(d2g.node_count() < 100 * g.node_count());
        // d/dx x^(2^40) at x = 1 is 2^40.
        assert_eq!(df.eval(&[1.0]), 2f64.powi(40));
        // Check g' against dual numbers at a small point (the expression stays finite).
        let x = num_dual::Dual64::new(0.1, 1.0);
        let want = g.eval_generic(&[x]).eps;
        let got = dg.eval(&[0.1]);
        assert!((got - want).abs() <= 1e-9 * want.abs(), "{got} vs {want}");
    }

    #[test]
    fn gradients_build_the_expressions_of_derivative() {
        let mut rng = Rng::new(8);
        let show = |e: &Expr| e.display_with(&|k| format!("v{k}")).to_string();
        for _ in 0..100 {
            let mut pool = Vec::new();
            let roots: Vec<Expr> = (0..3)
                .map(|_| random_expr(&mut rng, 3, 5, &mut pool))
                .collect();
            // Slot 1 is not wanted.
            let wanted = |k: usize| k != 1;
            let all = gradients(&roots, &wanted);
            let v = [
                rng.uniform(-2.0, 2.0),
                rng.uniform(-2.0, 2.0),
                rng.uniform(-2.0, 2.0),
            ];
            for (root, partials) in roots.iter().zip(&all) {
                let slots: Vec<usize> = partials.iter().map(|(k, _)| *k).collect();
                let contained: Vec<usize> =
                    root.vars().into_iter().filter(|&k| wanted(k)).collect();
                assert_eq!(slots, contained, "{}", show(root));
                for (k, d) in partials {
                    let want = root.derivative(*k);
                    assert_eq!(show(d), show(&want));
                    let (got, want) = (d.eval(&v), want.eval(&v));
                    assert!(got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()));
                }
            }
        }
    }

    #[test]
    fn gradients_of_a_shared_chain_cost_its_nonzeros() {
        // x_i = x_(i-1) + sin(q_i): all partials of all x_i are O(N^2) entries, each the
        // shared cos(q_j) node.
        let n = 400;
        let mut x = Expr::constant(0.0);
        let mut roots = Vec::new();
        for i in 0..n {
            x = x + Expr::var(i).sin();
            roots.push(x.clone());
        }
        let start = std::time::Instant::now();
        let all = gradients(&roots, &|_| true);
        assert!(start.elapsed().as_secs_f64() < 2.0);
        for (i, partials) in all.iter().enumerate() {
            assert_eq!(partials.len(), i + 1);
            for (j, d) in partials {
                assert!(d.ptr_eq(&all[n - 1][*j].1), "d x_{i} / d q_{j} is shared");
            }
        }
    }

    #[test]
    fn derivatives_together_are_the_derivatives_one_by_one() {
        let mut rng = Rng::new(11);
        let show = |e: &Expr| e.display_with(&|k| NAMES[k].to_string()).to_string();
        for _ in 0..100 {
            let mut pool = Vec::new();
            let e = random_expr(&mut rng, 3, 5, &mut pool);
            let together: Vec<String> = e.derivatives(&[2, 0, 1, 0]).iter().map(show).collect();
            let one_by_one: Vec<String> = [2, 0, 1, 0]
                .iter()
                .map(|&k| show(&e.derivative(k)))
                .collect();
            assert_eq!(together, one_by_one, "{}", show(&e));
        }
        // Leaves, and no slot at all.
        assert_eq!(
            p("x")
                .derivatives(&[0, 1])
                .iter()
                .map(show)
                .collect::<Vec<_>>(),
            ["1", "0"]
        );
        assert_eq!(
            p("2")
                .derivatives(&[0])
                .iter()
                .map(show)
                .collect::<Vec<_>>(),
            ["0"]
        );
        assert!(p("x*y").derivatives(&[]).is_empty());
    }

    #[test]
    fn random_gradients_match_dual_numbers() {
        let mut rng = Rng::new(5);
        for _ in 0..150 {
            let mut pool = Vec::new();
            let e = random_expr(&mut rng, 3, 5, &mut pool);
            let v = [
                rng.uniform(-2.0, 2.0),
                rng.uniform(-2.0, 2.0),
                rng.uniform(-2.0, 2.0),
            ];
            for k in 0..3 {
                let dual: Vec<_> = (0..3)
                    .map(|j| num_dual::Dual64::new(v[j], if j == k { 1.0 } else { 0.0 }))
                    .collect();
                let want = e.eval_generic(&dual).eps;
                let got = e.derivative(k).eval(&v);
                assert!(
                    (got - want).abs() <= 1e-10 * (1.0 + want.abs()),
                    "d/dx{k} {}: {got} vs {want}",
                    e.display_with(&|k| NAMES[k].to_string())
                );
            }
        }
    }
}
