//! The complete elliptic integral K(m) and Jacobi's sn, cn, dn by the arithmetic-geometric
//! mean (Abramowitz and Stegun 17.6 and 16.4), for the pendulum's closed form. Written here,
//! not taken from bead; `tests/library.rs` checks them against mpmath's values in the
//! pendulum's reference table.

/// The AGM ladder of parameter m = k^2: (a_n, c_n) until c_n vanishes.
fn ladder(m: f64) -> Vec<(f64, f64)> {
    let mut a = 1.0;
    let mut b = (1.0 - m).sqrt();
    let mut c = m.sqrt();
    let mut steps = vec![(a, c)];
    while c.abs() > 1e-17 * a && steps.len() < 40 {
        let next = (a + b) / 2.0;
        c = (a - b) / 2.0;
        b = (a * b).sqrt();
        a = next;
        steps.push((a, c));
    }
    steps
}

/// K(m) = integral from 0 to pi/2 of (1 - m sin^2)^(-1/2), 0 <= m < 1.
pub fn complete_k(m: f64) -> f64 {
    let (a, _) = *ladder(m).last().expect("at least one step");
    std::f64::consts::PI / (2.0 * a)
}

/// (sn, cn, dn)(u | m), 0 <= m < 1, by the descending AGM: phi_N = 2^N a_N u, then
/// phi_{n-1} = (phi_n + asin(c_n sin(phi_n) / a_n)) / 2.
pub fn sn_cn_dn(u: f64, m: f64) -> (f64, f64, f64) {
    let steps = ladder(m);
    let n = steps.len() - 1;
    let mut phi = 2f64.powi(n as i32) * steps[n].0 * u;
    let mut previous = phi;
    for i in (1..=n).rev() {
        let (a, c) = steps[i];
        previous = phi;
        phi = (phi + (c * phi.sin() / a).asin()) / 2.0;
    }
    let sn = phi.sin();
    let cn = phi.cos();
    let dn = if n == 0 {
        1.0
    } else {
        cn / (previous - phi).cos()
    };
    (sn, cn, dn)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn k_of_zero_is_half_pi_and_identities_hold() {
        assert!((complete_k(0.0) - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
        // K(1/2) = Gamma(1/4)^2 / (4 sqrt(pi)).
        assert!((complete_k(0.5) - 1.854_074_677_301_372).abs() < 1e-14);
        for &m in &[0.0, 0.25, 0.5, 0.9] {
            for &u in &[0.0, 0.3, 1.1, 2.5, -0.7] {
                let (sn, cn, dn) = sn_cn_dn(u, m);
                assert!((sn * sn + cn * cn - 1.0).abs() < 1e-14);
                assert!((dn * dn + m * sn * sn - 1.0).abs() < 1e-14);
            }
            // sn(K) = 1.
            let (sn, cn, _) = sn_cn_dn(complete_k(m), m);
            assert!((sn - 1.0).abs() < 1e-14 && cn.abs() < 1e-7, "{sn} {cn}");
        }
    }
}
