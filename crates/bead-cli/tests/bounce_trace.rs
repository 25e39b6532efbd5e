//! The ball in the article's bowl (`scenes/bounce.toml`) through the trace CSV a user reads,
//! against flights and impacts computed here: between impacts the ball flies freely, so
//! x(t) is linear and y(t) quadratic, and on the bowl C = x^2 + 100 y is a quadratic in t
//! whose root is the landing time; at a landing the velocity's component along the bowl's
//! normal n = (2x, 100) turns into -e times itself (v+ = v- - (1 + e) (v.n / n.n) n, the
//! impulse of a unit mass on one row). rk4 integrates a free flight exactly up to rounding,
//! so every traced row in flight must lie on this path.

mod common;

use common::{bead_in, ok, TempDir};

const G: f64 = 500.0;
/// The scene's restitution.
const E: f64 = 0.7;

/// A free flight from (x, y, vx, vy) at time t0.
#[derive(Clone, Copy, Debug)]
struct Flight {
    /// The restitution of its landing.
    e: f64,
    t0: f64,
    x: f64,
    y: f64,
    vx: f64,
    vy: f64,
}

impl Flight {
    fn at(&self, t: f64) -> [f64; 4] {
        let s = t - self.t0;
        [
            self.x + self.vx * s,
            self.y + self.vy * s + 0.5 * G * s * s,
            self.vx,
            self.vy + G * s,
        ]
    }

    /// When C = x^2 + 100 y reaches 0 again: the positive root of a s^2 + b s + c, with c = 0
    /// right after a bounce (the root -b / a then).
    fn landing(&self) -> f64 {
        let a = self.vx * self.vx + 50.0 * G;
        let b = 2.0 * self.x * self.vx + 100.0 * self.vy;
        let c = self.x * self.x + 100.0 * self.y;
        let s = if c.abs() < 1e-9 {
            -b / a
        } else {
            (-b + (b * b - 4.0 * a * c).sqrt()) / (2.0 * a)
        };
        self.t0 + s
    }

    /// The next flight: from the landing, the normal velocity reversed times e.
    fn bounce(&self) -> Flight {
        let t = self.landing();
        let [x, y, vx, vy] = self.at(t);
        let (nx, ny) = (2.0 * x, 100.0);
        let vn = (vx * nx + vy * ny) / (nx * nx + ny * ny);
        Flight {
            e: self.e,
            t0: t,
            x,
            y,
            vx: vx - (1.0 + self.e) * vn * nx,
            vy: vy - (1.0 + self.e) * vn * ny,
        }
    }
}

/// The first `bounces` flights of the ball dropped at rest from (x0, -200).
fn flights_from(x0: f64, e: f64, bounces: usize) -> Vec<Flight> {
    let mut flights = vec![Flight {
        e,
        t0: 0.0,
        x: x0,
        y: -200.0,
        vx: 0.0,
        vy: 0.0,
    }];
    for _ in 0..bounces {
        let next = flights.last().unwrap().bounce();
        flights.push(next);
    }
    flights
}

