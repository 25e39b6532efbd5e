"""Events as scipy has them: several at once, each with a direction and terminal or not,
their crossings (`t_events`, `y_events`) against the pendulum's analytic crossing times
(from the complete elliptic integral), recording that changes no number of the run, the
earliest terminal event winning, `Simulation.event_fired`, and `[[event]]` scene tables."""

import math

import numpy as np
import pytest

import bead
from conftest import ROOT

CIRCLE = ROOT / "scenes" / "circle.toml"
G, L, THETA0 = 9.81, 1.0, math.pi / 3


def period():
    """The pendulum's period from 60 degrees at rest: 4 sqrt(L/g) K(sin(theta0/2)), K by the
    arithmetic-geometric mean."""
    k = math.sin(THETA0 / 2)
    a, b = 1.0, math.sqrt(1 - k * k)
    for _ in range(40):
        a, b = (a + b) / 2, math.sqrt(a * b)
    return 4 * math.sqrt(L / G) * math.pi / (2 * a)


THREE = [
    bead.Event("bead.x", direction=-1),  # through the bottom leftward: T/4 + k T
    bead.Event("bead.x", direction=1),  # rightward: 3T/4 + k T
    bead.Event("bead.vx", direction=0),  # at rest at either end: k T/2 (not at t = 0)
]


def expected_times(duration):
    T = period()
    down = [T / 4 + k * T for k in range(10) if T / 4 + k * T <= duration]
    up = [3 * T / 4 + k * T for k in range(10) if 3 * T / 4 + k * T <= duration]
    rest = [k * T / 2 for k in range(1, 20) if k * T / 2 <= duration]
    return [down, up, rest]


@pytest.mark.parametrize(
    "method,integrator,kwargs,tolerance",
    [
        ("implicit", "rk4", {"dt": 1e-3}, 1e-9),
        ("parametric", "gauss-legendre", {"dt": 1e-3}, 1e-9),
        ("implicit", "rattle", {"dt": 1e-4}, 1e-7),
        ("parametric", "dopri5", {"dt": 1e-2, "rtol": 1e-11, "atol": 1e-13}, 1e-8),
    ],
)
def test_three_events_with_directions_match_the_analytic_crossing_times(
    method, integrator, kwargs, tolerance
):
    scene = bead.load(CIRCLE)
    duration = 5.0
    run = scene.run(method=method, integrator=integrator, duration=duration, events=THREE, **kwargs)
    assert run.summary["completed"] and run.t[-1] == duration
    assert len(run.t_events) == len(run.y_events) == 3
    for got, want, states in zip(run.t_events, expected_times(duration), run.y_events):
        assert got.shape == (len(want),), (got, want)
        np.testing.assert_allclose(got, want, rtol=0, atol=tolerance)
        assert states.shape == (len(want), 4)  # x, y, vx, vy of the one particle
    # The states are those at the crossings: x = 0 at the bottom, vx = 0 at the ends.
    down, up, rest = run.y_events
    assert np.all(np.abs(down[:, 0]) < 1e-9) and np.all(down[:, 2] < 0)
    assert np.all(np.abs(up[:, 0]) < 1e-9) and np.all(up[:, 2] > 0)
    assert np.all(np.abs(rest[:, 2]) < 1e-8)
    np.testing.assert_allclose(np.abs(rest[:, 0]), L * math.sin(THETA0), atol=1e-7)
    # The summary lists the same times, as `bead run --json` does.
    listed = [e["times"] for e in run.summary["events"]]
    assert listed == [t.tolist() for t in run.t_events]
    assert [e["direction"] for e in run.summary["events"]] == [-1, 1, 0]


