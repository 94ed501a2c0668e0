"""The house's layering, read from the source with ``ast`` (nothing is imported):

zipon (API, CLI) -> stages, orion_eval -> pipeline packages -> stores / geometry / config. The library
(``pipeline``) imports none of the layers above it, the evaluator neither ``stages`` nor ``zipon``; each
``stages/<name>.py`` is its ``Config`` and a short ``run(ctx)`` over one library function; no two project
modules import each other at module level. The checks are
run on a small made-up tree first, so a check that finds nothing has been seen to find something.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("pipeline", "stages", "orion_eval", "zipon")

# Which top-level packages each layer may import: pipeline is the library, stages the stage modules over it,
# orion_eval the evaluator over the library, zipon what users touch (the API, the CLI, the annotation server), which
# may import everything. No exceptions.
MAY_IMPORT = {"pipeline": {"pipeline"}, "stages": {"pipeline", "stages"}, "orion_eval": {"pipeline", "orion_eval"},
              "zipon": {"pipeline", "stages", "orion_eval", "zipon"}}
# Module-level import cycles that exist today, each with the issue item that removes it.
MODULE_LEVEL_CYCLES_ALLOWED: dict[frozenset[str], str] = {}
# Cycles closed only by imports inside functions (they work, but a module still needs its importer).
DEFERRED_CYCLES_ALLOWED = {**MODULE_LEVEL_CYCLES_ALLOWED}


# ----------------------------------------------------------------------------- reading imports


def project_modules(root: Path, packages=PACKAGES) -> dict[str, Path]:
    """``{dotted module name: file}`` of every module of ``packages`` under ``root``."""
    found = {}
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _module_level(body: list[ast.stmt]):
    """Import statements Python runs when the module is imported: the module body, its if/try/with blocks and
    class bodies; not functions, not ``if TYPE_CHECKING:`` blocks."""
    for node in body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, ast.If):
            if not _is_type_checking(node.test):
                yield from _module_level(node.body)
            yield from _module_level(node.orelse)
        elif isinstance(node, ast.Try):
            for block in (node.body, node.orelse, node.finalbody, *(h.body for h in node.handlers)):
                yield from _module_level(block)
        elif isinstance(node, (ast.With, ast.ClassDef)):
            yield from _module_level(node.body)


def imports(path: Path, module: str, modules: dict[str, Path], *, module_level: bool) -> list[tuple[str, int]]:
    """``(project module, line)`` for every import in ``path``: ``from a import b`` names ``a.b`` when that is a
    module, else ``a``; relative imports are resolved against ``module``'s package."""
    tree = ast.parse(path.read_bytes(), filename=str(path))
    nodes = _module_level(tree.body) if module_level else (
        n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom)))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in nodes:
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([node.module] if node.module else []))
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        found += [(name, node.lineno) for name in names if name.split(".")[0] in PACKAGES]
    return found


def import_cycles(modules: dict[str, Path], *, module_level: bool) -> list[frozenset[str]]:
    """Strongly connected groups of two or more modules in the import graph (Tarjan, iterative)."""
    graph = {m: sorted({n for n, _ in imports(p, m, modules, module_level=module_level) if n in modules} - {m})
             for m, p in modules.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups = []
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(graph[start]))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, edges = work[-1]
            nxt = next(edges, None)
            if nxt is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    group = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        group.add(member)
                        if member == node:
                            break
                    if len(group) > 1:
                        groups.append(frozenset(group))
            elif nxt not in index:
                index[nxt] = low[nxt] = len(index)
                stack.append(nxt)
                on_stack.add(nxt)
                work.append((nxt, iter(graph[nxt])))
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
    return groups


def layer_violations(root: Path) -> list[str]:
    """``file:line imports NAME`` for every import (any scope) of a package its layer may not import
    (:data:`MAY_IMPORT`)."""
    modules = project_modules(root)
    return [f"{path.relative_to(root).as_posix()}:{line} imports {name}"
            for module, path in modules.items()
            for name, line in imports(path, module, modules, module_level=False)
            if name.split(".")[0] in MAY_IMPORT and name.split(".")[0] not in MAY_IMPORT[module.split(".")[0]]]


def _outside(groups: list[frozenset[str]], allowed) -> list[list[str]]:
    return [sorted(g) for g in groups if not any(g <= a for a in allowed)]


# ----------------------------------------------------------------------------- the checks, first on a made-up tree


