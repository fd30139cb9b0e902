"""The receiver's layout: stage folders whose imports follow the data flow, no import cycle,
and no developer tool inside the installed package."""

from __future__ import annotations

import ast
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[2]
# Stage order of the data flow: a module may import only from its own stage or stages before it.
LAYER = {"core": 0, "io": 1, "vision": 2, "decode": 3, "locate": 4, "pipeline": 5, "serve": 6,
         "evaluate": 6, "calibrate": 6, "cli": 7}


def _modules() -> dict[str, set[str]]:
    """module -> the receiver modules it imports (top-level and inside functions)."""
    out = {}
    for path in (ROOT / "receiver").rglob("*.py"):
        mod = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("receiver"):
                deps.add(node.module)
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name.startswith("receiver"))
        out[mod] = deps
    for path in [*(ROOT / "receiver").rglob("*.pyx"), *(ROOT / "receiver").rglob("*.pxd")]:
        mod = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        out.setdefault(mod, set()).update(_cython_imports(path.read_text()))
    return out


# Cython's import lines: `from X cimport ...`, `from X import ...`, `cimport X`, `import X`
_CYTHON_IMPORT = re.compile(r"^\s*(?:from\s+(receiver[\w.]*)\s+c?import\b|c?import\s+(receiver[\w.]*))", re.M)


def _cython_imports(text: str) -> set[str]:
    """The receiver modules a .pyx / .pxd file imports or cimports."""
    return {m.group(1) or m.group(2) for m in _CYTHON_IMPORT.finditer(text)}


def test_cython_imports_are_read():
    text = "from receiver.core._buf cimport load\ncimport receiver.locate._loss\nfrom libc.math cimport sqrt\n"
    assert _cython_imports(text) == {"receiver.core._buf", "receiver.locate._loss"}


def _stage(mod: str) -> str:
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 else "receiver"


def test_imports_point_down_the_data_flow():
    bad = [(m, d) for m, deps in _modules().items() for d in deps
           if _stage(m) in LAYER and _stage(d) in LAYER and LAYER[_stage(d)] > LAYER[_stage(m)]]
    assert not bad, f"imports against the data flow: {bad}"


def test_same_level_stages_do_not_import_each_other():
    mods = _modules()
    bad = [(m, d) for m, deps in mods.items() for d in deps
           if _stage(m) != _stage(d) and _stage(m) in LAYER and _stage(d) in LAYER
           and LAYER[_stage(d)] == LAYER[_stage(m)]]
    assert not bad, bad


def test_no_import_cycle():
    graph = {m: {d for d in deps if d in _modules_cache} for m, deps in _modules_cache.items()}
    state: dict[str, int] = {}

    def visit(u, path):
        state[u] = 1
        for v in graph.get(u, ()):
            if state.get(v) == 1:
                raise AssertionError(f"import cycle: {' -> '.join(path[path.index(v):] + [v])}")
            if v not in state:
                visit(v, path + [v])
        state[u] = 2

    for m in graph:
        if m not in state:
            visit(m, [m])


_modules_cache = _modules()


def test_tools_is_not_an_installed_package():
    text = (ROOT / "pyproject.toml").read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("include = "))
    assert "tools" not in line, line


def test_every_stage_has_a_docstring_naming_its_modules():
    for stage in ("core", "io", "vision", "decode", "locate", "serve", "evaluate", "calibrate", "cli"):
        init = ROOT / "receiver" / stage / "__init__.py"
        assert ast.get_docstring(ast.parse(init.read_text())), f"receiver/{stage}/__init__.py has no docstring"
