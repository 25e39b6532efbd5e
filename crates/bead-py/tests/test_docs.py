"""Every example in the package's docstrings and in the READMEs runs, and prints what the
text says it prints.

- Docstrings: every `>>>` example in the docstrings of the installed package (`help(bead)`,
  its modules, classes, functions, methods and properties, the native ones included) runs
  as a doctest, from the repository's root (the examples' paths are relative to it).
- READMEs: every ```python block of README.md and crates/bead-py/README.md runs, from the
  repository's root; when a ```text block follows it, the block's output must be that text:
  line for line (runs of spaces count as one: pandas and numpy align columns), numbers equal
  within 1e-9 relative, and only the figures of the machine (a number of seconds before
  " s", a number of threads before " thread(s)") free.
- Every scene file the docs, docstrings and examples name is shipped.
"""

import contextlib
import doctest
import inspect
import io
import math
import re
from pathlib import Path

import pytest

import bead
from conftest import ROOT

READMES = [ROOT / "README.md", ROOT / "crates" / "bead-py" / "README.md"]


# ---------------------------------------------------------------------------------------
# Docstrings


def docstrings():
    """(name, docstring) of the package's modules and everything public in them."""
    import bead._builder
    import bead._errors
    import bead._run
    import bead._sweep

    found = {}

    def add(name, obj):
        doc = obj if isinstance(obj, str) else inspect.getdoc(obj)
        if doc and name not in found:
            found[name] = doc

    for module in (bead, bead._bead, bead._run, bead._sweep, bead._errors, bead._builder):
        add(module.__name__, module.__doc__ or "")
        for name, obj in vars(module).items():
            if name.startswith("__"):
                continue
            if inspect.isclass(obj) or callable(obj):
                add(f"{module.__name__}.{name}", obj)
            if inspect.isclass(obj):
                for member, value in vars(obj).items():
                    if not member.startswith("__") or member == "__init__":
                        add(f"{module.__name__}.{name}.{member}",
                            getattr(value, "__doc__", None) or "")
    return {name: doc for name, doc in found.items() if doc}


DOCSTRINGS = docstrings()
EXAMPLES = {name: doc for name, doc in DOCSTRINGS.items() if ">>>" in doc}


def test_help_bead_has_examples_that_run():
    # The module docstring's examples are doctests (its sweep example failed on every
    # shipped scene while it was plain text).
    assert ">>>" in bead.__doc__ and "bead.sweep(" in bead.__doc__
    assert "bead" in EXAMPLES


def test_no_docstring_shows_code_that_is_not_a_doctest():
    # An indented block of code (four spaces, then a call or an assignment) is an example
    # that no test would run: write it as >>> lines.
    code = re.compile(r"^ {4}(?!>>>|\.\.\.)[\w.]+(\(| = )", re.M)
    plain = {name: m.group(0) for name, doc in DOCSTRINGS.items()
             for m in [code.search(doc)] if m}
    assert plain == {}


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_docstring_examples_run(name, monkeypatch):
    monkeypatch.chdir(ROOT)
    parser = doctest.DocTestParser()
    test = parser.get_doctest(EXAMPLES[name], {}, name, name, 0)
    flags = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
    runner = doctest.DocTestRunner(optionflags=flags)
    report = io.StringIO()
    runner.run(test, out=report.write)
    assert runner.failures == 0, report.getvalue()
    assert runner.tries > 0


# ---------------------------------------------------------------------------------------
# READMEs


def python_blocks(path):
    """(line, code, expected text or None) of each ```python block of `path`, the expected
    text being the ```text block right after it (blank lines between allowed)."""
    lines = path.read_text().splitlines()
    blocks = []
    i = 0
    while i < len(lines):
        if lines[i].strip() == "```python":
            start = i + 1
            end = lines.index("```", start)
            code = "\n".join(lines[start:end]) + "\n"
            j = end + 1
            while j < len(lines) and not lines[j].strip():
                j += 1
            expected = None
            if j < len(lines) and lines[j].strip() == "```text":
                stop = lines.index("```", j + 1)
                expected = "\n".join(lines[j + 1:stop]) + "\n"
                i = stop
            else:
                i = end
            blocks.append((start, code, expected))
        i += 1
    return blocks


BLOCKS = [(path, *block) for path in READMES for block in python_blocks(path)]

NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
# Figures of the machine: seconds of wall time, the number of threads.
MACHINE = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?(?= s\b| thread\(s\))")


def same_output(expected, actual):
    """None when `actual` is `expected` by the rules of this module's docstring, else the
    first difference."""
    want = expected.rstrip("\n").split("\n")
    got = actual.rstrip("\n").split("\n")
    if len(want) != len(got):
        return f"{len(got)} lines printed, {len(want)} expected"
    for n, (w, g) in enumerate(zip(want, got), 1):
        w, g = (" ".join(MACHINE.sub("<machine>", line).split()) for line in (w, g))
        w_text, g_text = NUMBER.split(w), NUMBER.split(g)
        w_numbers, g_numbers = NUMBER.findall(w), NUMBER.findall(g)
        if w_text != g_text or len(w_numbers) != len(g_numbers):
            return f"line {n}: printed\n  {g}\nexpected\n  {w}"
        for a, b in zip(w_numbers, g_numbers):
            if not math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=0.0):
                return f"line {n}: printed {b} where {a} is expected:\n  {g}\nexpected\n  {w}"
    return None


