"""Locks on a (scene, stage) output set, so two runs on one data root never build the same outputs.

Granularity: one lock per (scene, stage), at ``artifacts/<scene>/.<stage>.lock`` (see
:mod:`pipeline.paths`). Runs on different scenes or stages (``zipon run -s a`` beside
``zipon run -s b``, or every worker of a dask cluster) proceed in parallel, as snakemake's
per-output locks allow; a data-root lock (DVC's repo lock) would serialise them for no gain.
A stage that *reads* an output another run republishes meanwhile is caught before it publishes
(:func:`pipeline.engine.publication.check_inputs_unchanged`).

Contention fails fast, as ``dvc repro`` ("Unable to acquire lock") and snakemake ("Directory
cannot be locked") do: a second run that would rebuild the same outputs stops at once with
:class:`~pipeline.errors.LockedError` naming the holder's pid and host, and the CLI exits 1.

The lock is filelock's :class:`~filelock.SoftFileLock`: a marker file created exclusively, holding
the owner's pid, host and process start token; it needs no ``fcntl`` support from the filesystem
(NFS and other shared filesystems work). A marker left by a dead process of *this* host is
reclaimed automatically (the pid is probed and the start token guards against pid reuse); a
marker of *another* host is never broken, because its process cannot be probed from here: the
error says which host holds it and which file to delete once that host's run is known dead.
Machines that share one host name but not one process table (containers with host networking)
must not share a data root: each would take the other's live pids for dead ones.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from filelock import SoftFileLock, Timeout
# filelock's owner identity (host name with its pid namespace, process start token, the staleness probe): the
# records and the rule its SoftFileLock uses, shared by the object-store locks (pipeline.engine.fsroot). Not a public
# module: filelock is pinned exactly in pyproject.toml for it (tests/pipeline/engine/test_locks.py covers the probe).
from filelock._identity import host_name, owner_is_stale, process_start_token

from pipeline.errors import LockedError


def holder_record() -> str:
    """This process's owner record as filelock's marker writes it: ``<pid>\\n<host>\\n<start token>\\n`` (the start
    token is empty where the platform offers none). :mod:`pipeline.engine.fsroot` writes the same record into its lock
    objects, so one rule (:func:`holder_is_dead`) judges both kinds of lock."""
    token = process_start_token(os.getpid())
    return f"{os.getpid()}\n{host_name()}\n{'' if token is None else token}\n"


def parse_holder(text: str | None) -> tuple[int, str, int | None] | None:
    """``(pid, host, start token or None)`` from an owner record (lines beyond the third are ignored), or ``None``
    when the text records no owner."""
    lines = (text or "").splitlines()
    if len(lines) < 2 or not lines[0].isdigit() or not lines[1]:
        return None
    token = int(lines[2]) if len(lines) > 2 and lines[2].isdigit() else None
    return int(lines[0]), lines[1], token


def holder_is_dead(holder: tuple[int, str, int | None] | None) -> bool:
    """Whether the owner ``(pid, host, start token)`` is a process of THIS host that is gone: its pid is not alive,
    or now names another process (a different start token). Another host's owner, or a record naming no owner
    (``None``), is never judged dead: neither can be probed from here. filelock's own probe, the one its soft locks
    reclaim by."""
    return holder is not None and owner_is_stale(*holder)


def lock_holder(path: Path) -> tuple[int, str] | None:
    """``(pid, host)`` recorded in the lock marker at ``path``, or ``None`` (no marker, or unreadable).

    filelock's marker is ``<pid>\\n<host>\\n[<start token>\\n]``.
    """
    try:
        holder = parse_holder(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError):
        return None
    return None if holder is None else holder[:2]


@contextmanager
def output_lock(path: Path, what: str) -> Iterator[None]:
    """Hold the lock at ``path`` (fail fast) for the body; ``what`` names the outputs in errors.

    Raises :class:`LockedError` ``"<what> is being built by another zipon run: pid P on host H ..."``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = SoftFileLock(str(path), timeout=0)
    try:
        lock.acquire()
    except Timeout as err:
        holder = lock_holder(path)
        who = f"pid {holder[0]} on host {holder[1]}" if holder else "a process that did not record itself"
        raise LockedError(
            f"{what} is being built by another zipon run: {who} holds {path}. Wait for that run to finish; "
            f"if it is gone (e.g. its host crashed), delete {path} and run again"
        ) from err
    try:
        yield
    finally:
        lock.release()
