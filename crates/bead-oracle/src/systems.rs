//! The oracle's systems, written again by hand from their physics (not read from the scene
//! through bead): masses, gravity, the map x(q, t) and its velocity, the implicit
//! constraints C(x, t) as bead defines them, the closed forms where there are some, and
//! each system's scales for relative errors.

use std::f64::consts::PI;
use std::sync::OnceLock;

use crate::elliptic;
use crate::reference::Reference;

/// (q, q') of the parametric form.
pub type State = (Vec<f64>, Vec<f64>);

/// One system with an answer bead did not compute.
pub struct System {
    /// The reference's name (tests/oracle/references/NAME.*) and the listing's.
    pub name: &'static str,
    /// The scene file, from the repository root.
    pub scene: &'static str,
    /// Space dimension.
    pub dim: usize,
    /// Particle names, in scene order.
    pub particles: &'static [&'static str],
    /// Particle masses, in scene order.
    pub masses: &'static [f64],
    /// Gravity (an acceleration).
    pub gravity: &'static [f64],
    /// The parametric form's coordinates.
    pub coordinates: &'static [&'static str],
    /// Length and speed scales: errors are |dx| / length and |dv| / speed.
    pub length: f64,
    pub speed: f64,
    /// x(q, t).
    pub map: fn(&[f64], f64) -> Vec<f64>,
    /// dx/dt = J(q, t) q' + dx/dt|q.
    pub velocity: fn(&[f64], &[f64], f64) -> Vec<f64>,
    /// The implicit rows C(x, t), as bead defines them (a distance row is
    /// (|d|^2 - L^2) / (2 L)).
    pub constraints: fn(&[f64], f64) -> Vec<f64>,
    /// (q, q') at t in closed form, when there is one.
    pub closed_form: Option<fn(f64) -> State>,
    /// Whether something does work on it (a driven constraint): its rows carry W.
    pub driven: bool,
    /// A parameter to sweep (`bead sweep --param NAME=A:B:3`), whose middle value B is the
    /// scene's, so that the middle member has the reference; the others are checked where
    /// `closed_form_with` gives their answer.
    pub sweep: (&'static str, f64, f64),
    /// (q, q') at t for another value of the swept parameter, when the closed form has it.
    pub closed_form_with: Option<fn(f64, f64) -> State>,
}

impl std::fmt::Debug for System {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name)
    }
}

impl System {
    /// Every system, in the listing's order.
    pub fn all() -> &'static [System] {
        &SYSTEMS
    }

    /// The system named `name`.
    pub fn named(name: &str) -> &'static System {
        SYSTEMS
            .iter()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("no oracle system {name}"))
    }

    /// Its reference (loaded once).
    pub fn reference(&self) -> &'static Reference {
        static LOADED: OnceLock<Vec<Reference>> = OnceLock::new();
        let all = LOADED.get_or_init(|| SYSTEMS.iter().map(|s| Reference::load(s.name)).collect());
        all.iter()
            .find(|r| r.name == self.name)
            .expect("a reference")
    }

    /// (q, q') at t: the closed form, else the reference table.
    pub fn exact(&self, t: f64) -> (Vec<f64>, Vec<f64>) {
        match self.closed_form {
            Some(f) => f(t),
            None => self.reference().at(t),
        }
    }

    /// The particle state (x, v) at t.
    pub fn exact_state(&self, t: f64) -> (Vec<f64>, Vec<f64>) {
        let (q, qdot) = self.exact(t);
        ((self.map)(&q, t), (self.velocity)(&q, &qdot, t))
    }

    /// T + V of a particle state.
    pub fn energy(&self, x: &[f64], v: &[f64]) -> f64 {
        let d = self.dim;
        let mut e = 0.0;
        for (p, &m) in self.masses.iter().enumerate() {
            let (xp, vp) = (&x[p * d..(p + 1) * d], &v[p * d..(p + 1) * d]);
            e += 0.5 * m * vp.iter().map(|c| c * c).sum::<f64>();
            e -= m * xp.iter().zip(self.gravity).map(|(a, g)| a * g).sum::<f64>();
        }
        e
    }

    /// An energy scale: the total mass times the speed scale squared.
    pub fn energy_scale(&self) -> f64 {
        self.masses.iter().sum::<f64>() * self.speed * self.speed
    }

    /// The error allowed for the reference itself, relative (its stated error and that of
    /// the interpolant, in the units of x and v through the scale of q).
    pub fn reference_floor(&self) -> f64 {
        if self.closed_form.is_some() {
            return 1e-15;
        }
        let per_q = match self.name {
            "parabola" => 1.0,
            "spinning-hoop" => 0.8,
            _ => 1.0,
        };
        4.0 * self.reference().error * per_q / self.length.min(self.speed)
    }
}

