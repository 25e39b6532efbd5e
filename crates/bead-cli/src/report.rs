//! Human-readable reports: the run summary, the comparison table and the scene description.
//! Everything here returns text; printing happens in the commands.

use std::fmt::Write as _;

use bead::expr::Expr;
use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::model::{Endpoint, ExprRow, Force, System};
use bead::output::Summary;
use bead::scene::{Generated, Scene, TableKind};
use bead::simulate::SetupError;

use crate::plan::Plan;

/// `x` with `sig` significant digits, in the shorter of fixed and exponent notation (like
/// C's `%g`); the report's formatter, so the report and the terminal print the same numbers.
pub use bead_report::report::sig as g;

/// `x` exactly (shortest round-trip), in exponent notation below 1e-4 and from 1e16 on in
/// magnitude so that extreme values stay short: `0.016666666666666666`, `1e300`. The
/// library's [`bead::readable`], so that the CLI and the library's messages (scene warnings,
/// errors) print a number the same way.
pub fn exact(x: f64) -> String {
    bead::readable(x)
}

/// A list of numbers as `[a, b]`, exact.
fn vector(v: &[f64]) -> String {
    let parts: Vec<String> = v.iter().map(|x| exact(*x)).collect();
    format!("[{}]", parts.join(", "))
}

/// The scene's title, or its file name when it has none.
pub fn title(scene: &Scene) -> &str {
    if scene.title.trim().is_empty() {
        &scene.file
    } else {
        &scene.title
    }
}

/// `rk4 (order 4, not symplectic)`.
pub fn integrator_text(kind: IntegratorKind) -> String {
    let described = kind.describe();
    let prefix = format!("{}: ", kind.name());
    match described.strip_prefix(&prefix) {
        Some(rest) => format!("{} ({rest})", kind.name()),
        None => described,
    }
}

fn method_blurb(method: Method) -> &'static str {
    match method {
        Method::Implicit => "constraint forces on the particle coordinates",
        Method::Parametric => "generalized coordinates",
    }
}