@pytest.mark.parametrize(
    "method,integrator",
    [("implicit", "rk4"), ("implicit", "rattle"), ("implicit", "rattle4"),
     ("implicit", "fast-projection"), ("implicit", "verlet"),
     ("parametric", "gauss-legendre"), ("implicit", "dopri5"), ("parametric", "dopri5")],
)
def test_recording_events_changes_no_number_of_the_run(method, integrator):
    scene = bead.load(CIRCLE)
    plain = scene.run(method=method, integrator=integrator, duration=3.0)
    watched = scene.run(method=method, integrator=integrator, duration=3.0, events=THREE)
    assert sum(len(t) for t in watched.t_events) >= 5
    np.testing.assert_array_equal(plain.t, watched.t)
    np.testing.assert_array_equal(plain.positions, watched.positions)
    np.testing.assert_array_equal(plain.velocities, watched.velocities)


@pytest.mark.parametrize("integrator", ["rk4", "dopri5"])
def test_a_terminal_event_ends_the_run_and_only_earlier_crossings_are_kept(integrator):
    T = period()
    events = THREE + [bead.Event("bead.x + 0.5", direction=-1, terminal=True)]
    run = bead.load(CIRCLE).run(integrator=integrator, duration=5.0, events=events)
    stop = run.summary["stop_time"]
    # x = L sin(theta) passes -0.5 going left after T/4 and before T/2.
    assert T / 4 < stop < T / 2
    assert run.t[-1] == stop and run.t_events[3].tolist() == [stop]
    assert abs(run.positions[-1, 0, 0] + 0.5) < 1e-9
    assert run.summary["stop_when"] == "bead.x + 0.5"
    assert [len(t) for t in run.t_events] == [1, 0, 0, 1]


def test_the_earliest_of_two_terminal_events_in_one_step_fires():
    # Both cross between two samples of one step of 0.01, the second first; a non-terminal
    # crossing after it is not recorded (the run ended before it), one before it is.
    events = [
        bead.Event("t - 0.3029", direction=1, terminal=True),
        bead.Event("t - 0.3021", direction=1, terminal=True),
        bead.Event("t - 0.3032", direction=1),
        bead.Event("t - 0.3011", direction=1),
    ]
    run = bead.load(CIRCLE).run(dt=0.01, duration=1.0, events=events)
    assert abs(run.summary["stop_time"] - 0.3021) < 2e-12
    assert [t.tolist() for t in run.t_events[1:3]] == [[run.summary["stop_time"]], []]
    assert abs(run.t_events[3][0] - 0.3011) < 2e-12
    assert len(run.t_events[0]) == 0


def test_a_simulation_says_whether_and_which_event_fired_and_keeps_its_crossings():
    T = period()
    events = [bead.Event("bead.x", direction=-1), bead.Event("bead.vx", direction=1, terminal=True)]
    sim = bead.load(CIRCLE).simulation(dt=1e-3, events=events)
    sim.advance_to(0.3)
    assert not sim.event_fired and sim.fired_event is None
    assert [len(t) for t in sim.t_events] == [0, 0]
    # vx crosses zero upward where the bead comes to rest on the left: T/2.
    sim.advance_to(2.0)
    assert sim.event_fired and sim.fired_event == 1
    assert abs(sim.t - T / 2) < 1e-9
    assert abs(sim.t_events[0][0] - T / 4) < 1e-9
    assert sim.t_events[1].tolist() == [sim.t]
    np.testing.assert_allclose(sim.y_events[1][0, :2], sim.positions.ravel(), rtol=0, atol=0)
    # Going on: the next step does not fire again at once; a parameter change keeps them.
    sim.step()
    assert not sim.event_fired
    sim.set_param("g", 9.81)
    sim.advance_to(3.0)
    assert [len(t) for t in sim.t_events] == [2, 1]
    sim.reset()
    assert [len(t) for t in sim.t_events] == [0, 0]


