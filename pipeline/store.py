"""Artifact stores: zarr v3 helpers, deterministic content digests, temporary folders, atomic writes.

A stage never writes where readers look. It writes in a folder of ``artifacts/<scene>/.tmp/`` made
by :func:`new_tmp_dir` (named after its owner: label, host, pid), and the runner publishes the
finished outputs with their manifest as one set (:mod:`pipeline.engine.publication`), so a crash leaves
one whole version and nothing half-written that looks finished. :func:`sweep_tmp` removes the
folders of dead processes of this host only.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, TypeVar

import blake3
import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError

from pipeline import __version__
from pipeline.stageconfig import canonical_json
from pipeline.errors import ArtifactError, MissingInputError
from pipeline.geometry import GridSpec

if TYPE_CHECKING:  # zarr is imported where a store is opened or written: `zipon status` reads none (~0.4 s)
    import zarr
    from zarr.codecs import BloscCodec

# Content digests (artifacts, raw logs) are BLAKE3: a cryptographic hash at ~3 GB/s on one core, 4x blake2b's
# 0.7 GB/s, which matters for a scene's 3 GB of decoded frames. A zarr store's digest hashes each array's decoded
# content on its own (:func:`array_digest`), so a writer that streams an array's rows digests them as it writes
# (:class:`ArrayDigests`) instead of reading the store back. Digests of older zipons read "blake2b:...".
DIGEST_ALGO = "blake3"
Hasher = blake3.blake3
KnownDigests = Mapping[str, tuple[tuple[int, ...], bytes]]  # array name -> (shape, digest): ArrayDigests.known


# ----------------------------------------------------------------------------- zarr

def compressor(level: int = 3, *, shuffle: str = "shuffle") -> BloscCodec:
    """Blosc-zstd; ``shuffle`` ('shuffle', 'bitshuffle', 'noshuffle') suits the dtype."""
    from zarr.codecs import BloscCodec

    return BloscCodec(cname="zstd", clevel=level, shuffle=shuffle)


def new_group(path: Path, attrs: dict[str, Any]) -> zarr.Group:
    """Create an empty zarr v3 group at ``path`` (which must not exist) with ``attrs``."""
    import zarr

    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path}: refusing to overwrite; stages write to fresh temporary paths")
    group = zarr.open_group(zarr.storage.LocalStore(str(path)), mode="w-", zarr_format=3)
    group.attrs.update(_plain(attrs))
    return group


def open_group(path: Path, *, artifact: str, format_version: int | None = None) -> zarr.Group:
    """Open an artifact read-only, checking it is the named artifact and a readable format version."""
    import zarr

    path = Path(path)
    if not (path / "zarr.json").is_file():
        raise MissingInputError(f"{path}: artifact {artifact!r} not found (run its stage first: zipon run)")
    group = zarr.open_group(zarr.storage.LocalStore(str(path), read_only=True), mode="r")
    got = group.attrs.get("artifact")
    if got != artifact:
        raise ArtifactError(f"{path}: attrs.artifact is {got!r}, expected {artifact!r}")
    if format_version is not None and group.attrs.get("format_version") != format_version:
        raise ArtifactError(
            f"{path}: format_version {group.attrs.get('format_version')!r}, this zipon reads {format_version}; "
            f"rebuild it with: zipon run --force"
        )
    return group


def artifact_attrs(artifact: str, format_version: int, stage: str, params_digest: str, **extra: Any) -> dict:
    """The self-description every artifact carries (STYLE rule 4)."""
    return {
        "artifact": artifact,
        "format_version": format_version,
        "stage": stage,
        "params_digest": params_digest,
        "code_version": __version__,
        **extra,
    }


# ----------------------------------------------------------------------------- typed attrs

_Attrs = TypeVar("_Attrs", bound="ArtifactAttrs")


class AttrsModel(BaseModel):
    """A typed part of an artifact's attrs. Keys the model does not name are kept as they are (summary
    figures a stage adds), so reading and writing through the model leaves the stored JSON unchanged."""

    model_config = ConfigDict(extra="allow", frozen=True)


class GridAttrs(AttrsModel):
    """``attrs.grid``: :meth:`GridSpec.to_attrs` (rows, cols, cell size, north-west corner, orientation)."""

    rows: int
    cols: int
    cell_size_m: float
    origin_xy: tuple[float, float]
    orientation: str = GridSpec.ORIENTATION

    @property
    def spec(self) -> GridSpec:
        return GridSpec(self.rows, self.cols, self.cell_size_m, self.origin_xy)


class ArtifactAttrs(AttrsModel):
    """The self-description every artifact carries (STYLE rule 4); each store module subclasses it with the
    attrs of its own artifact, and reads its attrs with :meth:`read`, never by string key."""

    artifact: str
    format_version: int
    stage: str
    params_digest: str
    code_version: str

    @classmethod
    def read(cls: type[_Attrs], attrs: Mapping[str, Any], path: Path | str) -> _Attrs:
        """The attrs of the artifact at ``path`` as this model; an ArtifactError names the field that does not fit."""
        try:
            return cls.model_validate(dict(attrs))
        except ValidationError as err:
            raise _attrs_error(err, path) from None

    @classmethod
    def checked(cls, attrs: Mapping[str, Any], path: Path | str) -> dict:
        """``attrs`` unchanged (same keys, same order, so the same bytes) after checking they read back as this
        model: a writer can never store attrs its reader refuses."""
        cls.read(_plain(dict(attrs)), path)
        return dict(attrs)


def _attrs_error(err: ValidationError, path: Path | str) -> ArtifactError:
    first = err.errors()[0]
    where = ".".join(str(p) for p in first["loc"]) or "(root)"
    return ArtifactError(f"{path}: attrs.{where}: {first['msg']} (got {str(first.get('input'))[:80]}); "
                         f"rebuild it with: zipon run --force")


def _plain(value: Any) -> Any:
    """Attrs as JSON-safe plain data (numpy scalars/arrays -> Python)."""
    return json.loads(json.dumps(value, default=_json_default))


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return obj.as_posix()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


# ----------------------------------------------------------------------------- digests

def _hash_zarr(path: Path, h: Hasher, known: KnownDigests | None = None) -> None:
    """Hash decoded content (not compressed bytes) so the digest is codec-version independent."""
    import zarr

    hash_zarr_group(zarr.open_group(zarr.storage.LocalStore(str(path), read_only=True), mode="r"), h, known)


def hash_zarr_group(root: zarr.Group, h: Hasher, known: KnownDigests | None = None) -> None:
    """:func:`content_digest`'s hashing of an open zarr store, on any store (an object store's too): every node in
    name order, its attrs, and for an array its dtype, shape, fill value and :func:`array_digest`.

    ``known``: array name -> (shape, digest) of arrays whose digest their writer kept while writing
    (:class:`ArrayDigests`); used when the array still has that shape, so the store is not read back."""
    import zarr

    nodes = [("", root)] + sorted(root.members(max_depth=None), key=lambda kv: kv[0])
    for name, node in nodes:
        h.update(f"\0node:{name}\0".encode())
        h.update(canonical_json(dict(node.attrs)).encode())
        if isinstance(node, zarr.Array):
            h.update(f"{node.dtype.str}{node.shape}{node.fill_value!r}".encode())
            shape, digest = (known or {}).get(name, (None, None))
            h.update(digest if shape == tuple(node.shape) else array_digest(node))


def array_digest(node: zarr.Array) -> bytes:
    """The digest of an array's decoded content, C order, read one chunk row at a time (bounded memory)."""
    h = new_digest()
    if node.ndim == 0:
        update_array(h, node[...])
        return h.digest()
    block = node.chunks[0]
    for start in range(0, node.shape[0], block):
        update_array(h, node[start : start + block])
    return h.digest()