/// The human summary of one run.
pub fn run_text(scene: &Scene, plan: &Plan, summary: &Summary) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}", title(scene));
    let row = |s: &mut String, key: &str, value: String| {
        let _ = writeln!(s, "  {key:<12} {value}");
    };
    row(&mut s, "scene", scene.file.clone());
    row(
        &mut s,
        "method",
        format!(
            "{} ({})",
            summary.method.name(),
            method_blurb(summary.method)
        ),
    );
    if summary.method == Method::Implicit && plan.feedback != Default::default() {
        row(
            &mut s,
            "stabilize",
            format!(
                "ks = {}, kd = {}",
                exact(plan.feedback.ks),
                exact(plan.feedback.kd)
            ),
        );
    }
    row(&mut s, "integrator", integrator_text(summary.integrator));
    if summary.projected {
        row(
            &mut s,
            "projection",
            format!(
                "on: positions onto C = 0 (tolerance {} of each constraint's scale, a rod's length) and velocities onto J v = -C_t after every step",
                g(plan.settings.constraint_tolerance, 4)
            ),
        );
    }
    if let Some(c) = &summary.contacts {
        let count =
            |n: u64, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
        row(
            &mut s,
            "contacts",
            format!(
                "{}, {}, {} on the unilateral constraints; the impacts took {} of kinetic energy",
                count(c.detaches, "detach", "detaches"),
                count(c.landings, "landing", "landings"),
                count(c.bounces, "bounce", "bounces"),
                g(c.dissipated, 7)
            ),
        );
    }
    if summary.substeps_max > 1 || summary.retried_steps > 0 {
        row(
            &mut s,
            "substeps",
            format!(
                "{} per step of dt asked, at most {} taken; {} step(s) retried with more because an iteration did not converge",
                summary.substeps, summary.substeps_max, summary.retried_steps
            ),
        );
    }
    if let Some(iterations) = summary.newton_iterations_max {
        let total = match summary.newton_iterations {
            Some(total) if summary.steps > 0 => format!(
                ", {total} in all ({} per step)",
                g(total as f64 / summary.steps as f64, 3)
            ),
            _ => String::new(),
        };
        row(
            &mut s,
            "newton",
            format!("at most {iterations} Newton iteration(s) per solve{total}"),
        );
    }
    let adaptive = summary.accepted_steps.is_some();
    if let (Some(accepted), Some(rejected)) = (summary.accepted_steps, summary.rejected_steps) {
        // dopri5: dt is the output interval; its steps are its own (summary.steps = accepted).
        row(
            &mut s,
            "dt",
            format!("{} s, the output interval", exact(summary.dt)),
        );
        row(
            &mut s,
            "steps",
            format!(
                "{accepted} accepted steps, {rejected} rejected, chosen by {} (rtol {}, atol {})",
                summary.integrator.name(),
                exact(plan.settings.rtol),
                exact(plan.settings.atol)
            ),
        );
        // The run loop ends each interval exactly at t = k dt.
        let intervals = (summary.t_final / summary.dt).round() as u64;
        let output = if summary.completed {
            format!("{intervals} intervals of dt")
        } else {
            format!(
                "{intervals} of {} intervals of dt (stopped early)",
                plan.steps
            )
        };
        row(&mut s, "output", output);
    } else {
        row(&mut s, "dt", format!("{} s", exact(summary.dt)));
        let steps = if summary.completed {
            format!("{}", summary.steps)
        } else {
            format!("{} of {} (stopped early)", summary.steps, plan.steps)
        };
        row(&mut s, "steps", steps);
    }
    row(&mut s, "t_final", format!("{} s", exact(summary.t_final)));
    if let Some(condition) = &summary.stop_when {
        let outcome = match (summary.stop_time, &summary.error) {
            (Some(t), _) => format!("crossed zero at t = {} s; the run stopped there", exact(t)),
            (None, Some(_)) if !summary.completed => {
                "did not cross zero before the run failed (below)".to_string()
            }
            (None, _) => "did not cross zero".to_string(),
        };
        row(&mut s, "stop_when", format!("{condition}: {outcome}"));
    }
    // Events beyond a single stop condition: each with its crossing times.
    let lone_stop = summary.events.len() == 1 && summary.events[0].terminal;
    if !lone_stop {
        for (i, event) in summary.events.iter().enumerate() {
            row(&mut s, &format!("event {}", i + 1), event_line(event));
        }
    }
    if let (Some(duration), Some(last)) = (plan.duration, plan.last_step()) {
        let _ = writeln!(
            s,
            "  {:<12} duration {} s is not a whole number of steps of dt = {} s; the last step is {} s long and ends at t = {} s",
            "note",
            exact(duration),
            exact(plan.dt),
            exact(last),
            exact(plan.t_end())
        );
    }
    if summary.energy_conserved {
        row(
            &mut s,
            "energy",
            format!(
                "initial {}, final {}, max relative error {}",
                g(summary.energy_initial, 10),
                g(summary.energy_final, 10),
                g(summary.energy_rel_error_max, 4)
            ),
        );
    } else {
        row(
            &mut s,
            "energy",
            format!(
                "initial {}, final {}: not conserved ({})",
                g(summary.energy_initial, 10),
                g(summary.energy_final, 10),
                summary.nonconservation_text()
            ),
        );
        row(
            &mut s,
            "work",
            format!(
                "W = {} done on the system by the end; E - W is conserved to a max relative error of {}",
                g(summary.work_final.unwrap_or(f64::NAN), 10),
                g(summary.conserved_energy_error_max(), 4)
            ),
        );
    }
    let distance = match (
        summary.constraint_distance_max,
        summary.constraint_distance_final,
    ) {
        (Some(max), Some(last)) => format!(
            "; distance off them |C|/|grad C| up to {} ({} of the scene's size {}), {} at the end",
            g(max, 4),
            percent(max / summary.length_scale),
            g(summary.length_scale, 4),
            g(last, 4)
        ),
        _ => String::new(),
    };
    row(
        &mut s,
        "constraint",
        format!(
            "max error {}, final error {}{distance}",
            g(summary.constraint_error_max, 4),
            g(summary.constraint_error_final, 4)
        ),
    );
    if summary.energy_hides_constraint_error() {
        let _ = writeln!(
            s,
            "  {:<12} the energy error is small, but the state went off the constraints by {} of the scene's size: the energy is that of a state off the curve; neither figure alone measures accuracy",
            "note",
            percent(summary.constraint_distance_max.unwrap_or(f64::NAN) / summary.length_scale)
        );
    }
    row(
        &mut s,
        "speed",
        format!(
            "{} {}steps/s (wall time {} s)",
            g(summary.steps_per_second, 4),
            if adaptive { "accepted " } else { "" },
            g(summary.wall_seconds, 4)
        ),
    );
    s
}

