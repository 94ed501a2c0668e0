"""The code a stage runs: the import closure of its entry module, found by reading the source.

A stage's code digest (``zipon status``, manifests) and its ``deps`` in ``dvc.yaml`` both come from
:func:`import_closure`: every project module (``pipeline``, ``stages``, ``orion_eval``, ``zipon``)
that the entry module imports, directly or through other project modules, at any depth and from
any scope (an import inside a function counts as much as one at the top), plus the ``__init__.py``
of every package on the way (Python runs them on import). Nothing is imported to compute it, so
``zipon status`` stays fast and a syntax error in a stage is reported, not raised.

Dynamic imports (``importlib.import_module(name)`` with a computed name) are not seen. The project's registries
loaded by name, the built-in readers and encoders (:data:`pipeline.plugins.BUILT_IN_READERS`,
:data:`~pipeline.plugins.BUILT_IN_ENCODERS`), are added from their declarations: code that imports
:mod:`pipeline.readers.base` (or :mod:`pipeline.encoders.choice`, which load them) runs every built-in reader (or
encoder). A package that imports every module of its folder (:data:`EVERY_MODULE`: the feedback kinds) runs them
all.

Parsing every file of the project costs most of a ``zipon status`` (~0.8 s for ~100 files), so the
imports read from a file are kept in a small cache keyed by the file's bytes and module name
(``imports-v1.json`` in ``$ZIPON_CACHE``, else ``$XDG_CACHE_HOME/zipon``, else ``~/.cache/zipon``): an
edited file is a new key, so the cache can only save work, never change a closure. It is skipped
when that folder cannot be written.
"""

from __future__ import annotations

import ast
import contextlib
import hashlib
import json
import os
from functools import lru_cache
from pathlib import Path

from pipeline import __version__, plugins
from pipeline.errors import ZiponError
from pipeline.paths import ENV_CACHE

ROOT = Path(__file__).resolve().parents[2]  # the checkout: pipeline/engine/codedeps.py
PROJECT_PACKAGES = ("pipeline", "stages", "orion_eval", "zipon", "tests")


