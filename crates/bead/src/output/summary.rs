//! The summary of a run as a serializable record.

use serde::ser::{SerializeMap, SerializeSeq};
use serde::{Serialize, Serializer};

use crate::formulation::Method;
use crate::integrate::IntegratorKind;
use crate::model::System;
use crate::simulate::{RunFailure, RunStats};

/// The figures of one run, complete or stopped early, as written by `bead run --json`.
///
/// Serialized (e.g. with `serde_json`) it has exactly these keys, in this order:
///
/// | key | value |
/// |---|---|
/// | `scene` | the scene file as given |
/// | `method` | `"implicit"` or `"parametric"` |
/// | `integrator` | e.g. `"rk4"` |
/// | `dt` | step size (s) |
/// | `steps` | integrator steps taken (adaptive runs: accepted steps) |
/// | `accepted_steps`, `rejected_steps` | adaptive runs (dopri5) only: the integrator's own steps |
/// | `t_final` | time of the last good state (s) |
/// | `wall_seconds`, `steps_per_second` | wall time and speed |
/// | `energy_initial`, `energy_final` | total mechanical energy T + V |
/// | `energy_rel_error_max` | max over the run of \|E - E0\| / `energy_scale` |
/// | `energy_scale` | E_scale = max(\|E0\|, T0 + \|V0\|, T0 + M \|g\| L) (see [`RunStats`]) |
/// | `energy_conserved` | whether T + V is conserved (nothing does work on the system) |
/// | `energy_not_conserved_by` | when it is not: what does work, e.g. `["drag on \`bead\`"]` |
/// | `work_final` | when the energy ledger ran: the work W done on T + V by the end |
/// | `energy_balance_error_max` | when the ledger ran: max of \|E - W - E0\| / `energy_scale`, the error of the conserved quantity |
/// | `constraint_error_max`, `constraint_error_final` | max_i \|C_i\| over the run and at the end |
/// | `constraint_distance_max`, `constraint_distance_final` | implicit form only: max_i \|C_i\| / \|grad C_i\| over the run and at the end, how far the state is off the constraints in length units |
/// | `length_scale` | the scene's length scale (the largest initial coordinate magnitude), to read the distance against |
/// | `projected` | only when `--project` was on: `true` |
/// | `newton_iterations_max` | rattle, rattle4, fast-projection or `--project` only: most Newton iterations of any one solve (a step, a substep, a rattle4 stage, a projection) |
/// | `newton_iterations` | the same only: Newton iterations of all solves, substeps, stages and retried attempts included |
/// | `substeps` | only when more than 1: substeps per step of dt asked for (`--substeps`) |
/// | `substeps_max` | only when more than 1: the most substeps any step took, those RATTLE's stability asked for and retries included |
/// | `retried_steps` | only when some were: steps retried with more substeps because an iteration did not converge |
/// | `stop_when` | the stop condition as written (`null` when none) |
/// | `stop_time` | the time the stop condition fired and the run ended (`null` when it did not) |
/// | `contacts` | only with unilateral constraints: `{"detaches": n, "landings": n, "bounces": n, "dissipated": J}`, the switches and the kinetic energy the impacts took |
/// | `events` | only when events were watched: `[{"when": EXPR, "direction": 1, -1 or 0, "terminal": bool, "times": [..]}]`, the times each crossed |
/// | `particles` | `{NAME: {"position": [..], "velocity": [..]}}` at the end, in particle order |
/// | `coordinates` | parametric runs only: `{NAME: [q, qdot]}` at the end, in coordinate order |
/// | `error` | only when the run stopped early: why |
/// | `completed` | whether every requested step ran |
///
/// Numbers are written exactly (shortest round-trip). JSON has no NaN or infinity, so a
/// non-finite number (e.g. the energy of a run that blew up) is written as `null`, whatever
/// the serializer.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// The scene file as given.
    pub scene: String,
    /// The formulation that ran.
    pub method: Method,
    #[serde(serialize_with = "integrator_name")]
    /// The integrator that ran (serialized by name).
    pub integrator: IntegratorKind,
    /// Step size (s).
    #[serde(serialize_with = "number")]
    pub dt: f64,
    /// Steps completed.
    pub steps: u64,
    /// Adaptive runs only: integrator steps accepted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accepted_steps: Option<u64>,
    /// Adaptive runs only: integrator step attempts rejected.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rejected_steps: Option<u64>,
    #[serde(serialize_with = "number")]
    /// Time of the last good state (s).
    pub t_final: f64,
    #[serde(serialize_with = "number")]
    /// Wall time of the run (s).
    pub wall_seconds: f64,
    #[serde(serialize_with = "number")]
    /// Steps per second of wall time.
    pub steps_per_second: f64,
    #[serde(serialize_with = "number")]
    /// Total mechanical energy T + V at t = 0.
    pub energy_initial: f64,
    #[serde(serialize_with = "number")]
    /// Total mechanical energy at the end.
    pub energy_final: f64,
    #[serde(serialize_with = "number")]
    /// Max relative energy error over the run (see [`RunStats::energy_rel_error_max`]).
    pub energy_rel_error_max: f64,
    /// The denominator of the relative energy errors (see [`RunStats::energy_scale`]).
    #[serde(serialize_with = "number")]
    pub energy_scale: f64,
    /// Whether T + V is conserved.
    pub energy_conserved: bool,
    /// What does work on the system, when T + V is not conserved.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub energy_not_conserved_by: Vec<String>,
    /// The work W done on T + V by the end, when the energy ledger ran.
    #[serde(
        skip_serializing_if = "Option::is_none",
        serialize_with = "optional_number"
    )]
    pub work_final: Option<f64>,
    /// Max of |E - W - E0| / E_scale, when the energy ledger ran.
    #[serde(
        skip_serializing_if = "Option::is_none",
        serialize_with = "optional_number"
    )]
    pub energy_balance_error_max: Option<f64>,
    #[serde(serialize_with = "number")]
    /// max_i |C_i| over the run.
    pub constraint_error_max: f64,
    #[serde(serialize_with = "number")]
    /// max_i |C_i| at the end.
    pub constraint_error_final: f64,
    /// The implicit form: max_i |C_i| / |grad C_i| over the run (a distance).
    #[serde(
        skip_serializing_if = "Option::is_none",
        serialize_with = "optional_number"
    )]
    pub constraint_distance_max: Option<f64>,
    /// The implicit form: max_i |C_i| / |grad C_i| at the end.
    #[serde(
        skip_serializing_if = "Option::is_none",
        serialize_with = "optional_number"
    )]
    pub constraint_distance_final: Option<f64>,
    /// The scene's length scale (see [`RunStats::length_scale`]).
    #[serde(serialize_with = "number")]
    pub length_scale: f64,
    /// Whether positions and velocities were projected onto the constraints after every step
    /// (written only when true).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub projected: bool,
    /// Most Newton iterations any one solve needed (a step, substep or rattle4 stage of the
    /// integrator's own solve; the projection).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub newton_iterations_max: Option<usize>,
    /// Newton iterations of all steps, of the same solves (see
    /// [`crate::simulate::Simulation::newton_iterations_total`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub newton_iterations: Option<u64>,
    /// Substeps per step of dt as asked (written only when more than 1).
    #[serde(skip_serializing_if = "is_one")]
    pub substeps: u32,
    /// The most substeps any step took, those RATTLE's stability asked for and retries
    /// included (written only when more than 1).
    #[serde(skip_serializing_if = "is_one")]
    pub substeps_max: u32,
    /// Steps retried with more substeps because an iteration did not converge (written only
    /// when some were).
    #[serde(skip_serializing_if = "is_zero")]
    pub retried_steps: u64,
    /// With unilateral constraints: their switches, counted (written only then).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contacts: Option<crate::simulate::ContactCounts>,
    /// The stop condition watched, as written (`null` when none).
    pub stop_when: Option<String>,
    /// The time the stop condition fired, which ended the run (`null` when it did not).
    #[serde(serialize_with = "optional_number")]
    pub stop_time: Option<f64>,
    /// Every watched event with its crossing times (written only when there are events).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<EventTimes>,
    /// Final particle states, in particle order.
    pub particles: ParticleStates,
    #[serde(skip_serializing_if = "Option::is_none")]
    /// Final generalized coordinates of a parametric run.
    pub coordinates: Option<CoordinateStates>,
    #[serde(skip_serializing_if = "Option::is_none")]
    /// Why the run stopped early, if it did.
    pub error: Option<String>,
    /// Whether every requested step ran.
    pub completed: bool,
}

