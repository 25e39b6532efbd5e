"""Every numeric argument of every function refuses a bad value with an error that names the
argument and says what it accepts: a ValueError for a value out of range (an integer beyond
a Rust integer or a float included; these were OverflowErrors naming nothing), a TypeError
for a value of the wrong type (a bool, a string, a float where an integer is needed)."""

import numpy as np
import pytest

import bead
from conftest import scene_path

POSITIVE = "a finite number > 0"
STEPS = "an integer from 1 to 2^53"
SUBSTEPS = "an integer from 1 to 2^32 - 1"
THREADS = "an integer from 0 to 1024 (0: one per core)"


@pytest.fixture(scope="module")
def scene():
    return bead.load(scene_path("parabola.toml"))


def run(scene, **kwargs):
    if "duration" not in kwargs:
        kwargs.setdefault("steps", 1)
    return scene.run(**kwargs)


def simulation(scene, **kwargs):
    return scene.simulation(**kwargs)


def sweep(scene, **kwargs):
    if "duration" not in kwargs:
        kwargs.setdefault("steps", 1)
    return bead.sweep(scene, {"g": [500.0]}, **kwargs)


def step(scene, count):
    return scene.simulation().step(count)


def advance_to(scene, t):
    return scene.simulation().advance_to(t)


def run_range(scene, **kwargs):
    args = {"start": 0, "stop": 1, "threads": 0, **kwargs}
    return bead.Sweep(scene, {"g": [500.0]}, steps=1).run_range(**args)


def sweep_run(scene, threads):
    return bead.Sweep(scene, {"g": [500.0]}, steps=1).run(threads)


def chunks(scene, count):
    return bead.Sweep(scene, {"g": [500.0]}, steps=1).chunks(count)


def load(scene, value):
    return bead.load(scene_path("parabola.toml"), params={"g": value})


def loads(scene, value):
    return bead.loads(scene.text, params={"g": value})


def with_params(scene, value):
    return scene.with_params({"g": value})


def sweep_values(scene, value):
    return bead.sweep(scene, {"g": [value]}, steps=1)


# (call, argument, what the message says the argument accepts): each call takes the scene
# and the bad value as the argument.
REALS = [
    *[(f, name, POSITIVE) for f in (run, sweep) for name in ("dt", "duration", "rtol")],
    (simulation, "dt", POSITIVE),
    (simulation, "rtol", POSITIVE),
    *[(f, "atol", "a finite number >= 0") for f in (run, simulation, sweep)],
    (advance_to, "t", "a finite time (s) >= the current time"),
    (load, 'params["g"]', "a finite number"),
    (loads, 'params["g"]', "a finite number"),
    (with_params, 'params["g"]', "a finite number"),
]

INTEGERS = [
    (run, "steps", STEPS),
    (sweep, "steps", STEPS),
    (run, "every", STEPS),
    *[(f, name, SUBSTEPS) for f in (run, simulation, sweep)
      for name in ("substeps", "max_substeps")],
    (sweep, "threads", THREADS),
    (sweep_run, "threads", THREADS),
    (run_range, "threads", THREADS),
    (run_range, "start", "an integer from 0 to 1"),
    (run_range, "stop", "an integer from 0 to 1"),
    (step, "count", "an integer from 0 to 2^64 - 1"),
]


def call(f, name, value, scene):
    if f in (run, simulation, sweep, run_range):
        return f(scene, **{name: value})
    return f(scene, value)


def ids(cases):
    return [f"{f.__name__}-{name}" for f, name, _ in cases]


@pytest.mark.parametrize("f,name,accepts", REALS, ids=ids(REALS))
@pytest.mark.parametrize("value", [10**400, -(10**400)], ids=["huge", "-huge"])
def test_a_real_beyond_a_float_names_the_argument(scene, f, name, accepts, value):
    with pytest.raises(ValueError) as caught:
        call(f, name, value, scene)
    text = str(caught.value)
    assert text.startswith(f"{name}=") and f"must be {accepts}" in text, text
    assert "beyond the range of a float" in text, text
    assert not isinstance(caught.value, OverflowError)


@pytest.mark.parametrize("f,name,accepts", REALS, ids=ids(REALS))
@pytest.mark.parametrize("value", [True, "1.0", [1.0]], ids=["bool", "str", "list"])
def test_a_real_of_the_wrong_type_is_a_type_error_naming_the_argument(scene, f, name, accepts, value):
    if f is sweep and name == "dt" and isinstance(value, list):
        # A list of dt values is a sweep over dt: an axis of the grid.
        result = call(f, name, value, scene)
        assert result.names == ["dt", "g"] and result.shape == (1, 1)
        assert result.params["dt"].tolist() == [[1.0]]
        return
    with pytest.raises(TypeError) as caught:
        call(f, name, value, scene)
    text = str(caught.value)
    assert text.startswith(f"{name}=") and f"must be {accepts}, not a " in text, text


@pytest.mark.parametrize("f,name,accepts", INTEGERS, ids=ids(INTEGERS))
@pytest.mark.parametrize("value", [-1, 2**64, 2**64 + 1, 10**30, np.int64(-7)],
                         ids=["-1", "2^64", "2^64+1", "1e30", "np-7"])