def update_array(h: Hasher, values: np.ndarray) -> None:
    """Feed ``values``' bytes (C order, their own dtype and byte order) to ``h`` without a copy when contiguous."""
    h.update(np.ascontiguousarray(values).reshape(-1).view(np.uint8))


class ArrayDigests:
    """:func:`array_digest` of arrays kept while their rows are written, in order, by one writer.

    ``update(name, rows)`` after writing ``rows`` (the decoded values, in the array's dtype) at the end of array
    ``name``; :meth:`known` is what :func:`content_digest` takes as ``known``. The writer must be the only one
    writing those arrays: a later write of the same shape would not be seen (a changed shape is)."""

    def __init__(self) -> None:
        self._hashes: dict[str, Hasher] = {}
        self._rows: dict[str, tuple[int, ...]] = {}

    def update(self, name: str, rows: np.ndarray) -> None:
        if name not in self._hashes:
            self._hashes[name] = new_digest()
        update_array(self._hashes[name], rows)
        self._rows[name] = (self._rows.get(name, (0,))[0] + len(rows), *rows.shape[1:])

    def known(self) -> KnownDigests:
        return {name: (self._rows[name], h.digest()) for name, h in self._hashes.items()}


def _hash_file(path: Path, h: Hasher) -> None:
    with open(path, "rb") as f:
        hash_stream(f, h)


def hash_stream(f, h: Hasher) -> None:
    """:func:`content_digest`'s hashing of one file's bytes, from any binary file object (an object store's too)."""
    for chunk in iter(lambda: f.read(1 << 22), b""):
        h.update(chunk)


def new_digest() -> Hasher:
    """The hash :func:`content_digest` fills; its result reads ``f"{DIGEST_ALGO}:{h.hexdigest()}"``."""
    return blake3.blake3()