/// Final position and velocity of one particle (dim each).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParticleState {
    /// Position (dim).
    #[serde(serialize_with = "numbers")]
    pub position: Vec<f64>,
    /// Velocity (dim).
    #[serde(serialize_with = "numbers")]
    pub velocity: Vec<f64>,
}

/// Particle states by name, serialized as a map in particle order.
/// A watched event and its crossing times, as `bead run --json` writes it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EventTimes {
    /// The expression as written.
    pub when: String,
    /// +1 (upward crossings), -1 (downward) or 0 (either), as scipy writes it.
    pub direction: i8,
    /// Whether a crossing ends the run.
    pub terminal: bool,
    /// The crossing times, in order.
    #[serde(serialize_with = "numbers")]
    pub times: Vec<f64>,
}

#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParticleStates(pub Vec<(String, ParticleState)>);

/// Generalized coordinates by name with their value and rate `[q, qdot]`, serialized as a map
/// in coordinate order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CoordinateStates(pub Vec<(String, [f64; 2])>);

impl Summary {
    /// The summary of a completed run of `system` from scene file `scene`. `coordinates` are
    /// the generalized coordinates' names of a parametric run (matching `stats.q`), empty for
    /// the implicit form.
    pub fn new(scene: &str, system: &System, coordinates: &[String], stats: &RunStats) -> Summary {
        let dim = system.dim().max(1);
        let particles = system
            .particles()
            .iter()
            .zip(stats.x.chunks(dim).zip(stats.xdot.chunks(dim)))
            .map(|(p, (x, v))| {
                (
                    p.name.clone(),
                    ParticleState {
                        position: x.to_vec(),
                        velocity: v.to_vec(),
                    },
                )
            })
            .collect();
        let coordinates = (!coordinates.is_empty()).then(|| {
            CoordinateStates(
                coordinates
                    .iter()
                    .zip(stats.q.iter().zip(&stats.qdot))
                    .map(|(name, (&q, &qdot))| (name.clone(), [q, qdot]))
                    .collect(),
            )
        });
        Summary {
            scene: scene.to_string(),
            method: stats.method,
            integrator: stats.integrator,
            dt: stats.dt,
            steps: stats.steps,
            accepted_steps: stats.accepted_steps,
            rejected_steps: stats.rejected_steps,
            t_final: stats.t_final,
            wall_seconds: stats.wall_seconds,
            steps_per_second: stats.steps_per_second(),
            energy_initial: stats.energy_initial,
            energy_final: stats.energy_final,
            energy_rel_error_max: stats.energy_rel_error_max,
            energy_scale: stats.energy_scale,
            energy_conserved: stats.energy_conserved,
            energy_not_conserved_by: stats
                .nonconservation
                .iter()
                .map(|n| n.to_string())
                .collect(),
            work_final: stats.work_final,
            energy_balance_error_max: stats.energy_balance_error_max,
            constraint_error_max: stats.constraint_error_max,
            constraint_error_final: stats.constraint_error_final,
            constraint_distance_max: stats.constraint_distance_max,
            constraint_distance_final: stats.constraint_distance_final,
            length_scale: stats.length_scale,
            projected: stats.projected,
            newton_iterations_max: stats.newton_iterations_max,
            newton_iterations: stats.newton_iterations,
            substeps: stats.substeps,
            substeps_max: stats.substeps_max,
            retried_steps: stats.retried_steps,
            contacts: stats.contacts.clone(),
            stop_when: stats.stop_when.clone(),
            stop_time: stats.stop_time,
            events: stats
                .events
                .iter()
                .map(|e| EventTimes {
                    when: e.when.clone(),
                    direction: e.direction.sign(),
                    terminal: e.terminal,
                    times: e.times.clone(),
                })
                .collect(),
            particles: ParticleStates(particles),
            coordinates,
            error: None,
            completed: true,
        }
    }

