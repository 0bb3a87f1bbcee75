"""Architecture rules of the package (issue 16), checked on the source with ``ast`` (fast, no imports).

* no import cycles between the modules of ``imls_lightning/`` and ``data_gen/``, counting imports
  inside functions too (a lazy import only hides a cycle), and the module names a module loads by
  string (``importlib.import_module``, ``hydra.utils.get_class``, ...; :func:`_loaded_by_name`);
* no module imports another module's private ``_name``: what is shared has a public name in its one
  home. Only the package is checked; tests may reach private names;
* no module imports the top-level package ``imls_lightning`` (its lazy public API, see
  ``tests/test_public_api.py``);
* packages form layers that point one way (issue 87, :data:`LAYERS`): no module imports a module of a higher
  layer, at module level or inside a function.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("imls_lightning", "data_gen", "hydra_plugins")


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = path
    return mods


def _absolute(module: str, path: Path, node: ast.ImportFrom) -> str:
    """The absolute name ``from ... import`` refers to (relative imports resolved)."""
    if not node.level:
        return node.module or ""
    base = module.split(".")
    if path.name != "__init__.py":
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


#: calls that import a module named by a string
LOADERS = ("import_module", "__import__", "get_class", "get_method", "get_object", "locate", "_locate")


def _loaded_by_name(tree: ast.AST, mods) -> set[str]:
    """The package modules a module may load by name: in a module that calls one of :data:`LOADERS`,
    every string constant naming a package module (``"pkg.mod"``) or a name in one (``"pkg.mod.Class"``).
    A string names its module only; the scan does not follow which string reaches which call."""
    calls = (n.func for n in ast.walk(tree) if isinstance(n, ast.Call))
    if not any((f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")) in LOADERS for f in calls):
        return set()
    names = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    return {s if s in mods else s.rpartition(".")[0] for s in names if s in mods or s.rpartition(".")[0] in mods}


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _scan():
    """``(edges, private)``: module -> package modules it imports (anywhere in it), and every
    ``(module, line, what)`` that reaches another module's private name."""
    mods = _modules()
    edges: dict[str, set[str]] = {}
    private: list[tuple[str, int, str]] = []
    for mod, path in mods.items():
        tree = ast.parse(path.read_text(), str(path))
        deps: set[str] = set()
        aliases: dict[str, str] = {}  # local name -> package module it is bound to
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                src = _absolute(mod, path, node)
                for a in node.names:
                    full = f"{src}.{a.name}"
                    if full in mods:  # from pkg import module
                        deps.add(full)
                        aliases[a.asname or a.name] = full
                    else:
                        deps.add(src)
                        if _private(a.name) and src in mods and src != mod:
                            private.append((mod, node.lineno, f"from {src} import {a.name}"))
            elif isinstance(node, ast.Import):
                for a in node.names:
                    deps.add(a.name)
                    if a.asname:
                        aliases[a.asname] = a.name
                    elif a.name in mods:
                        aliases[a.name] = a.name
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and _private(node.attr):
                target = ast.unparse(node.value)
                target = aliases.get(target, target)
                if target in mods and target != mod:
                    private.append((mod, node.lineno, f"{target}.{node.attr}"))
        deps |= _loaded_by_name(tree, mods)
        edges[mod] = {d for d in deps if d in mods and d != mod}
    return edges, private


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles():
    edges, _ = _scan()
    assert "imls_lightning.train" in edges and "imls_lightning.orp" in edges["imls_lightning.train"]
    # the packages are scanned module by module (a package's __init__ is the package's own name)
    assert {"imls_lightning.orp.search", "imls_lightning.orp.job", "imls_lightning.adaptive.cli",
            "imls_lightning.adaptive.labels", "imls_lightning.report.plots"} <= set(edges)
    assert "imls_lightning.orp.search" in edges["imls_lightning.orp.job"]
    assert _cycles(edges) == []


def test_top_level_package_is_imported_by_no_module():
    """``imls_lightning/__init__.py`` imports its public names lazily, by name (``HOMES``), which the
    scan does not see; it stays out of every cycle as long as no module of the packages imports it."""
    edges, _ = _scan()
    assert sorted(m for m, deps in edges.items() if "imls_lightning" in deps) == []
    tree = ast.parse((ROOT / "imls_lightning" / "__init__.py").read_text())
    homes = next(ast.literal_eval(n.value) for n in tree.body
                 if isinstance(n, ast.AnnAssign) and getattr(n.target, "id", "") == "HOMES")
    assert set(homes.values()) <= set(edges), "every home of a public name is a module of the package"


