"""The .pyi stub lists every public name of nudge._native with the module's signatures and
defaults, and the package re-exports the module."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import nudge
import nudge._native as native

STUB = Path(nudge.__file__).with_name("_native.pyi")


def _tree() -> ast.Module:
    return ast.parse(STUB.read_text())


def _stub_names() -> set[str]:
    names: set[str] = set()
    for node in _tree().body:
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
    private_helpers = {n for n in _stub_names() if n.startswith("_")} | {"Timings", "PlanResult", "LaneViolation"}
    stale = _stub_names() - _public(native) - private_helpers - {"__version__"}
    assert not stale, f"{STUB.name} lists names nudge._native lacks: {sorted(stale)}"


def test_stub_lists_every_method_of_every_class() -> None:
    for node in _tree().body:
        if not isinstance(node, ast.ClassDef) or not hasattr(native, node.name):
            continue
        cls = getattr(native, node.name)
        if isinstance(cls, type) and issubclass(cls, BaseException):
            continue
        stub_members = {n.name for n in node.body if isinstance(n, ast.FunctionDef)}
        missing = _public(cls) - stub_members
        assert not missing, f"{node.name}: members missing from the stub: {sorted(missing)}"


def _stub_signature(fn: ast.FunctionDef) -> list[tuple[str, str, str | None]]:
    """(name, kind, default source or None) of every parameter, `self` dropped."""
    a = fn.args
    out: list[tuple[str, str, str | None]] = []
    positional = a.posonlyargs + a.args
    defaults: list[ast.expr | None] = [None] * (len(positional) - len(a.defaults)) + list(a.defaults)
    for arg, d in zip(positional, defaults):
        out.append((arg.arg, "positional", None if d is None else ast.unparse(d)))
    if a.vararg:
        out.append((a.vararg.arg, "*", None))
    for arg, d in zip(a.kwonlyargs, a.kw_defaults):
        out.append((arg.arg, "keyword", None if d is None else ast.unparse(d)))
    if a.kwarg:
        out.append((a.kwarg.arg, "**", None))
    decorators = {ast.unparse(d) for d in fn.decorator_list}
    if "staticmethod" not in decorators and out and out[0][0] in ("self", "cls"):
        out = out[1:]
    return out


def _native_signature(obj: object) -> list[tuple[str, str, str | None]]:
    """The same from the text signature pyo3 generates (`...` for a default computed in Rust)."""
    sig = inspect.signature(obj)  # type: ignore[arg-type]
    kinds = {
        inspect.Parameter.POSITIONAL_ONLY: "positional",
        inspect.Parameter.POSITIONAL_OR_KEYWORD: "positional",
        inspect.Parameter.VAR_POSITIONAL: "*",
        inspect.Parameter.KEYWORD_ONLY: "keyword",
        inspect.Parameter.VAR_KEYWORD: "**",
    }
    out = []
    for p in sig.parameters.values():
        if p.name in ("self", "cls", "$self", "$cls"):
            continue
        d = None if p.default is inspect.Parameter.empty else ("..." if p.default is Ellipsis else repr(p.default))
        out.append((p.name, kinds[p.kind], d))
    return out


def _stub_functions() -> dict[str, ast.FunctionDef]:
    """`name` or `Class.name` -> stub definition (the first of overloads)."""
    found: dict[str, ast.FunctionDef] = {}
    for node in _tree().body:
        if isinstance(node, ast.FunctionDef):
            found.setdefault(node.name, node)
        elif isinstance(node, ast.ClassDef):
            for m in node.body:
                if isinstance(m, ast.FunctionDef):
                    found.setdefault(f"{node.name}.{m.name}", m)
    return found


def test_stub_signatures_and_defaults_match_the_module() -> None:
    checked = 0
    for key, fn in _stub_functions().items():
        owner, _, name = key.rpartition(".")
        if (name.startswith("__") and name != "__init__") or owner.startswith("_"):
            continue  # owner "_X": a typing helper of the stub only (e.g. a Protocol)
        if name == "__init__":  # the constructor's signature is the class's
            target = getattr(native, owner)
        else:
            target = getattr(getattr(native, owner), name) if owner else getattr(native, name, None)
        if target is None or getattr(target, "__text_signature__", None) is None:
            continue
        if owner and name != "__init__" and isinstance(inspect.getattr_static(getattr(native, owner), name), property):
            continue
        assert _stub_signature(fn) == _native_signature(target), key
        checked += 1
    assert checked >= 15, f"only {checked} signatures compared"


def test_defaults_come_from_rust() -> None:
    """The defaults the Rust signatures leave as `...` are the Rust constants, and the Python
    wrapper shows them."""
    sig = inspect.signature(nudge.simulate)
    assert sig.parameters["predictor"].default == native.DEFAULTS["predictor"] == "student"
    assert sig.parameters["seed"].default == native.DEFAULTS["seed"] == 0
    assert sig.parameters["runs"].default == native.DEFAULTS["runs"] == 1
    assert native.DEFAULTS["world_predictor"] == "teacher"
    cfg = nudge.SimConfig.default()
    assert (cfg.world, cfg.max_steps, cfg.abort_after, cfg.abort_hold) == ("teacher", 30, 4, 3)
    # The wrapper passes every native keyword through but those it fills itself (the package's
    # assets, the process's command line for provenance), and adds only the Ray fan-out.
    native_kw = {n for n, k, _ in _native_signature(native.simulate) if k == "keyword"} - {"assets", "command"}
    wrapper_kw = {p.name for p in sig.parameters.values() if p.kind is inspect.Parameter.KEYWORD_ONLY}
    assert native_kw == wrapper_kw - {"ray", "ray_chunk"}
    assert {"ray", "ray_chunk"} <= wrapper_kw and {"out", "planner", "progress"} <= native_kw


def test_package_reexports_the_module() -> None:
    # The package wraps the asset resolvers (with its own assets), runs cli_main as its
    # `nudge` command (nudge.__main__) and animates every run of simulate's records with the
    # native animate (one trace each).
    wrapped = {"simulate", "model_path", "assets_dir", "scenes_dir", "cli_main", "animate"}
    for name in _public(native) - wrapped:
        assert getattr(nudge, name) is getattr(native, name), name
    # nudge.simulate wraps the native one (resolves named models under the assets directory).
    assert callable(nudge.simulate)
    assert nudge.model_path("teacher") == nudge.assets_dir() / "models" / "teacher.safetensors"
    assert nudge.assets_dir() == native.assets_dir(nudge.SHIPPED_ASSETS)
    assert nudge.scene_paths()[0].parent == native.scenes_dir(nudge.assets_dir())
    assert (Path(nudge.__file__).parent / "py.typed").exists()
    assert callable(nudge.animate) and nudge.animate is not native.animate