@pytest.fixture
def toy_tree(tmp_path):
    files = {
        "pipeline/__init__.py": "",
        "pipeline/a.py": "from pipeline import b\n",
        "pipeline/b.py": "from . import a\n",  # a <-> b at module level
        "pipeline/c.py": "def f():\n    from pipeline import d\n",
        "pipeline/d.py": "from pipeline.c import f\n",  # c <-> d only through a function
        "pipeline/e.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pipeline import a\n",
        "pipeline/sub/__init__.py": "from .leaf import X\n",
        "pipeline/sub/leaf.py": "X = 1\n",
        "pipeline/cli.py": "def main():\n    from stages import STAGES\n",
        "orion_eval/run.py": "import zipon\n",
        "stages/__init__.py": "from pipeline import a\n",
        "orion_eval/__init__.py": "",
        "zipon/__init__.py": "import stages.x\n",
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    return tmp_path


def test_the_checks_find_what_a_made_up_tree_holds(toy_tree):
    modules = project_modules(toy_tree)
    assert set(import_cycles(modules, module_level=True)) == {frozenset({"pipeline.a", "pipeline.b"})}
    assert set(import_cycles(modules, module_level=False)) == {frozenset({"pipeline.a", "pipeline.b"}),
                                                               frozenset({"pipeline.c", "pipeline.d"})}
    assert layer_violations(toy_tree) == ["pipeline/cli.py:2 imports stages", "orion_eval/run.py:1 imports zipon"]


# ----------------------------------------------------------------------------- the checks on the project


def test_no_layer_imports_a_layer_above_it():
    assert layer_violations(ROOT) == [], "imports against the layering (zipon -> stages, orion_eval -> pipeline)"


def test_no_import_cycles_at_module_level():
    cycles = import_cycles(project_modules(ROOT), module_level=True)
    assert _outside(cycles, MODULE_LEVEL_CYCLES_ALLOWED) == []


def test_no_new_cycles_through_imports_inside_functions():
    cycles = import_cycles(project_modules(ROOT), module_level=False)
    assert _outside(cycles, DEFERRED_CYCLES_ALLOWED) == []


STAGE_MODULES = sorted(p for p in (ROOT / "stages").glob("*.py") if p.name != "__init__.py")


@pytest.mark.parametrize("path", STAGE_MODULES, ids=lambda p: p.stem)
def test_a_stage_is_its_config_and_a_short_run_over_the_library(path):
    """The stage rule (docs: architecture): ``Config`` + ``run(ctx)`` of at most 40 lines and no loop of its own; it imports
    the library, not another stage."""
    tree = ast.parse(path.read_text())
    defs = {n.name: n for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    configs = {t.id for n in tree.body if isinstance(n, ast.Assign) for t in n.targets if isinstance(t, ast.Name)}
    assert "Config" in defs or "Config" in configs, f"{path.name}: no Config"
    run = defs.get("run")
    assert isinstance(run, ast.FunctionDef), f"{path.name}: no run(ctx)"
    assert run.end_lineno - run.lineno + 1 <= 40, f"{path.name}: run() has {run.end_lineno - run.lineno + 1} lines"
    loops = [n.lineno for n in ast.walk(run) if isinstance(n, (ast.For, ast.While, ast.comprehension))]
    assert loops == [], f"{path.name}: run() loops at lines {loops}; the work belongs in the library"
    modules = project_modules(ROOT)
    own = [n for n, _ in imports(path, f"stages.{path.stem}", modules, module_level=False)]
    assert [n for n in own if n.split(".")[0] == "stages"] == []
    assert any(n.split(".")[0] == "pipeline" for n in own)


# A store module owns its data types and attrs model; it may import only leaves (config, errors, geometry, the
# store helpers, the ground-truth schema, the numpy scoring kernel) and the record schemas it stores, never the
# algorithms that fill it (any scope, ``if TYPE_CHECKING:`` included).
STORE_MODULES = ("pipeline.store", "pipeline.frames", "pipeline.maps.store", "pipeline.recon.store",
                 "pipeline.routes.store", "pipeline.goals.store")
STORE_MAY_IMPORT = {"pipeline", "pipeline.config", "pipeline.stageconfig", "pipeline.errors", "pipeline.geometry", "pipeline.store",
                    "pipeline.scene_gt", "pipeline.maps.scoring",
                    # the goal document and object record schemas (pydantic) the goals store holds
                    "pipeline.goals.objects", "pipeline.goals.schema",
                    # the action codes routes.zarr stores (constants only)
                    "pipeline.nav.codes",
                    # the floor records (Floor) a building's map stores keep, as recon.zarr defines them
                    "pipeline.recon.store",
                    # the window of cells (and stored tiles) a reader of a region reads (a leaf: geometry, errors)
                    "pipeline.region"}


def test_stores_import_no_algorithm_that_fills_them():
    modules = project_modules(ROOT)
    found = {m: sorted({n for n, _ in imports(modules[m], m, modules, module_level=False)} - STORE_MAY_IMPORT)
             for m in STORE_MODULES}
    assert {m: names for m, names in found.items() if names} == {}


# pipeline.config (the schema), pipeline.paramsfile (reading it) and pipeline.stageconfig (digests) are read by every
# command, the fast ones (status, params, query) included: they stay leaves (the params sections live in the schema and
# its per-area modules, each built-in encoder's settings in its own torch-free module; docs: architecture, design
# decisions).
PARAMS_MODULES = {"pipeline.ingest_params", "pipeline.eval_params", "pipeline.maps_params", "pipeline.encoder_params",
                  "pipeline.encoder_params.perception", "pipeline.encoder_params.lseg",
                  "pipeline.encoder_params.maskclip", "pipeline.encoder_params.conceptfusion",
                  "pipeline.encoder_params.torchscript", "pipeline.encoder_params.oracle"}
CONFIG_MAY_IMPORT = {"pipeline", "pipeline.errors", "pipeline.plugins", "pipeline.section", *PARAMS_MODULES,
                     "pipeline.config",
                     # the bounded YAML/JSON loader params files are read through (a leaf: errors, yaml, json)
                     "pipeline.userfiles",
                     # the cross-field checks run at load (a leaf: errors, os)
                     "pipeline.paramchecks"}


@pytest.mark.parametrize("start", ["pipeline.config", "pipeline.paramsfile", "pipeline.stageconfig"])
def test_config_and_what_it_imports_are_leaves(start):
    modules = project_modules(ROOT)
    seen, todo = set(), [start]
    while todo:
        name = todo.pop()
        seen.add(name)
        for dep, line in imports(modules[name], name, modules, module_level=False):
            assert dep in CONFIG_MAY_IMPORT | {start}, f"{modules[name]}:{line} imports {dep}"
            if dep not in seen and dep != "pipeline":
                todo.append(dep)
    assert {"pipeline.config", "pipeline.section", *PARAMS_MODULES} <= seen | {start}