def test_modules_loaded_by_name_count_as_imports():
    """A registry of module names that ``importlib`` loads is an import the ``import`` statements hide:
    ``inference.checkpoints`` loads the tasks by name, so no task may import it back."""
    mods = {"pkg.a", "pkg.b", "pkg.c"}
    loads = ast.parse('import importlib\nTASKS = {"B": "pkg.b", "C": "pkg.c.C", "x": "pkg.d"}\n'
                      'def load(n):\n    return importlib.import_module(TASKS[n])')
    assert _loaded_by_name(loads, mods) == {"pkg.b", "pkg.c"}
    assert _loaded_by_name(ast.parse('CMD = ["-m", "pkg.b"]'), mods) == set()  # a string alone is no import
    edges, _ = _scan()
    assert {"imls_lightning.tasks.ims", "imls_lightning.tasks.las"} <= edges["imls_lightning.inference.checkpoints"]
    assert "imls_lightning.tasks.ims" in edges["imls_lightning"]  # the lazy public API (HOMES)


# ------------------------------------------------------------------------------------------------
# layers (issue 87): the package graph points one way

#: the layers, lowest first; a package may import its own layer and those below it, never one above. ``entry points``
#: are the modules directly under ``imls_lightning/`` (the CLIs, thin) and ``imls_lightning`` is the lazy public API.
LAYERS = (
    ("base",),                                   # errors, validation, override quoting, atomic files, settings hashes
    ("render",),                                 # the ray casters and what they render (volume, scene, camera rays)
    ("data_gen",),                               # volume readers, procedural volumes, scenes from config, views, cache
    ("core",),                                   # the method's formulas (patterns, compaction, importance, metrics, fill)
    ("models",),                                 # the networks
    ("tasks", "training", "data"),               # training them (LightningModules, the fit, the data module, labels)
    ("inference",),                              # the product: trained networks run, checkpoints loaded by task name
    ("report",),                                 # the one writer of tables, plots and documents the measurements call
    ("evaluation", "estimate", "orp", "adaptive"),  # the measurements
    ("pipelines",),                              # the CLIs chained (demo, bench, bench_paper, size_search, reproduce)
    ("entry points", "viewer", "web", "hydra_plugins", "imls_lightning"),
)


def _package(module: str) -> str:
    """The package a module belongs to: ``imls_lightning.<pkg>.*`` -> ``<pkg>``, a module directly under
    ``imls_lightning/`` -> ``entry points``, ``data_gen.*`` -> ``data_gen``."""
    parts = module.split(".")
    if parts[0] != "imls_lightning" or len(parts) == 1:
        return parts[0]
    if (ROOT / "imls_lightning" / parts[1]).is_dir():
        return parts[1]
    return "entry points"


def _arrows_up(edges: dict[str, set[str]], layers=LAYERS) -> list[str]:
    """Every import from a lower layer's module of a higher layer's module, as
    ``importer (package) imports imported (package)``; a module of no layer is reported too."""
    rank = {pkg: i for i, layer in enumerate(layers) for pkg in layer}
    out = []
    for mod in sorted(edges):
        a = _package(mod)
        if a not in rank:
            out.append(f"{mod}: package {a!r} is in no layer of LAYERS")
            continue
        for dep in sorted(edges[mod]):
            b = _package(dep)
            if b in rank and rank[b] > rank[a]:
                out.append(f"{mod} ({a}) imports {dep} ({b}): an arrow up")
    return out


def test_layers_point_one_way():
    """The package graph, drawn from every import of every module (module level and inside functions, and the
    modules loaded by name), has no arrow up: a lower package never imports a higher one."""
    assert _arrows_up({"imls_lightning.core.x": {"imls_lightning.models.y", "imls_lightning.base.errors"},
                       "imls_lightning.models.y": {"imls_lightning.core.x"}}) == [
        "imls_lightning.core.x (core) imports imls_lightning.models.y (models): an arrow up"]
    assert _package("imls_lightning.train") == "entry points" and _package("data_gen.cache") == "data_gen"
    edges, _ = _scan()
    assert {"imls_lightning.render.vtk", "imls_lightning.base.errors", "hydra_plugins.orp_sweeper.orp_sweeper"} <= set(edges)
    found = _arrows_up(edges)
    assert found == [], "\n".join(found)


