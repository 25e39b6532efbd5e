"""The type stubs name exactly what the native module has, so that editors complete the real
API (a cheap guard against drift, like mypy's stubtest)."""

import ast
from pathlib import Path

import bead
from bead import _bead

STUB = Path(bead.__file__).with_name("_bead.pyi")


def stubbed():
    tree = ast.parse(STUB.read_text())
    names, members = set(), {}
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.AnnAssign):
            names.add(node.target.id)
        if isinstance(node, ast.ClassDef):
            members[node.name] = {n.name for n in node.body
                                  if isinstance(n, ast.FunctionDef) and not n.name.startswith("_")}
    return names, members


def public(obj):
    return {n for n in dir(obj) if not n.startswith("_")}


def test_stubs_cover_the_native_module():
    names, members = stubbed()
    assert names == public(_bead) | {"__version__"}
    for cls in ("Scene", "Simulation", "SweepPlan"):
        assert members[cls] == public(getattr(_bead, cls)), cls


def test_package_exports_what_it_documents():
    assert set(bead.__all__) <= set(dir(bead))
    assert {"load", "loads", "Scene", "Simulation", "Run", "SceneError", "RunError"} <= set(bead.__all__)
