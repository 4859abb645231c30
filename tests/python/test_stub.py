"""The .pyi stub lists every public name of nudge._native, and the package re-exports them."""

from __future__ import annotations

import ast
from pathlib import Path

import nudge
import nudge._native as native

STUB = Path(nudge.__file__).with_name("_native.pyi")


def _stub_names() -> set[str]:
    tree = ast.parse(STUB.read_text())
    names: set[str] = set()
    for node in tree.body:
        if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
            names.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, ast.Name))
    return names


def _public(obj: object) -> set[str]:
    return {n for n in dir(obj) if not n.startswith("_")}


def test_every_module_name_is_in_the_stub() -> None:
    missing = (_public(native) | {"__version__"}) - _stub_names()
    assert not missing, f"nudge._native names missing from {STUB.name}: {sorted(missing)}"


def test_stub_has_no_stale_names() -> None:
    private_helpers = {n for n in _stub_names() if n.startswith("_")} | {"Timings", "PlanResult"}
    stale = _stub_names() - _public(native) - private_helpers - {"__version__"}
    assert not stale, f"{STUB.name} lists names nudge._native lacks: {sorted(stale)}"


def test_stub_lists_every_method_of_every_class() -> None:
    tree = ast.parse(STUB.read_text())
    for node in tree.body:
        if not isinstance(node, ast.ClassDef) or not hasattr(native, node.name):
            continue
        cls = getattr(native, node.name)
        if isinstance(cls, type) and issubclass(cls, BaseException):
            continue
        stub_members = {n.name for n in node.body if isinstance(n, ast.FunctionDef)}
        missing = _public(cls) - stub_members
        assert not missing, f"{node.name}: members missing from the stub: {sorted(missing)}"


def test_package_reexports_the_module() -> None:
    for name in _public(native) - {"simulate"}:
        assert getattr(nudge, name) is getattr(native, name), name
    # nudge.simulate wraps the native one (resolves "teacher"/"student" to the shipped files).
    assert callable(nudge.simulate)
    assert (Path(nudge.__file__).parent / "py.typed").exists()