def test_an_integer_out_of_range_names_the_argument_and_its_range(scene, f, name, accepts, value):
    with pytest.raises(ValueError) as caught:
        call(f, name, value, scene)
    text = str(caught.value)
    assert text.startswith(f"{name}=") and text.endswith(f": must be {accepts}"), text
    assert not isinstance(caught.value, OverflowError)


@pytest.mark.parametrize("f,name,accepts", INTEGERS, ids=ids(INTEGERS))
@pytest.mark.parametrize("value", [1.0, True, "1"], ids=["float", "bool", "str"])
def test_an_integer_of_the_wrong_type_is_a_type_error_naming_the_argument(scene, f, name, accepts, value):
    with pytest.raises(TypeError) as caught:
        call(f, name, value, scene)
    text = str(caught.value)
    assert text.startswith(f"{name}=") and f"must be {accepts}, not a " in text, text


def test_negative_threads_names_the_argument(scene):
    with pytest.raises(ValueError, match=r"^threads=-1: must be an integer from 0 to 1024"):
        bead.sweep(scene, {"g": [1.0, 2.0]}, steps=1, threads=-1)


def test_steps_beyond_2_64_names_the_argument(scene):
    with pytest.raises(ValueError, match=r"^steps=18446744073709551616: must be an integer "
                                         r"from 1 to 2\^53$"):
        scene.run(steps=2**64)
    with pytest.raises(ValueError, match=r"^steps=18446744073709551616: must be"):
        bead.sweep(scene, {"g": [1.0]}, steps=2**64)


def test_substeps_beyond_2_32_are_refused_not_cut(scene):
    # They were cut to 2^32 - 1 without a word.
    with pytest.raises(ValueError, match=r"^substeps=4294967296: must be an integer from 1 "
                                         r"to 2\^32 - 1$"):
        scene.simulation(substeps=2**32)


def test_numpy_integers_and_floats_are_accepted(scene):
    run = scene.run(dt=np.float32(0.5), steps=np.int64(2), every=np.uint8(1),
                    stabilize=(np.float64(0.0), 0))
    assert len(run) == 3 and run.t[-1] == 1.0
    sim = scene.simulation(substeps=np.int32(2))
    sim.step(np.int16(3))
    sim.advance_to(np.float64(1.0))
    assert sim.t == 1.0
    result = bead.sweep(scene, {"g": [1.0, 2.0]}, steps=np.int64(1), threads=np.int64(1),
                        members=range(np.int64(0), np.int64(2)))
    assert result.steps.tolist() == [1, 1]


@pytest.mark.parametrize(
    "value,error,message",
    [
        ((1.0, 2.0, 3.0), TypeError, "stabilize=(1.0, 2.0, 3.0): must be two finite numbers >= 0, (ks, kd)"),
        ("ab", TypeError, "stabilize='ab': must be two finite numbers >= 0, (ks, kd)"),
        ((1.0, 10**400), ValueError, "stabilize[1] (kd)=10000000000000000000... (401 characters): must be"),
        (("x", 1.0), TypeError, "stabilize[0] (ks)='x': must be a finite number >= 0, not a str"),
        ((-1.0, 0.0), ValueError, "stabilize=-1,0: must be two finite numbers >= 0"),
    ],
)
def test_stabilize_names_itself(scene, value, error, message):
    for f in (run, simulation, sweep):
        with pytest.raises(error) as caught:
            f(scene, stabilize=value)
        assert str(caught.value).startswith(message), str(caught.value)


@pytest.mark.parametrize("members", [range(-1, 1), range(0, 3), range(0, 2, 2), (1, 0)])
def test_members_out_of_range_name_the_argument(scene, members):
    with pytest.raises(ValueError, match=r"^members=.*: must be a range of consecutive members "
                                         r"\(step 1\) within range\(0, 2\)$"):
        bead.sweep(scene, {"g": [1.0, 2.0]}, steps=1, members=members)


def test_chunks_count_names_the_argument(scene):
    plan = bead.Sweep(scene, {"g": [1.0, 2.0]}, steps=1)
    with pytest.raises(ValueError, match=r"^count=0: must be an integer >= 1$"):
        plan.chunks(0)
    with pytest.raises(TypeError, match=r"^count=2.0: must be an integer >= 1, not a float$"):
        plan.chunks(2.0)


def test_sweep_values_beyond_a_float_name_the_parameter(scene):
    with pytest.raises(ValueError, match=r'^params\["g"\]: a value is beyond the range of a '
                                         r'float'):
        sweep_values(scene, 10**400)


def test_unaligned_values_are_swept_not_a_panic(scene):
    # An array over a buffer at an odd offset (as Dask may unpickle one from a frame): the
    # native side read it in place and panicked ("The pointer must be aligned").
    buffer = bytearray(8 * 3 + 1)
    values = np.frombuffer(buffer, dtype=np.float64, offset=1, count=3)
    values[:] = [400.0, 500.0, 600.0]
    assert not values.flags.aligned
    result = bead.sweep(scene, {"g": values}, steps=1)
    assert result.params["g"].tolist() == [400.0, 500.0, 600.0]


def test_the_native_sweep_plan_refuses_unaligned_values_in_words(scene):
    buffer = bytearray(8 * 2 + 1)
    values = np.frombuffer(buffer, dtype=np.float64, offset=1, count=2)
    with pytest.raises(ValueError, match=r'^params\["g"\]: the values must be an aligned '
                                         r'float64 array'):
        bead._bead.SweepPlan(scene, ["g"], [values], steps=1)
