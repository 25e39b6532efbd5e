//! Distance and pin rows are evaluated by direct code (`model/native.rs`) and have a symbolic
//! form built on demand (for `bead check`, messages and the singular-point search). Both come
//! from the same parameters: here they agree to round-off at random states, in 2D and 3D,
//! for rods between particles, rods to a fixed point, pins, and beside expression rows
//! (which stay on the tape and must land in their own rows).

use bead::model::{Endpoint, System, SystemBuilder};

/// Small deterministic generator (xorshift64*), so that failures reproduce.
struct Rng(u64);

impl Rng {
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let bits = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11;
        lo + (hi - lo) * (bits as f64 / (1u64 << 53) as f64)
    }
}

/// Rods, an anchored rod, a pin and two expression rows, declared interleaved.
fn mixed(dim: usize) -> System {
    let gravity = vec![0.0; dim];
    let mut b = SystemBuilder::new(&gravity);
    let at = |k: f64| (0..dim).map(|a| k + a as f64 * 0.3).collect::<Vec<_>>();
    let zero = vec![0.0; dim];
    let p: Vec<_> = (0..5)
        .map(|k| {
            b.particle(&format!("p{k}"), 1.0 + k as f64, &at(k as f64), &zero)
                .unwrap()
        })
        .collect();
    b.distance("anchored", p[0], Endpoint::Fixed(at(-1.0)), 1.3)
        .unwrap();
    b.constraint_expr("p1.x^2 + p1.y - 2").unwrap();
    b.distance("rod 1-2", p[2], Endpoint::Particle(p[1]), 0.7)
        .unwrap();
    b.pin("pin", p[3], &at(3.0)).unwrap();
    // A rod declared from the higher-numbered particle to the lower one.
    b.distance("rod 4-2", p[2], Endpoint::Particle(p[4]), 2.5)
        .unwrap();
    b.constraint_expr("p4.x * p3.y - 1").unwrap();
    b.build().unwrap()
}

// `r` indexes the values, rates, biases and Jacobians of both paths, and names the row.
#[allow(clippy::needless_range_loop)]
fn agrees(system: &System, seed: u64) {
    let set = system.constraints();
    assert!(set.n_native_rows() > 0);
    let n = system.n_coords();
    let mut ws = set.workspace();
    let mut rng = Rng(seed);
    for _ in 0..200 {
        let x: Vec<f64> = (0..n).map(|_| rng.uniform(-5.0, 5.0)).collect();
        let v: Vec<f64> = (0..n).map(|_| rng.uniform(-3.0, 3.0)).collect();
        let t = rng.uniform(0.0, 2.0);
        let vars: Vec<f64> = [&x[..], &v[..], &[t]].concat();
        set.evaluate(t, &x, &v, &mut ws);
        let evaluated = ws.clone();
        set.gradient(t, &x, &mut ws);
        let gradient = ws.clone();
        let values = set.residuals(t, &x, &mut ws).to_vec();
        for r in 0..set.n_rows() {
            let row = set.symbolic_row(r).unwrap();
            let close = |a: f64, b: f64, scale: f64, what: &str| {
                assert!(
                    (a - b).abs() <= 4.0 * f64::EPSILON * scale.max(1.0),
                    "row {r} {what}: native {a} vs symbolic {b}"
                );
            };
            let scale = 50.0;
            let c = row.value.eval(&vars);
            close(evaluated.value[r], c, scale, "C");
            close(gradient.value[r], c, scale, "C (gradient)");
            close(values[r], c, scale, "C (residuals)");
            close(
                evaluated.velocity[r],
                row.velocity.eval(&vars),
                scale,
                "Cdot",
            );
            close(evaluated.bias[r], row.bias.eval(&vars), scale, "bias");
            let entries = set.row_entries(r);
            assert_eq!(set.row_columns(r).len(), row.gradient.len());
            for ((k, d), e) in row.gradient.iter().zip(entries) {
                assert_eq!(set.row_columns(r)[e - set.row_entries(r).start], *k);
                close(evaluated.jacobian[e], d.eval(&vars), 10.0, "J");
                close(gradient.jacobian[e], d.eval(&vars), 10.0, "J (gradient)");
            }
        }
    }
}

#[test]
fn native_rows_agree_with_their_symbolic_form_in_2d() {
    let system = mixed(2);
    // 2 rods + 1 anchored rod + 2 pin rows are native; the 2 expressions are not.
    assert_eq!(system.constraints().n_native_rows(), 5);
    agrees(&system, 1);
}

#[test]
fn native_rows_agree_with_their_symbolic_form_in_3d() {
    let system = mixed(3);
    assert_eq!(system.constraints().n_native_rows(), 6);
    agrees(&system, 2);
}