/// Every traced row of `bead run scenes/bounce.toml` (implicit and parametric, rk4 at the
/// scene's dt 1e-3) while the ball flies, through its first ten bounces, is on the path
/// computed here: positions within 1e-8 px, velocities within 1e-8 px/s (measured 1.6e-10
/// and 1.2e-9);
/// the trace's energy drops at each bounce by (1 - e^2) of the normal part.
#[test]
fn the_traced_bounces_are_the_flights_and_impacts_computed_by_hand() {
    let dir = TempDir::new("bounce-trace");
    let scene = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/bounce.toml");
    let flights = flights_from(60.0, E, 10);
    let end = flights.last().unwrap().t0;
    for method in ["implicit", "parametric"] {
        let trace = dir.path(&format!("{method}.csv"));
        ok(bead_in(
            &dir.0,
            &[
                "run",
                scene.to_str().unwrap(),
                "--method",
                method,
                "--duration",
                &format!("{end}"),
                "--trace",
                trace.to_str().unwrap(),
            ],
        ));
        let text = std::fs::read_to_string(&trace).unwrap();
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
        let (ct, cx, cy, cvx, cvy, ce) = (
            column("t"),
            column("ball.x"),
            column("ball.y"),
            column("ball.vx"),
            column("ball.vy"),
            column("energy"),
        );
        let (mut worst_x, mut worst_v, mut rows) = (0.0_f64, 0.0_f64, 0);
        let mut energy_before: Option<(usize, f64)> = None;
        let mut bounces_checked = 0;
        for line in lines {
            let cells: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
            let t = cells[ct];
            // The flight this row is in; rows within a microsecond of an impact are left out
            // (the impact time is located to 1e-10 dt, not to rounding).
            let Some(k) = flights.windows(2).position(|w| t > w[0].t0 && t < w[1].t0) else {
                continue;
            };
            if (t - flights[k].t0).abs() < 1e-6 || (t - flights[k + 1].t0).abs() < 1e-6 {
                continue;
            }
            let want = flights[k].at(t);
            worst_x = worst_x
                .max((cells[cx] - want[0]).abs())
                .max((cells[cy] - want[1]).abs());
            worst_v = worst_v
                .max((cells[cvx] - want[2]).abs())
                .max((cells[cvy] - want[3]).abs());
            rows += 1;
            // The energy over a bounce: kinetic energy (1 - e^2) m vn^2 / 2 taken.
            if let Some((before_k, before)) = energy_before {
                if before_k + 1 == k {
                    let f = flights[before_k];
                    let [x, _, vx, vy] = f.at(flights[k].t0);
                    let (nx, ny) = (2.0 * x, 100.0);
                    let vn2 = (vx * nx + vy * ny).powi(2) / (nx * nx + ny * ny);
                    let taken = 0.5 * (1.0 - E * E) * vn2;
                    let got = before - cells[ce];
                    assert!(
                        (got - taken).abs() <= 1e-9 * before,
                        "{method}: bounce {k} took {got}, by hand {taken}"
                    );
                    bounces_checked += 1;
                }
            }
            energy_before = Some((k, cells[ce]));
        }
        println!("{method}: {rows} rows in flight; positions within {worst_x:.2e} px, velocities within {worst_v:.2e} px/s");
        assert!(rows > 1000, "{method}: {rows} rows");
        assert_eq!(
            bounces_checked, 9,
            "{method}: bounces whose energy was checked"
        );
        assert!(worst_x < 1e-8, "{method}: positions off by {worst_x}");
        assert!(worst_v < 1e-8, "{method}: velocities off by {worst_v}");
    }
}

/// `bead sweep` over where the ball is dropped and its restitution (a 3 x 3 grid, both
/// forms): each member's final state in the CSV is the hand-computed flight's at t = 0.9 s,
/// within 1e-8 (members whose bounces have shrunk below 20 steps by then are left out: the
/// soft landing's rule, not the flights, decides them).
#[test]
fn the_swept_bounces_end_where_the_flights_computed_by_hand_do() {
    let dir = TempDir::new("bounce-sweep");
    let scene = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/bounce.toml");
    let end = 0.9;
    for method in ["implicit", "parametric"] {
        let out = ok(bead_in(
            &dir.0,
            &[
                "sweep",
                scene.to_str().unwrap(),
                "--method",
                method,
                "--param",
                "x0=20:100:3",
                "--param",
                "restitution=0.5:0.9:3",
                "--duration",
                &format!("{end}"),
            ],
        ));
        let mut lines = out.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
        let mut compared = 0;
        for line in lines {
            let cells: Vec<&str> = line.split(',').collect();
            let number = |name: &str| cells[column(name)].parse::<f64>().unwrap();
            assert_eq!(cells[column("status")], "ok", "{line}");
            assert_eq!(number("t_final"), end, "{line}");
            let flights = flights_from(number("x0"), number("restitution"), 40);
            let k = flights.iter().rposition(|f| f.t0 <= end).unwrap();
            if k + 1 >= flights.len()
                || flights[..=k + 1]
                    .windows(2)
                    .any(|w| w[1].t0 - w[0].t0 < 0.02)
            {
                continue;
            }
            let want = flights[k].at(end);
            let got = [
                number("ball.x"),
                number("ball.y"),
                number("ball.vx"),
                number("ball.vy"),
            ];
            for (g, w) in got.iter().zip(want) {
                assert!(
                    (g - w).abs() < 1e-8,
                    "{method}: {line}: {got:?} vs {want:?}"
                );
            }
            compared += 1;
        }
        println!("{method}: {compared} of 9 members compared");
        assert!(compared >= 6, "{method}: {compared} members compared");
    }
}