/// A fraction as a percentage with 4 significant digits (`1.2%`, `3e-06%`).
fn percent(fraction: f64) -> String {
    format!("{}%", g(100.0 * fraction, 4))
}

/// The header line and aligned table of `bead compare`.
pub fn compare_text(scene: &Scene, plan: &Plan, summaries: &[Summary]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}", title(scene));
    let _ = writeln!(
        s,
        "  scene {}; integrator {}; dt {} s; {} {} to t = {} s",
        scene.file,
        integrator_text(plan.integrator),
        exact(plan.dt),
        plan.steps,
        if plan.integrator.is_adaptive() {
            "output intervals"
        } else {
            "steps"
        },
        exact(plan.t_end())
    );
    if let (Some(duration), Some(last)) = (plan.duration, plan.last_step()) {
        let _ = writeln!(
            s,
            "  note: duration {} s is not a whole number of steps; the last step is {} s long and ends at t = {} s",
            exact(duration),
            exact(last),
            exact(plan.t_end())
        );
    }
    // Feedback and the projection apply to the implicit run only: not mentioned without one.
    let implicit = summaries.iter().any(|r| r.method == Method::Implicit);
    if implicit && plan.feedback != Default::default() {
        let _ = writeln!(
            s,
            "  implicit form stabilized with ks = {}, kd = {}",
            exact(plan.feedback.ks),
            exact(plan.feedback.kd)
        );
    }
    if implicit && plan.project {
        let _ = writeln!(
            s,
            "  implicit form projected onto its constraints after every step (--project)"
        );
    }
    s.push('\n');
    let any_failed = summaries.iter().any(|r| !r.completed);
    let mut header = vec![
        "method",
        "final constraint error",
        "max constraint error",
        "max |C|/|grad C|",
        "max rel energy error",
        "final energy",
        "steps/s",
    ];
    // Adaptive runs (dopri5): the integrator's own steps.
    let adaptive = summaries.iter().any(|r| r.accepted_steps.is_some());
    if adaptive {
        header.push("accepted/rejected steps");
    }
    if any_failed {
        header.push("status");
    }
    let mut rows: Vec<Vec<String>> = vec![header.iter().map(|h| h.to_string()).collect()];
    for r in summaries {
        let mut row = vec![
            r.method.name().to_string(),
            g(r.constraint_error_final, 4),
            g(r.constraint_error_max, 4),
            r.constraint_distance_max
                .map(|d| g(d, 4))
                .unwrap_or_else(|| "-".into()),
            energy_cell(r),
            g(r.energy_final, 10),
            g(r.steps_per_second, 4),
        ];
        if adaptive {
            row.push(match (r.accepted_steps, r.rejected_steps) {
                (Some(accepted), Some(rejected)) => format!("{accepted}/{rejected}"),
                _ => "-".into(),
            });
        }
        if any_failed {
            row.push(if r.completed {
                "ok".into()
            } else {
                format!("stopped at t = {}", exact(r.t_final))
            });
        }
        rows.push(row);
    }
    s.push_str(&table(&rows));
    s.push_str(&energy_note(summaries));
    if adaptive {
        s.push_str(ADAPTIVE_NOTE);
        s.push('\n');
    }
    s
}

/// Under a table with adaptive runs: what their steps are.
pub const ADAPTIVE_NOTE: &str = "steps/s counts integrator steps; an adaptive integrator's are its accepted steps, and its dt is the output interval";

