"""A stage's code is the import closure of its module: editing any file it runs makes it stale, editing a
file it never imports does not. Checked on a copy of the project, edited in place."""

import json
import shutil

import pytest

from pipeline.engine import codedeps
from pipeline.errors import ZiponError
from stages import STAGES

ROOT = codedeps.ROOT


@pytest.fixture
def checkout(tmp_path):
    for name in ("pipeline", "stages", "orion_eval"):
        shutil.copytree(ROOT / name, tmp_path / name, ignore=shutil.ignore_patterns("__pycache__"))
    return tmp_path


def _digests(root):
    return {name: codedeps.code_digest(spec.module, root) for name, spec in STAGES.items()}


def _edit(path):
    path.write_text(path.read_text() + "\n# edited\n")


def test_geometry_reaches_the_map_stages(checkout):
    before = _digests(checkout)
    _edit(checkout / "pipeline" / "geometry.py")
    after = _digests(checkout)
    changed = {s for s in STAGES if before[s] != after[s]}
    assert {"vlmap", "cfmap", "reconstruct", "goals", "routes"} <= changed


def test_a_map_module_does_not_reach_ingest_or_reconstruct(checkout):
    before = _digests(checkout)
    _edit(checkout / "pipeline" / "maps" / "fusion.py")
    after = _digests(checkout)
    assert {s for s in STAGES if before[s] != after[s]} == {"vlmap", "cfmap"}


def test_a_module_imported_inside_a_function_counts(checkout):
    (checkout / "pipeline" / "lazy_dep.py").write_text("VALUE = 1\n")
    stage = checkout / "stages" / "routes.py"
    stage.write_text(stage.read_text() + "\n\ndef _uses_lazy():\n    from pipeline import lazy_dep\n\n"
                     "    return lazy_dep.VALUE\n")
    files = {p.relative_to(checkout).as_posix() for p in codedeps.import_closure("stages.routes", checkout)}
    assert "pipeline/lazy_dep.py" in files and "pipeline/__init__.py" in files and "stages/__init__.py" in files
    before = codedeps.code_digest("stages.routes", checkout)
    _edit(checkout / "pipeline" / "lazy_dep.py")
    assert codedeps.code_digest("stages.routes", checkout) != before


def test_changed_files_are_named(checkout):
    old = codedeps.file_digests("stages.vlmap", checkout)
    _edit(checkout / "pipeline" / "maps" / "fusion.py")
    assert codedeps.changed_files(old, codedeps.file_digests("stages.vlmap", checkout)) == ["pipeline/maps/fusion.py"]


def test_a_syntax_error_is_a_clear_error(checkout):
    (checkout / "stages" / "routes.py").write_text("def run(:\n")
    with pytest.raises(ZiponError, match=r"routes\.py:1: cannot read the imports of stages\.routes"):
        codedeps.import_closure("stages.routes", checkout)
    with pytest.raises(ZiponError, match="code module 'stages.nope' not found"):
        codedeps.import_closure("stages.nope", checkout)


NESTED = '''
import a
def f():
    import b
    class C:
        def g(self):
            from c import d
    try:
        import e
    except ImportError:
        import h
    else:
        import i
    finally:
        import j
    with k:
        for x in y:
            while z:
                if w:
                    import l
                else:
                    import m
    match v:
        case 1:
            import n
x = lambda: __import__("o")
'''