def test_scene_event_tables_are_watched_and_events_replace_them():
    text = CIRCLE.read_text() + (
        '\n[[event]]\nexpr = "bead.x"\ndirection = -1\n'
        '\n[[event]]\nexpr = "bead.vx"\nterminal = true\n'
    )
    scene = bead.loads(text)
    run = scene.run(duration=5.0)
    T = period()
    # The second table: vx crosses zero (either way) first at T/2, and ends the run there.
    assert abs(run.summary["stop_time"] - T / 2) < 1e-9
    assert abs(run.t_events[0][0] - T / 4) < 1e-9 and len(run.t_events) == 2
    # events= replaces the tables; stop_when comes after them.
    run = scene.run(duration=1.0, events=["bead.x"], stop_when="t - 0.9")
    assert len(run.t_events) == 2
    assert abs(run.t_events[0][0] - T / 4) < 1e-9
    assert abs(run.t_events[1][0] - 0.9) < 2e-12


def test_bad_events_are_refused_with_their_place():
    scene = bead.load(CIRCLE)
    with pytest.raises(ValueError) as caught:
        scene.run(duration=0.1, events=[bead.Event("bead.x"), bead.Event("bead.w + 1")])
    assert str(caught.value).startswith("events[1]: ")
    assert "^" in str(caught.value)
    with pytest.raises(ValueError, match="direction must be 1, -1 or 0"):
        bead.Event("bead.x", direction=float("nan"))
    with pytest.raises(TypeError, match="a list of bead.Event"):
        scene.run(duration=0.1, events="bead.x")
    with pytest.raises(TypeError, match=r"events\[0\]: expected a bead.Event"):
        scene.run(duration=0.1, events=[3.0])
    with pytest.raises(ValueError, match="generalized coordinates"):
        scene.run(method="implicit", duration=0.1, events=[bead.Event("theta")])
    with pytest.raises(bead.SceneError, match="direction` must be 1"):
        bead.loads(CIRCLE.read_text() + '\n[[event]]\nexpr = "bead.x"\ndirection = 2\n')
    with pytest.raises(bead.SceneError, match="event 1: missing `expr`"):
        bead.loads(CIRCLE.read_text() + "\n[[event]]\nterminal = true\n")
    assert bead.Event("x", direction=-3.5) == bead.Event("x", direction=-1)


def test_a_sweep_records_each_members_crossings_as_its_run_does():
    # The period against the amplitude from one sweep with a non-terminal event: the time
    # between two leftward passages through the bottom, against 4 sqrt(L/g) K(sin(a/2)).
    scene = bead.load(CIRCLE)
    amplitudes = np.radians(np.linspace(10, 170, 9))
    options = dict(method="parametric", integrator="gauss-legendre", dt=1e-3, duration=8.0)
    result = bead.sweep(scene, initial={"q.theta": amplitudes},
                        events=[bead.Event("bead.x", direction=-1)], **options)
    assert result.t_events.shape == (9,) and set(result.status) == {"ok"}
    for a, times in zip(amplitudes, result.t_events):
        alone = scene.with_state(q=[a]).run(events=[bead.Event("bead.x", direction=-1)],
                                             **options)
        assert len(times) == 1 and times[0].tolist() == alone.t_events[0].tolist()
        k = math.sin(a / 2)
        x, y = 1.0, math.sqrt(1 - k * k)
        for _ in range(40):
            x, y = (x + y) / 2, math.sqrt(x * y)
        exact = 4 * math.sqrt(L / G) * math.pi / (2 * x)
        assert abs((times[0][1] - times[0][0]) / exact - 1) < 1e-12
    # A scene's own tables and stop_when come through too; chunks join.
    tabled = scene.with_event("bead.vx", 1, True)
    plan = bead.Sweep(tabled, {"g": [5.0, 9.81, 20.0]}, duration=5.0)
    joined = plan.assemble([plan.run_range(0, 1), plan.run_range(1, 3)])
    for g, times in zip([5.0, 9.81, 20.0], joined.t_events):
        alone = tabled.with_params({"g": g}).run(duration=5.0)
        assert [t.tolist() for t in times] == [t.tolist() for t in alone.t_events]
        assert len(times[0]) == 1
    with pytest.raises(TypeError, match="a list of bead.Event"):
        bead.sweep(scene, {"g": [1.0]}, events="bead.x")