/// The energy error cell of a summary: of T + V, or of E - W (marked) when energy is not
/// conserved.
pub fn energy_cell(summary: &Summary) -> String {
    if summary.energy_conserved {
        g(summary.energy_rel_error_max, 4)
    } else {
        format!("{} (E-W)", g(summary.conserved_energy_error_max(), 4))
    }
}

/// The notes under a comparison table: runs whose energy is not conserved, and runs whose
/// small energy error hides a departure from the constraints (empty when neither).
pub fn energy_note(summaries: &[Summary]) -> String {
    let mut reasons: Vec<String> = Vec::new();
    for summary in summaries.iter().filter(|s| !s.energy_conserved) {
        for reason in &summary.energy_not_conserved_by {
            let labelled = format!("{}: {reason}", summary.method.name());
            if !reasons.contains(&labelled) {
                reasons.push(labelled);
            }
        }
    }
    let mut note = String::new();
    if !reasons.is_empty() {
        note = format!(
            "energy not conserved ({}): rows marked (E-W) give the error of E - W, the energy minus the work done on the system, which is conserved\n",
            reasons.join("; ")
        );
    }
    let hiding: Vec<String> = summaries
        .iter()
        .filter(|s| s.energy_hides_constraint_error())
        .map(|s| format!("{} {}", s.method.name(), s.integrator.name()))
        .collect();
    if !hiding.is_empty() {
        note.push_str(&format!(
            "{}: the energy error is small but the state left the constraints (max |C|/|grad C| against the scene's size): the energy is that of a state off the curve; neither figure alone measures accuracy\n",
            hiding.join(", ")
        ));
    }
    note
}

/// Rows of cells as an aligned table: the first column left-aligned, numbers right-aligned,
/// a rule under the header.
pub fn table(rows: &[Vec<String>]) -> String {
    let n_columns = rows.iter().map(Vec::len).max().unwrap_or(0);
    let widths: Vec<usize> = (0..n_columns)
        .map(|c| {
            rows.iter()
                .filter_map(|r| r.get(c))
                .map(|cell| cell.chars().count())
                .max()
                .unwrap_or(0)
        })
        .collect();
    let mut s = String::new();
    for (i, row) in rows.iter().enumerate() {
        let mut line = String::new();
        for (c, cell) in row.iter().enumerate() {
            let width = widths[c];
            if c == 0 {
                let _ = write!(line, "{cell:<width$}");
            } else if c + 1 == n_columns && rows[0].get(c).is_some_and(|h| h == "status") {
                let _ = write!(line, "   {cell:<width$}");
            } else {
                let _ = write!(line, "   {cell:>width$}");
            }
        }
        let _ = writeln!(s, "{}", line.trim_end());
        if i == 0 {
            let total: usize = widths.iter().sum::<usize>() + 3 * n_columns.saturating_sub(1);
            let _ = writeln!(s, "{}", "-".repeat(total));
        }
    }
    s
}

/// Name of a slot of a constraint expression: x (n), v (n), t.
fn constraint_slot_name(system: &System, slot: usize) -> String {
    bead::describe::constraint_slot_name(system, slot)
}

/// Name of a slot of a parametric map expression: q (n_q), qdot (n_q), t.
fn parametric_slot_name(coordinates: &[String], slot: usize) -> String {
    bead::describe::parametric_slot_name(coordinates, slot)
}

fn particle_name(system: &System, id: usize) -> String {
    system
        .particles()
        .get(id)
        .map(|p| p.name.clone())
        .unwrap_or_else(|| format!("#{id}"))
}

fn describe_force(system: &System, force: &Force) -> String {
    match force {
        Force::Constant {
            particle,
            vector: v,
        } => {
            format!(
                "constant force {} on {}",
                vector(v),
                particle_name(system, particle.0)
            )
        }
        Force::Spring {
            a,
            b,
            stiffness,
            rest_length,
        } => {
            let other = match b {
                Endpoint::Particle(p) => particle_name(system, p.0),
                Endpoint::Fixed(point) => format!("the point {}", vector(point)),
            };
            format!(
                "spring {} to {other}: stiffness {}, rest length {}",
                particle_name(system, a.0),
                exact(*stiffness),
                exact(*rest_length)
            )
        }
        Force::Drag {
            particle,
            coefficient,
        } => match particle {
            Some(p) => format!(
                "drag on {}: coefficient {}",
                particle_name(system, p.0),
                exact(*coefficient)
            ),
            None => format!(
                "drag on every particle: coefficient {}",
                exact(*coefficient)
            ),
        },
    }
}