def test_render_and_base_stand_alone():
    """The ray casters import only the foundation, and the foundation none of the project."""
    edges, _ = _scan()
    for mod, deps in edges.items():
        if _package(mod) == "render":
            assert {_package(d) for d in deps} <= {"render", "base"}, (mod, deps)
        if _package(mod) == "base":
            assert {_package(d) for d in deps} <= {"base"}, (mod, deps)


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_private_imports_across_modules():
    _, private = _scan()
    assert private == [], "\n".join(f"{m}:{line}: {what}" for m, line, what in private)


#: what a function may call on a module-level container to change it
_MUTATORS = {"append", "extend", "insert", "update", "clear", "pop", "remove", "add", "discard", "setdefault"}


def _module_state_filled_by_functions(tree: ast.Module) -> list[tuple[str, int]]:
    """``(name, line)`` of every module-level list / dict / set that a function of the module fills
    (item or slice assignment, a mutating method) or rebinds (``global``)."""
    names = set()
    for node in tree.body:
        target = node.targets[0] if isinstance(node, ast.Assign) and len(node.targets) == 1 else getattr(node, "target", None)
        if isinstance(target, ast.Name) and isinstance(getattr(node, "value", None), (ast.List, ast.Dict, ast.Set)):
            names.add(target.id)
    out = []
    for fn in (n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))):
        for n in ast.walk(fn):
            if isinstance(n, ast.Global):
                out += [(name, n.lineno) for name in n.names]
            targets = n.targets if isinstance(n, ast.Assign) else [n.target] if isinstance(n, ast.AugAssign) else []
            for t in (x for tt in targets for x in ast.walk(tt)):
                if isinstance(t, ast.Subscript) and isinstance(t.value, ast.Name) and t.value.id in names:
                    out.append((t.value.id, n.lineno))
            if (isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr in _MUTATORS
                    and isinstance(n.func.value, ast.Name) and n.func.value.id in names):
                out.append((n.func.value.id, n.lineno))
    return out