def module_file(module: str, root: Path = ROOT) -> Path | None:
    """The source file of a project module (``a.b`` -> ``a/b.py`` or ``a/b/__init__.py``), or None."""
    base = root.joinpath(*module.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _is_project(module: str) -> bool:
    return module.split(".", 1)[0] in PROJECT_PACKAGES


def _imports_of(path: Path, module: str, root: Path) -> tuple[str, ...]:
    """Project modules named by every import statement in ``path`` (module ``module``)."""
    st = path.stat()
    return _parsed_imports(path, module, root, (st.st_mtime_ns, st.st_size))


@lru_cache(maxsize=4096)
def _parsed_imports(path: Path, module: str, root: Path, stamp: tuple[int, int]) -> tuple[str, ...]:
    """:func:`_imports_of`, cached while the file's mtime and size stay the same (and across processes by
    content, :class:`_ImportCache`)."""
    source = _read(path, stamp)
    key = hashlib.blake2b(f"{module}\0{path.name}\0".encode() + source, digest_size=16).hexdigest()
    named = _IMPORTS.get(key)
    if named is None:
        named = _named_imports(source, path, module)
        _IMPORTS.put(key, named)
    return tuple(m for m in named if _is_project(m) and module_file(m, root) is not None)


def _named_imports(source: bytes, path: Path, module: str) -> list[str]:
    """Every module an import statement of ``source`` names (absolute, relative ones resolved against ``module``;
    ``from pkg import name`` also names ``pkg.name``, which may be a submodule)."""
    try:
        tree = ast.parse(source, filename=str(path))
    except SyntaxError as err:
        raise ZiponError(f"{path}:{err.lineno}: cannot read the imports of {module}: {err.msg}") from None
    is_pkg = path.name == "__init__.py"
    package = module if is_pkg else module.rpartition(".")[0]
    found: list[str] = []
    for node in _statements(tree.body):
        if isinstance(node, ast.Import):
            found += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base_parts = package.split(".")
                base_parts = base_parts[: len(base_parts) - (node.level - 1)]
                base = ".".join(base_parts + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            found.append(base)
            # `from pkg import name`: name may be a submodule
            found += [f"{base}.{alias.name}" for alias in node.names if alias.name != "*"]
    return [m for m in found if m]


class _ImportCache:
    """``{blake2b(module, file name, bytes): [named imports]}`` kept on disk between processes (see the module
    docstring). Loaded on first use; new entries are written back (atomically) after each closure."""

    VERSION = 1
    MAX_ENTRIES = 4096

    def __init__(self) -> None:
        self._entries: dict[str, list[str]] | None = None
        self._dirty = False

    @staticmethod
    def path() -> Path:
        name = f"imports-v{_ImportCache.VERSION}.json"
        if os.environ.get(ENV_CACHE):  # zipon's own cache folder (pipeline.paths), when the user set one
            return Path(os.environ[ENV_CACHE]) / name
        return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "zipon" / name

    def _load(self) -> dict[str, list[str]]:
        if self._entries is None:
            try:
                data = json.loads(self.path().read_text())
                self._entries = {k: v for k, v in data.items() if isinstance(v, list)} if isinstance(data, dict) else {}
            except (OSError, ValueError):  # no cache yet, or a damaged one: start empty (it only saves work)
                self._entries = {}
        return self._entries

    def get(self, key: str) -> list[str] | None:
        return self._load().get(key)

    def put(self, key: str, named: list[str]) -> None:
        self._load()[key] = named
        self._dirty = True

    def save(self) -> None:
        if not self._dirty:
            return
        entries = self._load()
        keep = dict(list(entries.items())[-self.MAX_ENTRIES:])  # newest last: old versions of files fall out
        path = self.path()
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(keep, separators=(",", ":")))
            os.replace(tmp, path)
            self._dirty = False
        except OSError:  # a read-only home or cache folder: keep working without the cache
            with contextlib.suppress(OSError):  # the temporary file may not exist, nor its folder
                tmp.unlink()


_IMPORTS = _ImportCache()


def _statements(body: list[ast.stmt]):
    """Every statement of ``body`` and of the blocks nested in it (function and class bodies, branches, loops,
    ``try``/``with``/``match`` blocks). Imports are statements, so this finds each one ``ast.walk`` finds, without
    visiting the expressions (about nine nodes in ten)."""
    stack = list(body)
    while stack:
        node = stack.pop()
        yield node
        for name in ("body", "orelse", "finalbody", "handlers", "cases"):
            block = getattr(node, name, None)
            if isinstance(block, list):
                stack.extend(block)


def import_closure(entry: str, root: Path = ROOT) -> list[Path]:
    """Source files of ``entry`` and every project module it imports, transitively (sorted).

    Kept per process while none of those files changes (mtime, size): ``zipon status`` asks once per scene."""
    key = (entry, root)
    hit = _CLOSURES.get(key)
    if hit is not None and hit[0] == _stamps(hit[1]):
        return list(hit[1])
    files = _closure(entry, root)
    _IMPORTS.save()
    _CLOSURES[key] = (_stamps(files), files)
    return list(files)


_CLOSURES: dict[tuple[str, Path], tuple[tuple | None, list[Path]]] = {}
#: modules that load project modules by name from a declaration: {loader: the modules it loads}
LOADED_BY_NAME = {loader: sorted({v.split(":")[0] for v in declared.values()}) for loader, declared in
                  (("pipeline.readers.base", plugins.BUILT_IN_READERS),
                   ("pipeline.encoders.choice", plugins.BUILT_IN_ENCODERS))}
#: packages whose ``__init__`` imports every module of their folder (one module per registered implementation)
EVERY_MODULE = ("pipeline.goals.feedback",)


def _stamps(paths: list[Path]) -> tuple | None:
    try:
        return tuple((st.st_mtime_ns, st.st_size) for st in map(os.stat, paths))
    except OSError:  # a file of the closure is gone: recompute
        return None


def _closure(entry: str, root: Path) -> list[Path]:
    files: dict[str, Path | None] = {}  # module -> its file, looked up once per closure (a closure is one snapshot)

    def file_of(module: str) -> Path | None:
        if module not in files:
            files[module] = module_file(module, root)
        return files[module]

    if file_of(entry) is None:
        raise ZiponError(f"code module {entry!r} not found under {root}")
    seen: set[str] = set()
    todo = [entry]
    while todo:
        mod = todo.pop()
        if mod in seen:
            continue
        seen.add(mod)
        parts = mod.split(".")
        todo += [pkg for pkg in (".".join(parts[:i]) for i in range(1, len(parts))) if pkg not in seen and file_of(pkg)]
        todo += [m for m in _imports_of(file_of(mod), mod, root) if m not in seen]
        todo += [m for m in LOADED_BY_NAME.get(mod, ()) if m not in seen and file_of(m)]
        if mod in EVERY_MODULE:
            todo += [f"{mod}.{p.stem}" for p in sorted(file_of(mod).parent.glob("*.py"))
                     if p.stem != "__init__" and f"{mod}.{p.stem}" not in seen]
    return sorted({file_of(m) for m in seen})


def _source(path: Path) -> bytes:
    """The file's bytes, read once per process while its mtime and size stay the same (``zipon status`` digests
    the same closure files for every scene and stage)."""
    st = path.stat()
    return _read(path, (st.st_mtime_ns, st.st_size))


@lru_cache(maxsize=4096)
def _read(path: Path, stamp: tuple[int, int]) -> bytes:
    return path.read_bytes()


def code_digest(entry: str, root: Path = ROOT) -> str:
    """Digest of the import closure of ``entry`` (file paths and bytes) plus zipon's version.

    Kept per process while no file of the closure changes (mtime, size), as the closure is: ``zipon status`` asks
    once per scene and stage."""
    files = import_closure(entry, root)
    stamps = _stamps(files)
    hit = _DIGESTS.get((entry, root))
    if hit is not None and stamps is not None and hit[0] == stamps:
        return hit[1]
    h = hashlib.blake2b(digest_size=16)
    h.update(__version__.encode())
    for path in files:
        h.update(f"\0{path.relative_to(root).as_posix()}\0".encode())
        h.update(_source(path))
    digest = f"blake2b:{h.hexdigest()}"
    _DIGESTS[(entry, root)] = (stamps, digest)
    return digest


_DIGESTS: dict[tuple[str, Path], tuple[tuple | None, str]] = {}


def changed_files(old: dict[str, str], new: dict[str, str]) -> list[str]:
    """Files added, removed or edited between two ``{path: digest}`` listings (sorted)."""
    return sorted(p for p in set(old) | set(new) if old.get(p) != new.get(p))


def file_digests(entry: str, root: Path = ROOT) -> dict[str, str]:
    """``{relative path: blake2b digest}`` of every file of the closure (recorded in manifests)."""
    return {
        path.relative_to(root).as_posix(): "blake2b:" + hashlib.blake2b(_source(path), digest_size=8).hexdigest()
        for path in import_closure(entry, root)
    }