@pytest.mark.parametrize(
    "path,line,code,expected", BLOCKS,
    ids=[f"{p.relative_to(ROOT)}:{line}" for p, line, _, _ in BLOCKS])
def test_readme_python_examples_print_what_the_readme_says(path, line, code, expected,
                                                          monkeypatch):
    monkeypatch.chdir(ROOT)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(code, f"{path}:{line}", "exec"), {"__name__": "__readme__"})
    if expected is not None:
        difference = same_output(expected, printed.getvalue())
        assert difference is None, difference


def test_the_readmes_have_python_examples():
    assert [p.name for p, *_ in BLOCKS].count("README.md") >= 3
    assert sum(expected is not None for *_, expected in BLOCKS) >= 2


@pytest.mark.parametrize("expected,actual,same", [
    ("a 1.0 b", "a   1.0000000000001 b", True),
    ("a 1.0 b", "a 1.0001 b", False),
    ("26.4 s on 2 thread(s)", "3.1 s on 16 thread(s)", True),
    ("x 2 y", "x 2 z", False),
    ("one\ntwo", "one", False),
])
def test_the_output_comparison(expected, actual, same):
    assert (same_output(expected, actual) is None) == same


# ---------------------------------------------------------------------------------------
# Scene files named by the docs

def named_scenes():
    texts = [p.read_text() for p in READMES + [ROOT / "DESIGN.md"]]
    texts += [p.read_text() for p in sorted((ROOT / "examples").glob("*.py"))]
    texts += list(DOCSTRINGS.values())
    names = set()
    for text in texts:
        # `scenes/NAME.toml` on its own, not a path under another directory
        # (tests/oracle/scenes/rotating-rod.toml is the oracle suite's own scene).
        for match in re.finditer(r"(?<![\w./-])scenes/([\w-]+\.toml)", text):
            names.add(match.group(1))
    return sorted(names)


def test_every_scene_the_docs_name_is_shipped():
    names = named_scenes()
    assert "parabola.toml" in names and "parabola-x0.toml" in names
    missing = [n for n in names if not (ROOT / "scenes" / n).exists()]
    assert missing == []


def test_readme_sweep_example_runs_on_a_shipped_scene(cli):
    """The README's `bead sweep` example names a shipped scene and prints its rows (it named
    parabola-x0.toml, which was not shipped)."""
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```text\n\$ (bead sweep scenes/parabola-x0\.toml [^\n]*)\n(.*?)```",
                      text, re.S)
    assert block, "the README's sweep example"
    command, shown = block.group(1), block.group(2).splitlines()
    args = re.findall(r'"[^"]*"|\S+', command)[1:]
    code, out, err = cli(*[a.strip('"') for a in args])
    assert code == 0, err
    rows = out.splitlines()
    # The block shows the header and some rows ("..." for those left out), then the
    # summary that goes to stderr.
    for line in shown:
        if line == "..." or line.startswith("sweep: "):
            continue
        assert line in rows, line
    assert len(rows) == 11 and shown[-1].startswith("sweep: 10 members")


# ---------------------------------------------------------------------------------------
# The scene format's reference


SCENE_FORMAT = ROOT / "docs" / "scene-format.md"


def scene_format_examples():
    text = SCENE_FORMAT.read_text()
    return re.findall(r"```toml\n(.*?)```", text, re.S)


@pytest.mark.parametrize("k", range(len(scene_format_examples())))
def test_every_scene_of_the_format_reference_loads_and_runs(k):
    """Each ```toml block of docs/scene-format.md is a scene: it loads and runs two steps
    with every form it has."""
    scene = bead.loads(scene_format_examples()[k], name=f"scene-format.md example {k + 1}")
    for method in scene.methods:
        run = scene.run(method=method, steps=2)
        assert run.completed, (method, run.error)


def test_the_format_reference_names_every_key_the_loader_knows():
    text = SCENE_FORMAT.read_text()
    for key in ("title", "[params]", "[world]", "gravity", "[[particle]]", "name", "mass",
                "position", "velocity", "[[force]]", "constant", "spring", "drag", "between",
                "anchor", "stiffness", "rest_length", "coefficient", "vector",
                "[[constraint]]", "expression", "distance", "pin", "expr", "length",
                "[parametric]", "coordinates", "initial", "rates", "[parametric.positions]",
                "[run]", "method", "integrator", "dt", "duration", "steps", "stabilize",
                "stop_when", "event_samples", "[[event]]", "direction", "terminal", "for"):
        # `key`, `key = ...` or "key" (a kind's name).
        assert re.search(f"`{re.escape(key)}[` ]", text) or f'"{key}"' in text, key
    for name in bead.INTEGRATORS:
        assert f"`{name}`" in text, name


def test_help_of_the_package_points_to_the_format_reference():
    assert "docs/scene-format.md" in bead.__doc__