def test_entry_points_keep_no_module_state():
    """An entry point (a module directly under ``imls_lightning/`` with a ``main``) hands its command
    line to Hydra without a module-level list that ``main`` fills (the scene overrides reach the
    ``@hydra.main`` function through its closure): a later call cannot see an earlier one's."""
    assert _module_state_filled_by_functions(ast.parse("X = []\ndef main():\n    X[:] = [1]")) == [("X", 3)]
    found = []
    for path in sorted((ROOT / "imls_lightning").glob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        if any(isinstance(n, ast.FunctionDef) and n.name == "main" for n in tree.body):
            found += [f"{path.name}:{line}: {name}" for name, line in _module_state_filled_by_functions(tree)]
    assert found == [], "\n".join(found)


# ------------------------------------------------------------------------------------------------
# thin entry points (issue 33): a module directly under imls_lightning/ parses its config and calls a package

#: modules directly under ``imls_lightning/`` that are no entry point
NOT_ENTRY_POINTS = ("__init__.py",)
#: the most lines an entry point may have
ENTRY_POINT_LINES = 150
#: the most lines a function may have (numba kernels excepted: a kernel is one loop nest numba compiles whole)
FUNCTION_LINES = 120


def _entry_points() -> list[Path]:
    return [p for p in sorted((ROOT / "imls_lightning").glob("*.py")) if p.name not in NOT_ENTRY_POINTS]


def _entry_point_modules() -> set[str]:
    """Every module run with ``python -m``: the modules directly under ``imls_lightning/`` (but
    :data:`NOT_ENTRY_POINTS`) and every package's ``__main__``."""
    mods = {f"imls_lightning.{p.stem}" for p in _entry_points()}
    for pkg in PACKAGES:
        mods |= {".".join(m.relative_to(ROOT).with_suffix("").parts) for m in (ROOT / pkg).rglob("__main__.py")}
    return mods


def _script_imports() -> dict[str, set[str]]:
    """``scripts/*.py`` -> the modules it imports (anywhere in it)."""
    out = {}
    for path in sorted((ROOT / "scripts").glob("*.py")):
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and not node.level and node.module:
                deps |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
            elif isinstance(node, ast.Import):
                deps |= {a.name for a in node.names}
        out[f"scripts/{path.name}"] = deps
    return out


#: the most lines a file of ``scripts/`` may have (issue 87, 5: a longer one becomes a package command or leaves)
SCRIPT_LINES = 150


def _script_breaches(folder: Path) -> list[str]:
    """What a ``scripts/`` folder breaks: a file over :data:`SCRIPT_LINES` lines, or a Python file that calls
    ``sys.path.insert`` (a script imports the installed package as any user's code does, or it is a package command)."""
    found = []
    paths = sorted(p for p in folder.rglob("*") if p.is_file() and "__pycache__" not in p.parts) if folder.is_dir() else []
    for path in paths:
        text = path.read_text(errors="replace")
        if (n := len(text.splitlines())) > SCRIPT_LINES:
            found.append(f"{path.relative_to(folder.parent)}: {n} lines")
        if path.suffix == ".py" and any(
                isinstance(c, ast.Call) and ast.unparse(c.func) == "sys.path.insert" for c in ast.walk(ast.parse(text, str(path)))):
            found.append(f"{path.relative_to(folder.parent)}: calls sys.path.insert")
    return found


def test_scripts_follow_the_package_rules(tmp_path):
    """``scripts/``, where it exists, holds no file over :data:`SCRIPT_LINES` lines and none that calls
    ``sys.path.insert``; what a user runs again is a package command (``python -m imls_lightning...``) with tests."""
    folder = tmp_path / "scripts"
    folder.mkdir()
    (folder / "ok.py").write_text("import sys\nprint(sys.path[0])\n")
    (folder / "hack.py").write_text("import sys\nsys.path.insert(0, '..')\n")
    (folder / "long.sh").write_text("echo\n" * (SCRIPT_LINES + 1))
    assert _script_breaches(folder) == ["scripts/hack.py: calls sys.path.insert", f"scripts/long.sh: {SCRIPT_LINES + 1} lines"]
    assert _script_breaches(tmp_path / "none") == []
    found = _script_breaches(ROOT / "scripts")
    assert found == [], "scripts/ breaks the package's rules (make it a package command or delete it):\n" + "\n".join(found)


def test_entry_points_are_thin():
    """An entry point parses its config and calls a package: at most :data:`ENTRY_POINT_LINES` lines."""
    long = {p.name: n for p in _entry_points() if (n := len(p.read_text().splitlines())) > ENTRY_POINT_LINES}
    assert long == {}, f"entry points over {ENTRY_POINT_LINES} lines (move the logic into a package): {long}"


def test_no_entry_point_imports_another():
    """What two entry points share lives in a package (``imls_lightning.pipelines``,
    ``imls_lightning.evaluation``, ...), never in one of them: no module of the packages and no script
    imports an entry point."""
    edges, _ = _scan()
    entries = _entry_point_modules()
    assert {"imls_lightning.evaluate", "imls_lightning.demo", "imls_lightning.adaptive.__main__"} <= entries
    found = sorted(f"{m} imports {d}" for m in edges for d in edges[m] & entries if d != m)
    found += sorted(f"{m} imports {d}" for m, deps in _script_imports().items() for d in deps & entries)
    assert found == [], "\n".join(found)


def _numba_kernel(fn: ast.AST) -> bool:
    """A function decorated with ``numba.njit`` / ``jit`` / ``guvectorize`` / ... (also called: ``@njit(...)``)."""
    for dec in getattr(fn, "decorator_list", []):
        target = dec.func if isinstance(dec, ast.Call) else dec
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name in ("njit", "jit", "vectorize", "guvectorize", "stencil", "cfunc") or "numba" in ast.unparse(target):
            return True
    return False


def _long_functions(tree: ast.AST, limit: int = FUNCTION_LINES) -> list[tuple[str, int, int]]:
    return [(fn.name, fn.lineno, fn.end_lineno - fn.lineno + 1) for fn in ast.walk(tree)
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)) and fn.end_lineno - fn.lineno + 1 > limit
            and not _numba_kernel(fn)]


def test_no_long_functions():
    """No function over :data:`FUNCTION_LINES` lines (numba kernels excepted): a long body is split into named steps."""
    kernel = "import numba\n@numba.njit(cache=True)\ndef k(x):\n" + "    x += 1\n" * 130 + "    return x\n"
    assert _long_functions(ast.parse(kernel)) == []
    assert _long_functions(ast.parse(kernel.replace("@numba.njit(cache=True)\n", ""))) == [("k", 2, 132)]
    found = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            found += [f"{path.relative_to(ROOT)}:{line}: {name} ({n} lines)"
                      for name, line, n in _long_functions(ast.parse(path.read_text(), str(path)))]
    assert found == [], "\n".join(found)
