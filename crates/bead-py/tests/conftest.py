"""Shared fixtures: the repository's scenes and the `bead` command-line tool to compare with."""

import os
import shutil
import subprocess
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
SCENES = sorted((ROOT / "scenes").glob("*.toml"))


def _cli() -> str:
    """The `bead` binary: $BEAD_CLI, else the debug build in the cargo target directory."""
    given = os.environ.get("BEAD_CLI")
    if given:
        return given
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    for profile in ("debug", "release"):
        candidate = target / profile / "bead"
        if candidate.exists():
            return str(candidate)
    found = shutil.which("bead")
    if found:
        return found
    raise RuntimeError(
        "the parity tests need the bead command-line tool: run `cargo build -p bead-cli` "
        "or set BEAD_CLI to its path"
    )


@pytest.fixture(scope="session")
def cli():
    """Run `bead ARGS...`; returns (exit code, stdout, stderr)."""
    binary = _cli()

    def run(*args):
        done = subprocess.run(
            [binary, *map(str, args)], capture_output=True, text=True, cwd=ROOT
        )
        return done.returncode, done.stdout, done.stderr

    return run


@pytest.fixture(scope="session")
def cli_json(cli):
    """`bead run ARGS... --json` as a dict (the summary is printed even when the run fails)."""

    def run(*args):
        code, out, err = cli("run", *args, "--json")
        return code, json.loads(out) if out else None, err

    return run


def scene_path(name: str) -> str:
    return str(ROOT / "scenes" / name)