fn plural(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// `e` as `bead check` prints it: numeric factors collected, at most
/// [`bead::describe::EXPRESSION_LIMIT`] characters (plus the last token and the count of what
/// is left; derivatives written out can be far larger than the scene). The library's
/// formatter, which the viewer's equations use too.
fn expression(e: &Expr, name: &dyn Fn(usize) -> String) -> String {
    bead::describe::expression(e, name)
}

/// What `bead check` found when it started each formulation of a scene as `bead run` starts
/// it (the library's own checks, [`bead::simulate::Simulation::new`]), without stepping.
pub struct StartCheck {
    /// The scene's `[run]` settings as `bead run` resolves them, or `bead run`'s error.
    pub plan: Result<Plan, String>,
    /// Each formulation the scene has (none when the plan failed) and whether it starts.
    pub forms: Vec<(Method, Result<(), SetupError>)>,
    /// The formulation `bead run` picks without `--method`.
    pub run_method: Method,
}

impl StartCheck {
    /// Every refusal, worded as `bead run` words it, the formulation named. A formulation
    /// other than the one `bead run` picks is held to its initial state only: that the
    /// scene's integrator or projection does not apply to it (rattle on the parametric form)
    /// is what `bead compare` skips with a note, not an error of the scene.
    pub fn errors(&self) -> Vec<String> {
        let mut errors = Vec::new();
        if let Err(e) = &self.plan {
            errors.push(e.clone());
        }
        for (method, result) in &self.forms {
            if let Err(e) = result {
                if self.only_not_applicable(*method, e) {
                    continue;
                }
                errors.push(format!("{} form: {}", method.name(), setup_error(e)));
            }
        }
        errors
    }

    /// Whether `e` only says that the scene's settings do not apply to `method`, a
    /// formulation `bead run` does not pick by default.
    fn only_not_applicable(&self, method: Method, e: &SetupError) -> bool {
        self.run_method != method && matches!(e, SetupError::Config(_))
    }

    /// The refusal of the implicit form for having more constraint rows than coordinates.
    fn over_constrained(&self) -> Option<&SetupError> {
        self.forms.iter().find_map(|(_, result)| match result {
            Err(e @ SetupError::OverConstrained { .. }) => Some(e),
            _ => None,
        })
    }
}

/// A setup error as `bead run` prints it (the error and its causes).
fn setup_error(e: &SetupError) -> String {
    format!("{:#}", anyhow::Error::from(e.clone()))
}

/// One line, or a run of elided lines, of a list in `bead check`.
enum Listed<'a> {
    /// The item with this index (a particle, force or declared constraint).
    Item(usize),
    /// `skipped` items made by the table `generated`, not listed.
    Elided {
        skipped: usize,
        generated: &'a Generated,
    },
}

impl Listed<'_> {
    /// The line that stands for an elided run (empty for an item).
    fn elided(&self) -> String {
        match self {
            Listed::Item(_) => String::new(),
            Listed::Elided { skipped, generated } => format!(
                "  ... {skipped} more made by {} {} (line {}: for {})\n",
                generated.kind.name(),
                generated.table,
                generated.line,
                generated.ranges
            ),
        }
    }
}

/// The `count` items of `kind` as `bead check` lists them: every one, except that of the
/// items a table with `for` made, more than [`bead::LISTED_NAMES`] are cut like
/// [`bead::name_list`] cuts names: the first ones, a line saying how many are left out, and
/// the last. So a generated scene of 10^4 particles prints a few lines per table.
fn listed(scene: &Scene, kind: TableKind, count: usize) -> Vec<Listed<'_>> {
    let mut out = Vec::new();
    let mut next = 0;
    for generated in scene.generated().iter().filter(|g| g.kind == kind) {
        let items = generated.items.clone();
        if items.len() <= bead::LISTED_NAMES || items.end > count {
            continue;
        }
        out.extend((next..items.start).map(Listed::Item));
        let shown = bead::LISTED_NAMES - 2;
        out.extend((items.start..items.start + shown).map(Listed::Item));
        out.push(Listed::Elided {
            skipped: items.len() - shown - 1,
            generated,
        });
        out.push(Listed::Item(items.end - 1));
        next = items.end;
    }
    out.extend((next..count).map(Listed::Item));
    out
}