    /// The summary of a run's outcome: complete, or stopped early with the figures up to the
    /// last good state, `completed: false` and the reason in `error`.
    pub fn from_result(
        scene: &str,
        system: &System,
        coordinates: &[String],
        result: &Result<RunStats, RunFailure>,
    ) -> Summary {
        match result {
            Ok(stats) => Summary::new(scene, system, coordinates, stats),
            Err(failure) => {
                let mut summary = Summary::new(scene, system, coordinates, &failure.stats);
                summary.error = Some(failure.error.to_string());
                summary.completed = false;
                summary
            }
        }
    }

    /// The largest relative error of what the system conserves: `energy_balance_error_max`
    /// (of E - W) when energy is not conserved, else `energy_rel_error_max`.
    pub fn conserved_energy_error_max(&self) -> f64 {
        match (self.energy_conserved, self.energy_balance_error_max) {
            (false, Some(balance)) => balance,
            _ => self.energy_rel_error_max,
        }
    }

    /// Whether the energy figure understates the run's error: the state went off the
    /// constraints by more than 1e-6 of the scene's size and by more than ten times the
    /// conserved energy's relative error. The energy is then that of a state off the curve,
    /// and a small energy error says nothing about accuracy (implicit verlet on the spinning
    /// hoop conserves E - W to 3e-6 while the bead leaves the hoop by 0.2 of its radius).
    pub fn energy_hides_constraint_error(&self) -> bool {
        let Some(distance) = self.constraint_distance_max else {
            return false;
        };
        let relative = distance / self.length_scale;
        relative > 1e-6 && relative > 10.0 * self.conserved_energy_error_max()
    }