def test_statement_walk_finds_every_import_ast_walk_finds():
    """The import scan visits statements only; on a made-up module with imports in every kind of block and on
    every project file it finds exactly the imports of a full ``ast.walk``."""
    import ast

    def names(nodes):
        return sorted(ast.dump(n) for n in nodes if isinstance(n, (ast.Import, ast.ImportFrom)))

    tree = ast.parse(NESTED)
    found = names(codedeps._statements(tree.body))
    assert found == names(ast.walk(tree)) and len(found) == 10
    for path in sorted(p for pkg in ("pipeline", "stages", "orion_eval", "zipon") for p in (codedeps.ROOT / pkg).rglob("*.py")):
        tree = ast.parse(path.read_bytes())
        assert names(codedeps._statements(tree.body)) == names(ast.walk(tree)), path


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """An empty on-disk import cache in ``tmp_path/cache`` and no in-process memory of parsed files."""
    monkeypatch.setenv("ZIPON_CACHE", str(tmp_path / "cache"))

    def forget():
        monkeypatch.setattr(codedeps, "_IMPORTS", codedeps._ImportCache())
        monkeypatch.setattr(codedeps, "_CLOSURES", {})
        codedeps._parsed_imports.cache_clear()

    forget()
    yield forget
    codedeps._parsed_imports.cache_clear()


def _closure(root, entry="stages.routes"):
    return [p.relative_to(root).as_posix() for p in codedeps.import_closure(entry, root)]


def test_the_import_cache_serves_a_new_process_and_an_edit_is_read_again(checkout, fresh_cache, monkeypatch):
    first = _closure(checkout)
    path = codedeps._ImportCache.path()
    assert path.parent.name == "cache" and len(json.loads(path.read_text())) == len(first)
    fresh_cache()  # a new process: nothing in memory, the file on disk
    parsed = []
    real = codedeps._named_imports
    monkeypatch.setattr(codedeps, "_named_imports", lambda *a: parsed.append(a[2]) or real(*a))
    assert _closure(checkout) == first and parsed == []
    (checkout / "pipeline" / "lazy_dep.py").write_text("VALUE = 1\n")
    stage = checkout / "stages" / "routes.py"
    stage.write_text(stage.read_text() + "\n\ndef _uses_lazy():\n    from pipeline import lazy_dep\n")
    assert _closure(checkout) == sorted([*first, "pipeline/lazy_dep.py"])
    assert parsed == ["stages.routes", "pipeline.lazy_dep"]  # only the edited and the new file were parsed


def test_a_damaged_or_unwritable_cache_changes_nothing(checkout, fresh_cache, monkeypatch, tmp_path):
    expected = _closure(checkout)
    path = codedeps._ImportCache.path()
    path.write_text("{not json")
    fresh_cache()
    assert _closure(checkout) == expected
    assert isinstance(json.loads(path.read_text()), dict)  # rewritten whole
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv("ZIPON_CACHE", str(blocker / "cache"))  # its folder cannot be made
    fresh_cache()
    assert _closure(checkout) == expected and not (blocker / "cache").exists()



def test_the_ingest_stage_runs_every_built_in_reader_loaded_by_name():
    """Built-in readers are loaded from their declarations, not imported by name: their files are still code of
    the ingest stage (editing the TUM reader makes frames stale)."""
    from pipeline import plugins

    files = {p.relative_to(codedeps.ROOT).as_posix() for p in codedeps.import_closure("stages.ingest")}
    modules = {v.split(":")[0] for v in plugins.BUILT_IN_READERS.values()}
    assert {m.replace(".", "/") + ".py" for m in modules} <= files
    assert "pipeline/readers/roslog.py" in files  # and what they import


def test_a_new_feedback_kind_module_is_code_of_the_goals_stage(checkout):
    """The feedback package imports every module of its folder (one per kind): a kind added as its one new file is
    code of the goals stage (and of what reads feedback), though no module names it."""
    kind = checkout / "pipeline" / "goals" / "feedback" / "gesture.py"
    kind.write_text('"""A new kind."""\n')
    files = {p.relative_to(checkout).as_posix() for p in codedeps.import_closure("stages.goals", checkout)}
    assert {"pipeline/goals/feedback/gesture.py", "pipeline/goals/feedback/procedural.py"} <= files
    before = _digests(checkout)
    _edit(kind)
    after = _digests(checkout)
    assert {"goals", "routes"} <= {s for s in STAGES if before[s] != after[s]}