def content_digest(path: Path, known: KnownDigests | None = None) -> str:
    """Deterministic digest of an artifact: a zarr store (decoded; ``known``: :meth:`ArrayDigests.known` of its
    writer, see :func:`hash_zarr_group`), a folder, or a file."""
    path = Path(path)
    if not path.exists():
        raise MissingInputError(f"{path}: cannot digest a missing artifact")
    h = new_digest()
    if (path / "zarr.json").is_file():
        _hash_zarr(path, h, known)
    elif path.is_dir():
        for file in sorted(p for p in path.rglob("*") if p.is_file()):
            h.update(f"\0file:{file.relative_to(path).as_posix()}\0".encode())
            _hash_file(file, h)
    else:
        _hash_file(path, h)
    return f"{DIGEST_ALGO}:{h.hexdigest()}"


def files_digest(paths: list[Path]) -> str:
    """Digest of raw inputs (a log file, or every file of a dataset folder or code package; Python's
    ``__pycache__`` folders, rewritten whenever code is imported, are left out)."""
    h = new_digest()
    for p in paths:
        p = Path(p)
        files = (sorted(q for q in p.rglob("*") if q.is_file() and "__pycache__" not in q.parts) if p.is_dir()
                 else [p])
        for file in files:
            h.update(f"\0file:{file.name}\0".encode())
            _hash_file(file, h)
    return f"{DIGEST_ALGO}:{h.hexdigest()}"


# ----------------------------------------------------------------------------- atomic writes

def new_tmp_dir(base: Path, label: str) -> Path:
    """A fresh private folder ``<label>@<host>-<pid>-<token>`` under ``base`` for outputs in progress.

    The name records its owner, so :func:`sweep_tmp` on any machine of a cluster removes only
    folders of dead processes on its own host.
    """
    path = Path(base) / f"{label}@{socket.gethostname()}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    path.mkdir(parents=True)
    return path


def tmp_owner(path: Path) -> tuple[str, str, int] | None:
    """``(label, host, pid)`` of a folder made by :func:`new_tmp_dir`, or ``None`` for any other name."""
    head, sep, tail = Path(path).name.rpartition("@")
    parts = tail.rsplit("-", 2)
    if not sep or len(parts) != 3 or not parts[1].isdigit():
        return None
    return head, parts[0], int(parts[1])


def sweep_tmp(base: Path, label: str | None = None) -> list[Path]:
    """Remove leftovers of killed runs: folders of ``base`` (of ``label`` only, when given) whose
    owner was a process of this host that is gone. Another host's folders are never touched, since
    its processes cannot be probed from here; nor are names :func:`new_tmp_dir` did not make.
    """
    removed = []
    base = Path(base)
    if not base.is_dir():
        return removed
    host = socket.gethostname()
    for path in sorted(base.iterdir()):
        owner = tmp_owner(path)
        if owner is None or owner[1] != host or (label is not None and owner[0] != label):
            continue
        if not _pid_alive(owner[2]):
            remove(path)
            removed.append(path)
    return removed


def _pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists on this host (one we may not signal counts as alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def publish(tmp_path: Path, final_path: Path) -> None:
    """Move ONE finished file or folder into place, replacing any previous version.

    The old version is first renamed aside (same filesystem, atomic), then the new one is
    renamed in, then the old one is deleted: readers see the old or the new, never a mix.
    A stage's outputs are published as one set by :mod:`pipeline.engine.publication` instead.
    """
    tmp_path, final_path = Path(tmp_path), Path(final_path)
    final_path.parent.mkdir(parents=True, exist_ok=True)
    trash = None
    if final_path.exists() or final_path.is_symlink():
        trash = final_path.with_name(f".{final_path.name}.old-{uuid.uuid4().hex[:8]}")
        os.replace(final_path, trash)
    os.replace(tmp_path, final_path)
    if trash is not None:
        remove(trash)


def remove(path: Path) -> None:
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists() or path.is_symlink():
        path.unlink()


def fsync_dir(path: Path) -> None:
    """Make the entries of folder ``path`` (creations, renames) durable; a no-op where folders
    cannot be opened (Windows)."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # some filesystems refuse fsync on folders; renames there are as durable as they get
        pass
    finally:
        os.close(fd)


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``path`` whole or not at all (temporary file, fsync, rename, fsync of the folder)."""
    path = Path(path)
    if not path.parent.is_dir():
        path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{uuid.uuid4().hex[:8]}")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        remove(tmp)
        if err.filename is None or err.filename == str(tmp):  # write()/fsync() errors carry no path, and the
            raise OSError(err.errno, err.strerror, str(path)) from err  # temporary file is ours: name the file
        raise
    except BaseException:
        remove(tmp)
        raise
    fsync_dir(path.parent)