fn pendulum_with(t: f64, theta0: f64) -> (Vec<f64>, Vec<f64>) {
    // sin(theta/2) = k sn(K - w t | k^2), theta' = -2 k w cn(K - w t | k^2).
    let (l, g): (f64, f64) = (1.0, 9.81);
    let w: f64 = (g / l).sqrt();
    let k = (theta0 / 2.0).sin();
    let m = k * k;
    let kk = elliptic::complete_k(m);
    let (sn, cn, _) = elliptic::sn_cn_dn(kk - w * t, m);
    (vec![2.0 * (k * sn).asin()], vec![-2.0 * k * w * cn])
}

fn helix_with(t: f64, w0: f64) -> (Vec<f64>, Vec<f64>) {
    let (r, b, g) = (1.0, 0.2, 9.81);
    let a = g * b / (r * r + b * b);
    (vec![w0 * t - a * t * t / 2.0], vec![w0 - a * t])
}

fn rod_with(t: f64, r0: f64) -> (Vec<f64>, Vec<f64>) {
    let w = ROD_W;
    (vec![r0 * (w * t).cosh()], vec![r0 * w * (w * t).sinh()])
}

/// The rotating rod's rate and mass (tests/oracle/scenes/rotating-rod.toml).
pub const ROD_W: f64 = 2.0;
pub const ROD_M: f64 = 1.5;
pub const ROD_R0: f64 = 0.5;
/// The spinning hoop's rate (scenes/spinning-hoop.toml).
pub const HOOP_W: f64 = 5.0;

