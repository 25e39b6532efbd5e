//! Applied forces. Each knows how to add itself to the force vector and, when conservative,
//! its potential energy.

use super::ParticleId;

/// The far end of a spring or rod: another particle or a fixed point in space.
#[derive(Clone, Debug, PartialEq)]
pub enum Endpoint {
    Particle(ParticleId),
    /// A fixed point (dim).
    Fixed(Vec<f64>),
}

impl Endpoint {
    /// Position of the endpoint, axis `a`, in configuration `x`.
    pub(crate) fn coord(&self, dim: usize, x: &[f64], a: usize) -> f64 {
        match self {
            Endpoint::Particle(p) => x[p.0 * dim + a],
            Endpoint::Fixed(point) => point[a],
        }
    }
}

/// An applied force (gravity is a property of the world, see [`super::System::gravity`]).
#[derive(Clone, Debug, PartialEq)]
pub enum Force {
    /// A constant force F on one particle; potential V = -F.x.
    Constant {
        particle: ParticleId,
        vector: Vec<f64>,
    },
    /// Linear spring between `a` and `b`: F_a = -k (|d| - L) d/|d|, d = x_a - x_b, F_b = -F_a;
    /// potential V = k (|d| - L)^2 / 2. At |d| = 0 the direction is undefined and the force is 0.
    Spring {
        a: ParticleId,
        b: Endpoint,
        stiffness: f64,
        rest_length: f64,
    },
    /// Linear drag F = -c v on one particle, or on all when `particle` is `None`. Dissipative.
    Drag {
        particle: Option<ParticleId>,
        coefficient: f64,
    },
}

impl Force {
    /// Add this force to `force` (n_coords) at positions `x`, velocities `v`.
    pub(crate) fn accumulate(&self, dim: usize, x: &[f64], v: &[f64], force: &mut [f64]) {
        match self {
            Force::Constant { particle, vector } => {
                for (a, f) in vector.iter().enumerate() {
                    force[particle.0 * dim + a] += f;
                }
            }
            Force::Spring {
                a,
                b,
                stiffness,
                rest_length,
            } => {
                let mut d = [0.0; 3];
                for (axis, d) in d.iter_mut().enumerate().take(dim) {
                    *d = x[a.0 * dim + axis] - b.coord(dim, x, axis);
                }
                let length = d.iter().map(|c| c * c).sum::<f64>().sqrt();
                if length == 0.0 {
                    return;
                }
                let scale = -stiffness * (length - rest_length) / length;
                for (axis, d) in d.iter().enumerate().take(dim) {
                    force[a.0 * dim + axis] += scale * d;
                    if let Endpoint::Particle(pb) = b {
                        force[pb.0 * dim + axis] -= scale * d;
                    }
                }
            }
            Force::Drag {
                particle,
                coefficient,
            } => match particle {
                Some(p) => {
                    for axis in 0..dim {
                        force[p.0 * dim + axis] -= coefficient * v[p.0 * dim + axis];
                    }
                }
                None => {
                    for (f, v) in force.iter_mut().zip(v) {
                        *f -= coefficient * v;
                    }
                }
            },
        }
    }

    /// Potential energy V(x); 0 for dissipative forces.
    pub(crate) fn potential(&self, dim: usize, x: &[f64]) -> f64 {
        match self {
            Force::Constant { particle, vector } => -(0..dim)
                .map(|a| vector[a] * x[particle.0 * dim + a])
                .sum::<f64>(),
            Force::Spring {
                a,
                b,
                stiffness,
                rest_length,
            } => {
                let length = (0..dim)
                    .map(|axis| {
                        let d = x[a.0 * dim + axis] - b.coord(dim, x, axis);
                        d * d
                    })
                    .sum::<f64>()
                    .sqrt();
                0.5 * stiffness * (length - rest_length).powi(2)
            }
            Force::Drag { .. } => 0.0,
        }
    }

    /// Whether the force derives from a potential (drag does not).
    pub fn is_conservative(&self) -> bool {
        // A drag of coefficient 0 (a damping slider at 0) is no force and does no work.
        !matches!(self, Force::Drag { coefficient, .. } if *coefficient != 0.0)
    }

    /// Whether the force depends on the velocities (drag does).
    pub fn depends_on_velocity(&self) -> bool {
        matches!(self, Force::Drag { .. })
    }

    /// Its power F . v at positions `x` and velocities `v` (n_coords each).
    pub(crate) fn power(&self, dim: usize, x: &[f64], v: &[f64]) -> f64 {
        match self {
            Force::Constant { particle, vector } => {
                (0..dim).map(|a| vector[a] * v[particle.0 * dim + a]).sum()
            }
            Force::Spring {
                a,
                b,
                stiffness,
                rest_length,
            } => {
                let mut d = [0.0; 3];
                let mut dv = [0.0; 3];
                for axis in 0..dim {
                    d[axis] = x[a.0 * dim + axis] - b.coord(dim, x, axis);
                    dv[axis] = v[a.0 * dim + axis]
                        - match b {
                            Endpoint::Particle(pb) => v[pb.0 * dim + axis],
                            Endpoint::Fixed(_) => 0.0,
                        };
                }
                let length = d.iter().map(|c| c * c).sum::<f64>().sqrt();
                if length == 0.0 {
                    return 0.0;
                }
                // F_a . v_a + F_b . v_b = F_a . (v_a - v_b).
                let scale = -stiffness * (length - rest_length) / length;
                (0..dim).map(|axis| scale * d[axis] * dv[axis]).sum()
            }
            Force::Drag {
                particle,
                coefficient,
            } => match particle {
                Some(p) => {
                    -coefficient
                        * (0..dim)
                            .map(|axis| v[p.0 * dim + axis].powi(2))
                            .sum::<f64>()
                }
                None => -coefficient * v.iter().map(|v| v * v).sum::<f64>(),
            },
        }
    }

    /// A short description for messages, e.g. `drag on bead`.
    pub(crate) fn describe(&self, particles: &[super::Particle]) -> String {
        let name = |p: &super::ParticleId| {
            particles
                .get(p.0)
                .map(|p| format!("`{}`", p.name))
                .unwrap_or_else(|| format!("particle #{}", p.0))
        };
        match self {
            Force::Constant { particle, .. } => format!("constant force on {}", name(particle)),
            Force::Spring { a, b, .. } => match b {
                Endpoint::Particle(b) => format!("spring between {} and {}", name(a), name(b)),
                Endpoint::Fixed(_) => format!("spring from {} to a fixed point", name(a)),
            },
            Force::Drag {
                particle: Some(p), ..
            } => format!("drag on {}", name(p)),
            Force::Drag { particle: None, .. } => "drag on every particle".into(),
        }
    }
}