/// The description printed by `bead check`, ending with whether each formulation starts.
pub fn check_text(scene: &Scene, start: &StartCheck) -> String {
    let system = &*scene.system;
    let mut s = String::new();
    let _ = writeln!(s, "{}", title(scene));
    let _ = writeln!(s, "  scene        {}", scene.file);
    let _ = writeln!(
        s,
        "  dimension    {}D, gravity {}",
        system.dim(),
        vector(system.gravity())
    );
    if !scene.params.is_empty() {
        let params: Vec<String> = scene
            .params
            .iter()
            .map(|(n, v)| {
                let unit = scene
                    .param_specs
                    .iter()
                    .find(|s| s.name == *n)
                    .and_then(|s| s.unit.as_deref())
                    .map(|u| format!(" {u}"))
                    .unwrap_or_default();
                format!("{n} = {}{unit}", exact(*v))
            })
            .collect();
        let _ = writeln!(s, "  parameters   {}", params.join(", "));
    }

    for (i, generated) in scene.generated().iter().enumerate() {
        let made = generated.items.len();
        let what = generated.kind.name();
        let _ = writeln!(
            s,
            "  {}{what} {} (line {}): {}, {}",
            if i == 0 {
                "generated    "
            } else {
                "             "
            },
            generated.table,
            generated.line,
            generated.ranges,
            plural(made, what, &format!("{what}s"))
        );
    }

    let particles = system.particles();
    let _ = writeln!(s, "\nparticles ({})", particles.len());
    let shown = listed(scene, TableKind::Particle, particles.len());
    let width = shown
        .iter()
        .filter_map(|l| match l {
            Listed::Item(p) => Some(particles[*p].name.chars().count()),
            Listed::Elided { .. } => None,
        })
        .max()
        .unwrap_or(0);
    for item in &shown {
        match item {
            Listed::Item(p) => {
                let p = &particles[*p];
                let _ = writeln!(
                    s,
                    "  {:<width$}  mass {}, position {}, velocity {}",
                    p.name,
                    exact(p.mass),
                    vector(&p.position),
                    vector(&p.velocity)
                );
            }
            Listed::Elided { .. } => s.push_str(&item.elided()),
        }
    }

    let _ = writeln!(
        s,
        "\nforces ({})",
        match system.forces().len() {
            0 => "gravity only".to_string(),
            n => format!("gravity and {}", plural(n, "other", "others")),
        }
    );
    let _ = writeln!(s, "  gravity {}", vector(system.gravity()));
    for item in listed(scene, TableKind::Force, system.forces().len()) {
        match item {
            Listed::Item(f) => {
                let _ = writeln!(s, "  {}", describe_force(system, &system.forces()[f]));
            }
            Listed::Elided { .. } => s.push_str(&item.elided()),
        }
    }

    let set = system.constraints();
    let _ = writeln!(
        s,
        "\nconstraints ({}, {})",
        set.n_declared(),
        plural(set.n_rows(), "row", "rows")
    );
    let name = |slot: usize| constraint_slot_name(system, slot);
    let (x0, v0) = system.initial_particle_state();
    let mut eval = set.workspace();
    if set.n_rows() > 0 {
        set.evaluate(0.0, &x0, &v0, &mut eval);
    }
    for item in listed(scene, TableKind::Constraint, set.n_declared()) {
        let info = match item {
            Listed::Item(c) => set.info(c),
            Listed::Elided { .. } => {
                s.push_str(&item.elided());
                continue;
            }
        };
        let rows = if info.rows.len() == 1 {
            format!("row {}", info.rows.start)
        } else {
            format!(
                "rows {}..{}",
                info.rows.start,
                info.rows.end.saturating_sub(1)
            )
        };
        let _ = writeln!(s, "  {}: {} ({rows})", info.name, info.description);
        if let Some(u) = system
            .unilateral()
            .iter()
            .find(|u| info.rows.contains(&u.row))
        {
            let _ = writeln!(
                s,
                "    unilateral: side {} (C {} 0 allowed; it pushes, never pulls), restitution {}",
                u.side.name(),
                if u.side.sign() > 0.0 { ">=" } else { "<=" },
                g(u.restitution, 6)
            );
        }
        for row in info.rows.clone() {
            let initial = |v: &Vec<f64>| v.get(row).map(|x| g(*x, 6)).unwrap_or_else(|| "?".into());
            match set.symbolic_row(row).as_deref() {
                Some(symbolic) => {
                    let ExprRow {
                        value,
                        gradient,
                        velocity,
                        bias,
                    } = symbolic;
                    let _ = writeln!(s, "    row {row}: C = {}", expression(value, &name));
                    for (k, d) in gradient {
                        let _ = writeln!(s, "      dC/d({}) = {}", name(*k), expression(d, &name));
                    }
                    let _ = writeln!(s, "      Cdot = {}", expression(velocity, &name));
                    let _ = writeln!(
                        s,
                        "      bias = {}   (Cddot = J a + bias)",
                        expression(bias, &name)
                    );
                }
                None => {
                    let columns: Vec<String> =
                        set.row_columns(row).iter().map(|k| name(*k)).collect();
                    let _ = writeln!(
                        s,
                        "    row {row}: a Rust constraint on {}; derivatives by dual numbers",
                        columns.join(", ")
                    );
                }
            }
            let _ = writeln!(
                s,
                "      at t = 0: C = {}, Cdot = {}",
                initial(&eval.value),
                initial(&eval.velocity)
            );
        }
    }
    if set.n_rows() > 0 {
        let _ = writeln!(
            s,
            "  compiled: {} Jacobian nonzeros, {} tape instructions",
            set.n_nonzeros(),
            set.n_instructions()
        );
    }
    match (start.over_constrained(), system.parametric()) {
        (Some(refusal), _) => {
            let _ = writeln!(s, "\ndegrees of freedom: none: {refusal}");
        }
        (None, Some(map)) if set.n_rows() == 0 => {
            let _ = writeln!(
                s,
                "\ndegrees of freedom: {} (the parametric form's coordinates)",
                map.coordinates().len()
            );
        }
        (None, _) => {
            let _ = writeln!(s, "\ndegrees of freedom: {}", system.degrees_of_freedom());
        }
    }

    match system.parametric() {
        None => {
            let _ = writeln!(s, "\nparametric form: none");
        }
        Some(map) => {
            let coordinates = map.coordinates();
            let described: Vec<String> = coordinates
                .iter()
                .zip(map.initial().iter().zip(map.rates()))
                .map(|(c, (q, r))| format!("{c} = {} ({c}' = {})", exact(*q), exact(*r)))
                .collect();
            let _ = writeln!(
                s,
                "\nparametric form: {}",
                plural(coordinates.len(), "coordinate", "coordinates")
            );
            let _ = writeln!(s, "  initial      {}", described.join(", "));
            let qname = |slot: usize| parametric_slot_name(coordinates, slot);
            for k in 0..system.n_coords() {
                let row = map.symbolic(k);
                let coordinate = system.coordinate_name(k);
                let _ = writeln!(s, "  {coordinate} = {}", expression(row.position, &qname));
                // Every column, the structural zeros of J too.
                for (j, name) in coordinates.iter().enumerate() {
                    let d = match row.columns.iter().position(|&c| c == j) {
                        Some(e) => expression(&row.jacobian[e], &qname),
                        None => "0".to_string(),
                    };
                    let _ = writeln!(s, "    d({coordinate})/d{name} = {d}");
                }
                let _ = writeln!(s, "    velocity = {}", expression(row.velocity, &qname));
                let _ = writeln!(
                    s,
                    "    h = {}   (acceleration = J q'' + h)",
                    expression(row.bias, &qname)
                );
            }
            let _ = writeln!(s, "  compiled: {} tape instructions", map.n_instructions());
        }
    }

    let run = &scene.run;
    let mut defaults = Vec::new();
    if let Some(m) = run.method {
        defaults.push(format!("method {}", m.name()));
    }
    if let Some(i) = run.integrator {
        defaults.push(format!("integrator {}", i.name()));
    }
    if let Some(dt) = run.dt {
        defaults.push(format!("dt {}", exact(dt)));
    }
    if let Some(d) = run.duration {
        defaults.push(format!("duration {}", exact(d)));
    }
    if let Some(n) = run.steps {
        defaults.push(format!("steps {n}"));
    }
    if let Some(f) = run.stabilize {
        defaults.push(format!("stabilize {},{}", exact(f.ks), exact(f.kd)));
    }
    let _ = writeln!(
        s,
        "\nrun defaults: {}",
        if defaults.is_empty() {
            "none".to_string()
        } else {
            defaults.join(", ")
        }
    );
    bead::formulation::prepare_fused_accelerations(system);
    let _ = writeln!(s, "\nmachine code: {}", system.machine_code());
    start_text(&mut s, start);
    s
}