static SYSTEMS: [System; 6] = [
    System {
        name: "pendulum",
        scene: "scenes/circle.toml",
        dim: 2,
        particles: &["bead"],
        masses: &[1.0],
        gravity: &[0.0, 9.81],
        coordinates: &["theta"],
        length: 1.0,
        speed: 3.0,
        map: |q, _| vec![q[0].sin(), q[0].cos()],
        velocity: |q, d, _| vec![q[0].cos() * d[0], -q[0].sin() * d[0]],
        constraints: |x, _| vec![x[0] * x[0] + x[1] * x[1] - 1.0],
        closed_form: Some(|t| pendulum_with(t, PI / 3.0)),
        driven: false,
        sweep: ("theta0", PI / 6.0, PI / 3.0),
        closed_form_with: Some(pendulum_with),
    },
    System {
        name: "helix",
        scene: "scenes/helix.toml",
        dim: 3,
        particles: &["bead"],
        masses: &[1.0],
        gravity: &[0.0, 0.0, -9.81],
        coordinates: &["phi"],
        length: 1.0,
        speed: 3.0,
        map: |q, _| vec![q[0].cos(), q[0].sin(), 0.2 * q[0]],
        velocity: |q, d, _| vec![-q[0].sin() * d[0], q[0].cos() * d[0], 0.2 * d[0]],
        constraints: |x, _| vec![x[0] - (x[2] / 0.2).cos(), x[1] - (x[2] / 0.2).sin()],
        closed_form: Some(|t| helix_with(t, 3.0)),
        driven: false,
        sweep: ("w0", 2.0, 3.0),
        closed_form_with: Some(helix_with),
    },
    System {
        name: "rotating-rod",
        scene: "tests/oracle/scenes/rotating-rod.toml",
        dim: 2,
        particles: &["bead"],
        masses: &[ROD_M],
        gravity: &[0.0, 0.0],
        coordinates: &["r"],
        length: 1.0,
        speed: 3.0,
        map: |q, t| vec![q[0] * (ROD_W * t).cos(), q[0] * (ROD_W * t).sin()],
        velocity: |q, d, t| {
            let (s, c) = (ROD_W * t).sin_cos();
            vec![d[0] * c - q[0] * ROD_W * s, d[0] * s + q[0] * ROD_W * c]
        },
        constraints: |x, t| {
            let (s, c) = (ROD_W * t).sin_cos();
            vec![-x[0] * s + x[1] * c]
        },
        closed_form: Some(|t| rod_with(t, ROD_R0)),
        driven: true,
        sweep: ("r0", 0.25, ROD_R0),
        closed_form_with: Some(rod_with),
    },
    System {
        name: "spinning-hoop",
        scene: "scenes/spinning-hoop.toml",
        dim: 3,
        particles: &["bead"],
        masses: &[1.0],
        gravity: &[0.0, 0.0, -9.81],
        coordinates: &["th"],
        length: 0.8,
        speed: 3.0,
        map: |q, t| {
            let (s, c) = (HOOP_W * t).sin_cos();
            vec![
                0.8 * q[0].sin() * c,
                0.8 * q[0].sin() * s,
                -0.8 * q[0].cos(),
            ]
        },
        velocity: |q, d, t| {
            let (s, c) = (HOOP_W * t).sin_cos();
            let (st, ct) = q[0].sin_cos();
            vec![
                0.8 * (ct * d[0] * c - st * HOOP_W * s),
                0.8 * (ct * d[0] * s + st * HOOP_W * c),
                0.8 * st * d[0],
            ]
        },
        constraints: |x, t| {
            let (s, c) = (HOOP_W * t).sin_cos();
            vec![
                x[0] * x[0] + x[1] * x[1] + x[2] * x[2] - 0.64,
                -x[0] * s + x[1] * c,
            ]
        },
        closed_form: None,
        driven: true,
        sweep: ("w", 4.0, HOOP_W),
        closed_form_with: None,
    },
    System {
        name: "parabola",
        scene: "scenes/parabola.toml",
        dim: 2,
        particles: &["bead"],
        masses: &[1.0],
        gravity: &[0.0, 500.0],
        coordinates: &["q"],
        length: 150.0,
        speed: 475.0,
        map: |q, _| vec![q[0], -q[0] * q[0] / 100.0],
        velocity: |q, d, _| vec![d[0], -q[0] * d[0] / 50.0],
        constraints: |x, _| vec![x[0] * x[0] + 100.0 * x[1]],
        closed_form: None,
        driven: false,
        sweep: ("g", 400.0, 500.0),
        closed_form_with: None,
    },
    System {
        name: "double-pendulum",
        scene: "scenes/double-pendulum.toml",
        dim: 2,
        particles: &["a", "b"],
        masses: &[1.0, 1.0],
        gravity: &[0.0, 9.81],
        coordinates: &["theta1", "theta2"],
        length: 1.0,
        speed: 5.0,
        map: |q, _| {
            let (a, b) = (q[0].sin_cos(), q[1].sin_cos());
            vec![a.0, a.1, a.0 + b.0, a.1 + b.1]
        },
        velocity: |q, d, _| {
            let (a, b) = (q[0].sin_cos(), q[1].sin_cos());
            let va = [a.1 * d[0], -a.0 * d[0]];
            vec![va[0], va[1], va[0] + b.1 * d[1], va[1] - b.0 * d[1]]
        },
        constraints: |x, _| {
            let (dx, dy) = (x[2] - x[0], x[3] - x[1]);
            vec![
                (x[0] * x[0] + x[1] * x[1] - 1.0) / 2.0,
                (dx * dx + dy * dy - 1.0) / 2.0,
            ]
        },
        closed_form: None,
        driven: false,
        sweep: ("m2", 0.5, 1.0),
        closed_form_with: None,
    },
];
