//! [`Trajectory`]: a run's recorded samples held in memory, one flat vector per quantity.

use crate::simulate::{Sample, Sink};

/// Every sample a run records, row after row, in flat vectors (row-major): what a front end
/// turns into arrays (Python's `Run`, a sweep member's trajectory) without a copy.
///
/// Per row: `t`, `energy`, `constraint_error` (one each), `x` and `xdot` (the particles'
/// coordinates), `q` and `qdot` (`k` each: the formulation's coordinates; none when `k` is
/// 0) and `work` (one, while the energy ledger runs).
///
/// ```
/// use bead::output::Trajectory;
/// use bead::scene::Scene;
/// use bead::simulate::{run, RunOptions, Simulation, SimulationConfig};
/// let scene = Scene::parse(
///     "[world]\ngravity = [0.0, 10.0]\n[[particle]]\nname = \"ball\"\nmass = 1.0\nposition = [0.0, 0.0]\n",
///     "ball.toml",
///     &[],
/// )?;
/// let config = SimulationConfig { dt: 0.1, ..Default::default() };
/// let mut simulation = Simulation::new(scene.system.clone(), config)?;
/// let mut rows = Trajectory::with_room(11, 2, 0, false);
/// run(&mut simulation, RunOptions::steps(10), &mut rows)?;
/// assert_eq!(rows.rows(), 11);
/// // Free fall from rest: y = 5 t^2.
/// assert!((rows.x[2 * 10 + 1] - 5.0).abs() < 1e-12);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectory {
    pub t: Vec<f64>,
    pub x: Vec<f64>,
    pub xdot: Vec<f64>,
    pub energy: Vec<f64>,
    pub constraint_error: Vec<f64>,
    pub q: Vec<f64>,
    pub qdot: Vec<f64>,
    pub work: Vec<f64>,
    /// Formulation coordinates recorded per row (0: none).
    k: usize,
}

impl Trajectory {
    /// An empty trajectory with room for `rows` rows of `coordinates` particle coordinates
    /// and `k` formulation coordinates (0 to record none), and the ledger's work when
    /// `work`, reserved up front so that no vector moves while it grows (the peak is then
    /// the rows themselves). When the system will not reserve that much at once (a run may
    /// stop long before its end), they grow as needed.
    pub fn with_room(rows: u64, coordinates: usize, k: usize, work: bool) -> Trajectory {
        let rows = usize::try_from(rows).unwrap_or(usize::MAX);
        let room = |per_row: usize| {
            let mut v = Vec::new();
            let wanted = rows.saturating_mul(per_row);
            if v.try_reserve_exact(wanted).is_err() {
                v.reserve(wanted.min(1 << 16));
            }
            v
        };
        Trajectory {
            t: room(1),
            x: room(coordinates),
            xdot: room(coordinates),
            energy: room(1),
            constraint_error: room(1),
            q: room(k),
            qdot: room(k),
            work: if work { room(1) } else { Vec::new() },
            k,
        }
    }

    /// The rows recorded.
    pub fn rows(&self) -> usize {
        self.t.len()
    }

    /// Formulation coordinates per row (0 when q and qdot are not recorded).
    pub fn k(&self) -> usize {
        self.k
    }
}

impl Sink for Trajectory {
    fn record(&mut self, sample: &Sample) -> std::io::Result<()> {
        self.t.push(sample.t);
        self.x.extend_from_slice(sample.x);
        self.xdot.extend_from_slice(sample.xdot);
        self.energy.push(sample.energy);
        self.constraint_error.push(sample.constraint_error);
        if self.k > 0 {
            self.q.extend_from_slice(sample.q);
            self.qdot.extend_from_slice(sample.qdot);
        }
        if let Some(w) = sample.work {
            self.work.push(w);
        }
        Ok(())
    }
}