    /// What does work on the system, for text: `driven constraint: plane depends on t, drag on
    /// \`bead\``.
    pub fn nonconservation_text(&self) -> String {
        self.energy_not_conserved_by.join(", ")
    }

    /// Pretty-printed JSON.
    pub fn to_json_pretty(&self) -> serde_json::Result<String> {
        serde_json::to_string_pretty(self)
    }
}

impl Serialize for ParticleStates {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for (name, state) in &self.0 {
            map.serialize_entry(name, state)?;
        }
        map.end()
    }
}

impl Serialize for CoordinateStates {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for (name, pair) in &self.0 {
            map.serialize_entry(name, &Numbers(pair))?;
        }
        map.end()
    }
}

/// A number, or `null` when it is not finite.
struct Number(f64);

impl Serialize for Number {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        if self.0.is_finite() {
            serializer.serialize_f64(self.0)
        } else {
            serializer.serialize_none()
        }
    }
}

/// A list of [`Number`]s.
struct Numbers<'a>(&'a [f64]);

impl Serialize for Numbers<'_> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut seq = serializer.serialize_seq(Some(self.0.len()))?;
        for &x in self.0 {
            seq.serialize_element(&Number(x))?;
        }
        seq.end()
    }
}

fn number<S: Serializer>(x: &f64, serializer: S) -> Result<S::Ok, S::Error> {
    Number(*x).serialize(serializer)
}

fn is_one(n: &u32) -> bool {
    *n == 1
}

fn is_zero(n: &u64) -> bool {
    *n == 0
}

fn optional_number<S: Serializer>(x: &Option<f64>, serializer: S) -> Result<S::Ok, S::Error> {
    Number(x.unwrap_or(f64::NAN)).serialize(serializer)
}

fn numbers<S: Serializer>(x: &[f64], serializer: S) -> Result<S::Ok, S::Error> {
    Numbers(x).serialize(serializer)
}