/// The last section of `bead check`: whether each formulation starts.
fn start_text(s: &mut String, start: &StartCheck) {
    match &start.plan {
        Ok(plan) => {
            let _ = writeln!(
                s,
                "\nstart at t = 0 ({}, dt {})",
                plan.integrator.name(),
                exact(plan.dt)
            );
        }
        Err(e) => {
            let _ = writeln!(s, "\nstart at t = 0: not tried: {e}");
        }
    }
    for (method, result) in &start.forms {
        let outcome = match result {
            Ok(()) => "ok".to_string(),
            Err(e) if start.only_not_applicable(*method, e) => {
                format!("not with these settings (bead run uses the other form): {e}")
            }
            Err(e) => format!("refused: {}", setup_error(e)),
        };
        let _ = writeln!(s, "  {:<12} {outcome}", method.name());
    }
}

/// `EXPR (downward, terminal): crossed at t = 0.5, 1.5 s`, at most 8 times listed.
fn event_line(event: &bead::output::EventTimes) -> String {
    const LISTED: usize = 8;
    let direction = match event.direction {
        1 => "upward",
        -1 => "downward",
        _ => "either way",
    };
    let kind = if event.terminal { ", terminal" } else { "" };
    let times = &event.times;
    let crossed = if times.is_empty() {
        "did not cross zero".to_string()
    } else {
        let shown: Vec<String> = times.iter().take(LISTED).map(|t| exact(*t)).collect();
        let more = if times.len() > LISTED {
            format!(", ... ({} crossings in all)", times.len())
        } else {
            String::new()
        };
        format!("crossed at t = {}{more} s", shown.join(", "))
    };
    format!("{} ({direction}{kind}): {crossed}", event.when)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn g_picks_fixed_or_exponent_notation() {
        assert_eq!(g(0.0, 4), "0");
        assert_eq!(g(-112500.0, 10), "-112500");
        assert_eq!(g(1.0 / 60.0, 6), "0.0166667");
        assert_eq!(g(1.234e-8, 4), "1.234e-8");
        assert_eq!(g(2.5e12, 4), "2.5e12");
        assert_eq!(g(9.99999, 3), "10");
        assert_eq!(g(f64::NAN, 3), "NaN");
    }

    #[test]
    fn exact_is_shortest_round_trip_and_short_at_the_extremes() {
        assert_eq!(exact(1.0 / 60.0), "0.016666666666666666");
        assert_eq!(exact(10.0), "10");
        assert_eq!(exact(1e300), "1e300");
        assert_eq!(exact(-2.5e-7), "-2.5e-7");
        assert_eq!(exact(0.0), "0");
    }

    #[test]
    fn table_aligns_columns() {
        let rows = vec![
            vec!["method".to_string(), "x".to_string()],
            vec!["implicit".to_string(), "12".to_string()],
            vec!["p".to_string(), "3".to_string()],
        ];
        assert_eq!(
            table(&rows),
            "method      x\n-------------\nimplicit   12\np           3\n"
        );
    }
}
