"""The examples run: the flip-time picture at a small grid (checked against the physics and
against single runs), and the Dask sweep (equal to the local sweep bit for bit)."""

import importlib.util
import subprocess
import sys

import numpy as np
import pytest

import bead
from conftest import ROOT

EXAMPLES = ROOT / "examples"


def example(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def flip():
    module = example("flip_time")
    values, result = module.flip_times(16, duration=5.0, dt=0.01)
    return module, values, result


def test_flip_time_small_grid_physics(flip):
    _, values, result = flip
    assert result.shape == (16, 16) and result.counts()["failed"] == 0
    t1, t2 = np.meshgrid(values, values, indexing="ij")
    # Released from rest with 2 cos(theta1) + cos(theta2) > 1 neither arm can get over the
    # top (m1 = m2, L1 = L2): those members never flip.
    cannot = 2 * np.cos(t1) + np.cos(t2) > 1
    assert cannot.sum() > 30
    assert (result.status[cannot] == "ok").all() and np.isnan(result.stop_time[cannot]).all()
    # Near the top, some flip quickly; flip times lie inside the run.
    flipped = result.status == "event"
    assert flipped.sum() > 30
    assert (result.stop_time[flipped] > 0).all() and (result.stop_time[flipped] < 5.0).all()
    # At the flip an arm is over the top: |theta| = pi for one of them.
    top = np.abs(result.q[flipped]).max(axis=-1)
    np.testing.assert_allclose(top, np.pi, atol=1e-9)


def test_flip_time_of_a_member_by_hand(flip):
    module, values, result = flip
    # A member that flips: the single run with the same stop_when gives the same time bit
    # for bit, and its recorded steps show the crossing where the event put it.
    i, j = 2, 12
    assert result.status[i, j] == "event"
    scene = bead.load(module.SCENE).with_params({"th1": values[i], "th2": values[j]})
    run = scene.run(dt=0.01, duration=5.0, stop_when=module.FLIP, **module.RUN)
    t = run.summary["stop_time"]
    assert t == result.stop_time[i, j]
    # By hand from the trajectory: max(|theta1|, |theta2|) < pi at every step before the last,
    # the last state (the crossing) at pi, within one step of the previous one.
    top = np.abs(run.q).max(axis=1)
    assert (top[:-1] < np.pi).all() and abs(top[-1] - np.pi) < 1e-9
    assert 0 < run.t[-1] - run.t[-2] <= 0.01 and run.t[-1] == t
    # The flipped arm points straight up from its pivot (+y is down).
    a, b = run.positions[-1]
    arm = a if abs(abs(run.q[-1, 0]) - np.pi) < 1e-9 else b - a
    np.testing.assert_allclose(arm, [0.0, -1.0], atol=1e-8)


def test_flip_time_draws_the_picture(flip, tmp_path, capsys):
    pytest.importorskip("matplotlib", reason="the picture needs matplotlib (pip install matplotlib)")
    module, _, _ = flip
    out = tmp_path / "flip.png"
    assert module.main(["--n", "16", "--duration", "5", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 5000
    printed = capsys.readouterr().out
    assert "16 x 16 members" in printed and "wall time" in printed


def test_flip_time_writes_to_the_current_directory_by_default(flip, tmp_path, monkeypatch):
    """Without --out the picture goes to ./flip_time.png, never over docs/flip_time.png (the
    README's picture, which the default overwrote)."""
    pytest.importorskip("matplotlib", reason="the picture needs matplotlib (pip install matplotlib)")
    module, _, _ = flip
    docs = ROOT / "docs" / "flip_time.png"
    before = docs.read_bytes() if docs.exists() else None
    monkeypatch.chdir(tmp_path)
    assert module.main(["--n", "4", "--duration", "0.5"]) == 0
    assert (tmp_path / "flip_time.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (docs.read_bytes() if docs.exists() else None) == before


def test_dask_sweep_equals_the_local_sweep():
    pytest.importorskip("distributed", reason="dask[distributed] is not installed "
                        "(scripts/test installs it: pip install 'dask[distributed]')")
    done = subprocess.run([sys.executable, str(EXAMPLES / "dask_sweep.py"), "--n", "12",
                           "--duration", "2", "--chunks", "5"],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "dask result equals the local sweep bit for bit: yes" in done.stdout
    assert "a LocalCluster of 2 worker processes" in done.stdout


def test_numpy_ensemble_measures_the_same_work_as_bead_sweep():
    """examples/numpy_ensemble.py times bead.sweep beside a hand-written numpy RK4 of the same
    equations; both must end every member at the same place (the script checks that before
    it reports), else the comparison measures different work."""
    module = example("numpy_ensemble")
    x0 = module.release_points(64)
    for method, by_hand in [("implicit", module.numpy_implicit),
                            ("parametric", module.numpy_parametric)]:
        bx, by = module.through_bead(x0, 120, method, threads=1)
        nx, ny = by_hand(x0, 120)
        assert np.abs(bx - nx).max() <= 1e-9 * 200 and np.abs(by - ny).max() <= 1e-9 * 200
        # Not the same numbers by accident: the members moved.
        assert np.abs(bx - x0).max() > 100.0
    rows = module.compare(members=64, steps=50, threads=1, rounds=1)
    assert [r[0] for r in rows] == ["implicit", "parametric"]
    assert all(r[1] > 0 and r[2] > 0 and r[3] > 0 for r in rows)