fn integrator_name<S: Serializer>(kind: &IntegratorKind, serializer: S) -> Result<S::Ok, S::Error> {
    serializer.serialize_str(kind.name())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::SystemBuilder;
    use crate::simulate::RunError;

    /// The keys of an implicit run (a parametric one has no `constraint_distance_*`).
    const KEYS: [&str; 21] = [
        "scene",
        "method",
        "integrator",
        "dt",
        "steps",
        "t_final",
        "wall_seconds",
        "steps_per_second",
        "energy_initial",
        "energy_final",
        "energy_rel_error_max",
        "energy_scale",
        "energy_conserved",
        "constraint_error_max",
        "constraint_error_final",
        "constraint_distance_max",
        "constraint_distance_final",
        "length_scale",
        "stop_when",
        "stop_time",
        "particles",
    ];

    fn system() -> System {
        let mut b = SystemBuilder::new(&[0.0, -9.81]);
        b.particle("b", 1.0, &[0.0, 0.0], &[0.0, 0.0]).unwrap();
        b.particle("a", 2.0, &[1.0, 0.0], &[0.0, 0.0]).unwrap();
        b.build().unwrap()
    }

    fn stats(method: Method) -> RunStats {
        RunStats {
            method,
            integrator: IntegratorKind::Rk4,
            dt: 0.5,
            steps: 4,
            t_final: 2.0,
            wall_seconds: 0.5,
            energy_initial: -1.0,
            energy_final: -1.5,
            energy_rel_error_max: 0.5,
            energy_scale: 2.0,
            energy_conserved: true,
            nonconservation: Vec::new(),
            work_final: None,
            energy_balance_error_max: None,
            constraint_error_max: 1e-3,
            constraint_error_final: 1e-4,
            constraint_distance_max: (method == Method::Implicit).then_some(2e-3),
            constraint_distance_final: (method == Method::Implicit).then_some(2e-4),
            length_scale: 2.0,
            x: vec![1.0, 2.0, 3.0, 4.0],
            xdot: vec![5.0, 6.0, 7.0, 8.0],
            q: vec![0.25, 0.75],
            qdot: vec![-1.0, -2.0],
            accepted_steps: None,
            rejected_steps: None,
            projected: false,
            newton_iterations_max: None,
            newton_iterations: None,
            substeps: 1,
            substeps_max: 1,
            retried_steps: 0,
            stop_when: None,
            stop_time: None,
            contacts: None,
            events: Vec::new(),
        }
    }

    fn keys(json: &str) -> Vec<String> {
        // Top-level keys in written order (serde_json::Value would sort them).
        json.lines()
            .filter(|l| l.starts_with("  \"") && !l.starts_with("   "))
            .map(|l| {
                l.trim_start()
                    .trim_start_matches('"')
                    .split('"')
                    .next()
                    .unwrap_or("")
                    .to_string()
            })
            .collect()
    }

    #[test]
    fn implicit_summary_has_exactly_the_documented_keys_in_order() {
        let summary = Summary::new("s.toml", &system(), &[], &stats(Method::Implicit));
        let json = summary.to_json_pretty().unwrap();
        let mut expected: Vec<String> = KEYS.iter().map(|k| k.to_string()).collect();
        expected.push("completed".into());
        assert_eq!(keys(&json), expected);
        let value: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(value["method"], "implicit");
        assert_eq!(value["integrator"], "rk4");
        assert_eq!(value["steps_per_second"], 8.0);
        assert_eq!(value["completed"], true);
        assert_eq!(
            value["particles"]["a"]["position"],
            serde_json::json!([3.0, 4.0])
        );
        assert_eq!(
            value["particles"]["b"]["velocity"],
            serde_json::json!([5.0, 6.0])
        );
    }

    #[test]
    fn adaptive_summary_adds_step_counts_after_steps() {
        let mut s = stats(Method::Implicit);
        s.integrator = IntegratorKind::Dopri5;
        s.accepted_steps = Some(120);
        s.rejected_steps = Some(3);
        let json = Summary::new("s.toml", &system(), &[], &s)
            .to_json_pretty()
            .unwrap();
        let mut expected: Vec<String> = KEYS.iter().map(|k| k.to_string()).collect();
        expected.insert(5, "accepted_steps".into());
        expected.insert(6, "rejected_steps".into());
        expected.push("completed".into());
        assert_eq!(keys(&json), expected);
        let value: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(value["integrator"], "dopri5");
        assert_eq!(value["accepted_steps"], 120);
        assert_eq!(value["rejected_steps"], 3);
    }

    #[test]
    fn a_driven_run_says_energy_is_not_conserved_and_gives_the_balance_error() {
        let mut s = stats(Method::Implicit);
        s.energy_conserved = false;
        s.nonconservation = vec![crate::formulation::Nonconservation::DrivenConstraint(
            "hoop".into(),
        )];
        s.work_final = Some(2.5);
        s.energy_balance_error_max = Some(1e-9);
        let json = Summary::new("s.toml", &system(), &[], &s)
            .to_json_pretty()
            .unwrap();
        let mut expected: Vec<String> = KEYS.iter().map(|k| k.to_string()).collect();
        let at = expected
            .iter()
            .position(|k| k == "energy_conserved")
            .unwrap()
            + 1;
        for (i, key) in [
            "energy_not_conserved_by",
            "work_final",
            "energy_balance_error_max",
        ]
        .iter()
        .enumerate()
        {
            expected.insert(at + i, key.to_string());
        }
        expected.push("completed".into());
        assert_eq!(keys(&json), expected);
        let value: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(value["energy_conserved"], false);
        assert_eq!(
            value["energy_not_conserved_by"],
            serde_json::json!(["driven constraint: hoop depends on t"])
        );
        assert_eq!(value["energy_balance_error_max"], 1e-9);
    }

    #[test]
    fn particles_keep_their_order() {
        let json = Summary::new("s.toml", &system(), &[], &stats(Method::Implicit))
            .to_json_pretty()
            .unwrap();
        let b = json.find("\"b\"").unwrap();
        let a = json.find("\"a\"").unwrap();
        assert!(b < a, "{json}");
    }

    #[test]
    fn parametric_summary_adds_coordinates() {
        let names = vec!["u".to_string(), "w".to_string()];
        let json = Summary::new("s.toml", &system(), &names, &stats(Method::Parametric))
            .to_json_pretty()
            .unwrap();
        let mut expected: Vec<String> = KEYS
            .iter()
            .filter(|k| !k.starts_with("constraint_distance"))
            .map(|k| k.to_string())
            .collect();
        expected.push("coordinates".into());
        expected.push("completed".into());
        assert_eq!(keys(&json), expected);
        let value: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(value["coordinates"]["u"], serde_json::json!([0.25, -1.0]));
        assert_eq!(value["coordinates"]["w"], serde_json::json!([0.75, -2.0]));
    }

    #[test]
    fn a_failed_run_has_error_and_is_not_completed_and_non_finite_numbers_are_null() {
        let mut s = stats(Method::Implicit);
        s.energy_final = f64::NAN;
        s.energy_rel_error_max = f64::INFINITY;
        s.x[0] = f64::NEG_INFINITY;
        let failure = RunFailure {
            error: RunError::Diverged {
                t: 1.5,
                step: 3,
                quantity: crate::simulate::Quantity::Position("b.y".into()),
                value: f64::NAN,
                limit: None,
            },
            stats: Box::new(s),
        };
        let summary = Summary::from_result("s.toml", &system(), &[], &Err(failure));
        let json = summary.to_json_pretty().unwrap();
        let mut expected: Vec<String> = KEYS.iter().map(|k| k.to_string()).collect();
        expected.push("error".into());
        expected.push("completed".into());
        assert_eq!(keys(&json), expected);
        let value: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(value["completed"], false);
        assert_eq!(value["error"], "diverged at t = 1.5 (step 3): b.y is NaN");
        assert!(value["energy_final"].is_null());
        assert!(value["energy_rel_error_max"].is_null());
        assert!(value["particles"]["b"]["position"][0].is_null());
    }
}
