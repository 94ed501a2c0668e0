"""A data root on an object store (``--data-dir s3://bucket/prefix``, any fsspec URL): publication, locks, pulls.

Stages read and write local paths (zarr ``LocalStore``, open3d's PLY files), so a run against an object store
works like a DVC remote: each machine builds in a local CACHE that mirrors the root
(:func:`pipeline.paths.cache_dir`; :attr:`pipeline.paths.Workspace.data_dir` is
that cache and ``manifests_dir`` defaults to its ``manifests/``), and the object store holds the published
versions. S3 has no rename, so nothing is ever renamed there; publication of one (scene, stage) is:

1. each output is uploaded under a key of its own content digest, ``<artifact path>@<digest hex>``
   (``artifacts/sim_00/frames.zarr@3f2a.../zarr.json``, ...): a new version never overwrites the published one;
2. the manifest, ``manifests/<scene>/<stage>.json`` (byte-identical to the local one; it records the digests),
   is written LAST, as one PUT: the commit point. Readers trust only what a manifest names, and check the
   content digest of every version they download (:meth:`RemoteRoot.pull_stage`), so an upload cut short is
   never read: before step 2 nothing names it; a rerun uploads it again (same key, same bytes);
3. versions of those outputs the manifest no longer names are deleted.

A kill before step 2 leaves the previous version published (and unreferenced objects, deleted by the next
publication of that stage); after it, the new one. One PUT replaces one whole manifest, so a reader sees the
old or the new set, never a mix.

Locks: ``artifacts/<scene>/.<stage>.lock`` is created with a conditional write (``If-None-Match: *``, s3fs's
``mode="create"``; S3 and moto honour it), so exactly one run builds a (scene, stage); a second fails at once
with :class:`~pipeline.errors.LockedError`, as on a local root. The lock holds its holder's owner record (pid, host,
process start token: :func:`pipeline.engine.locks.holder_record`) and a nonce. The rule is that of local locks
(:mod:`pipeline.engine.locks`): a lock left by a dead process of THIS host (pid gone, or reused by another process: the
start token differs) is reclaimed automatically, the check-delete-create serialised between this host's processes
by a host-local file lock; a lock of ANOTHER host is never broken (its process cannot be probed from here): the error
names the object to delete once that run is known dead. Object stores without conditional writes cannot lock;
zipon refuses to build there (the error says so) rather than risk two writers.

A stage checks, just before step 2, that the manifests of its inputs are still the ones it pulled; a stage
whose input was republished meanwhile is not published (as :func:`pipeline.engine.publication.check_inputs_unchanged`).
``zipon verify`` re-hashes the published versions in place (:meth:`RemoteRoot.digest`: zarr stores through zarr's
``FsspecStore``), then mirrors them like ``zipon status``.
"""

from __future__ import annotations

import hashlib
import tempfile
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from pipeline.errors import ArtifactError, LockedError, MissingInputError, StageError
from pipeline.engine.locks import holder_is_dead, holder_record, parse_holder
from pipeline.engine.manifest import Manifest
from pipeline.paths import ARTIFACTS, LOCK, MANIFEST, Workspace
from pipeline.store import (DIGEST_ALGO, content_digest, hash_stream, hash_zarr_group, new_digest, publish, remove,
                            write_text_atomic)

RECLAIM_WAIT_S = 30.0  # at most this long for another process of this host reclaiming the same lock (a few requests)
CONNECT_TIMEOUT_S = 10.0  # an object store that does not accept a connection in this long is unreachable
READ_TIMEOUT_S = 60.0  # nor one that does not answer a request in this long
MAX_ATTEMPTS = 3  # botocore's tries per request (its own backoff between them)


def reclaim_guard(uri: str) -> Path:
    """The host-local file that serialises reclaiming the lock object ``uri`` between this host's processes (in the
    temp folder, so runs with different mirrors of one data root share it)."""
    folder = Path(tempfile.gettempdir()) / "zipon-locks"
    folder.mkdir(mode=0o1777, exist_ok=True)
    return folder / f"{hashlib.blake2b(uri.encode(), digest_size=8).hexdigest()}.lock"


def version_key(rel: str, digest: str) -> str:
    """The object-store key of one published version of the artifact at ``rel``: ``<rel>@<digest hex>``."""
    return f"{rel}@{digest.split(':', 1)[-1]}"


class RemoteRoot:
    """A data root URL opened through fsspec (``s3://`` needs ``pip install zipon[s3]``; endpoint and credentials
    come from the usual environment: ``AWS_ENDPOINT_URL_S3``, ``AWS_ACCESS_KEY_ID``, ...)."""

    def __init__(self, url: str):
        import fsspec

        self.url = url.rstrip("/")
        options = {}
        if self.url.startswith(("s3://", "s3a://")):  # every request bounded in time (botocore's defaults: 60 s, 5 tries)
            options["config_kwargs"] = {"connect_timeout": CONNECT_TIMEOUT_S, "read_timeout": READ_TIMEOUT_S,
                                        "retries": {"max_attempts": MAX_ATTEMPTS}}
        try:
            self.fs, self.root = fsspec.core.url_to_fs(self.url, **options)
        except (ImportError, ValueError) as err:
            raise MissingInputError(f"data root {self.url}: cannot open it with fsspec ({err}); for s3:// install "
                                    "zipon's s3 extra: pip install 'zipon[s3]'") from None
        self.root = self.root.rstrip("/")
        if options and hasattr(self.fs, "retries"):
            self.fs.retries = 1  # s3fs's own retry loop on top of botocore's would multiply each wait by 5

    def check(self) -> None:
        """Reach the store once, at start: a missing or refused credential, an unknown bucket or an endpoint that
        does not answer is one :class:`~pipeline.errors.ConfigError` naming the URL, not a traceback from deep in
        the first stage."""
        from pipeline.errors import ConfigError

        try:
            self.fs.ls(self.root.split("/", 1)[0], detail=False, refresh=True)
        except FileNotFoundError:
            raise ConfigError(f"--data-dir {self.url}: bucket {self.root.split('/', 1)[0]!r} does not exist (create "
                              "it, or check the URL and the endpoint AWS_ENDPOINT_URL_S3)") from None
        except Exception as err:  # noqa: BLE001 - botocore's and aiohttp's errors have no common base worth naming
            kind = type(err).__name__
            hint = ("set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY (or AWS_PROFILE)" if "Credentials" in kind
                    else "check the credentials' rights on it" if isinstance(err, PermissionError) else
                    f"check the endpoint (AWS_ENDPOINT_URL_S3) and the network; each request waits at most "
                    f"{CONNECT_TIMEOUT_S:g} s to connect and {READ_TIMEOUT_S:g} s for an answer")
            first = str(err).splitlines()[0][:200] if str(err) else ""
            raise ConfigError(f"--data-dir {self.url}: cannot reach the object store ({kind}: {first}); "
                              f"{hint}") from None

    def key(self, rel: str) -> str:
        return f"{self.root}/{rel}"

    def uri(self, rel: str) -> str:
        return f"{self.url}/{rel}"

    def read_text(self, rel: str) -> str | None:
        """The object ``rel`` as text, or ``None`` when it does not exist."""
        try:
            return self.fs.cat_file(self.key(rel)).decode("utf-8")
        except FileNotFoundError:
            return None

    def scenes(self) -> list[str]:
        """The scenes with at least one published manifest (``manifests/<scene>/``), sorted."""
        try:
            entries = self.fs.ls(self.key("manifests"), detail=False, refresh=True)
        except FileNotFoundError:
            return []
        return sorted(e.rstrip("/").rsplit("/", 1)[-1] for e in entries)

    def write_text(self, rel: str, text: str) -> None:
        """One PUT: the object is replaced whole or not at all."""
        self.fs.pipe_file(self.key(rel), text.encode("utf-8"))

    # ------------------------------------------------------------------ locks

    @contextmanager
    def lock(self, rel: str, what: str) -> Iterator[None]:
        """Hold the lock object ``rel`` for the body (fail fast); ``what`` names the outputs in errors.

        A lock left by a dead process of this host is reclaimed (:func:`pipeline.engine.locks.holder_is_dead`, the rule of
        local locks); any other holder makes this raise :class:`LockedError` naming it and the object."""
        body = holder_record() + f"{uuid.uuid4().hex}\n"  # the owner record, then a nonce: release deletes only ours
        if not self._create(rel, body, what):
            text = self.read_text(rel)  # None: released (or being reclaimed) since the create: try again below
            if text is not None and not holder_is_dead(parse_holder(text)):
                raise self._locked(rel, what, text)
            self._reclaim(rel, body, what)
        try:
            yield
        finally:
            if (self.read_text(rel) or "") == body:
                self.fs.rm_file(self.key(rel))

    def _create(self, rel: str, body: str, what: str) -> bool:
        """Create the lock object ``rel`` holding ``body`` unless it exists (one conditional PUT); whether it did."""
        try:
            self.fs.pipe_file(self.key(rel), body.encode(), mode="create")
        except FileExistsError:
            return False
        except (NotImplementedError, TypeError) as err:
            raise StageError(f"data root {self.url}: this filesystem offers no conditional (create-only) write, so "
                             f"zipon cannot lock {what} there ({err}); build on a local or S3 data root") from None
        return True

    def _reclaim(self, rel: str, body: str, what: str) -> None:
        """Replace the lock ``rel`` of a dead process of this host (or none: it went meanwhile) with ours.

        Two processes of this host that found the same dead holder take turns through a host-local file lock on this
        key (:func:`reclaim_guard`): the first deletes and creates; the second then reads the first's live record and
        fails. Other hosts never delete a lock of this host, so nothing else races the delete."""
        from filelock import FileLock, Timeout

        try:
            with FileLock(str(reclaim_guard(self.uri(rel))), timeout=RECLAIM_WAIT_S, mode=0o666):
                text = self.read_text(rel)  # again: another process of this host may have reclaimed it meanwhile
                if text is not None:
                    if not holder_is_dead(parse_holder(text)):
                        raise self._locked(rel, what, text)
                    self.fs.rm_file(self.key(rel))
                if not self._create(rel, body, what):
                    raise self._locked(rel, what, self.read_text(rel))
        except Timeout:
            raise self._locked(rel, what, self.read_text(rel)) from None

    def _locked(self, rel: str, what: str, text: str | None) -> LockedError:
        holder = parse_holder(text)
        who = f"pid {holder[0]} on host {holder[1]}" if holder else "a run that did not record itself"
        return LockedError(f"{what} is being built by another zipon run: {who} holds {self.uri(rel)}. Wait for that "
                           f"run to finish; if it is gone, delete {self.uri(rel)} and run again")

    # ------------------------------------------------------------------ artifacts

    def push(self, local: Path, rel: str, digest: str) -> None:
        """Upload the finished artifact ``local`` (a zarr folder or a file) as version ``digest`` of ``rel``."""
        key = self.key(version_key(rel, digest))
        if Path(local).is_dir():
            # trailing slashes: the folder's CONTENT goes to the key even when a cut-short upload of this same
            # version left objects there (without them fsspec would nest a copy inside); same keys, same bytes
            self.fs.put(f"{local}/", f"{key}/", recursive=True)
        else:
            self.fs.put_file(str(local), key)

    def pull(self, rel: str, digest: str, dest: Path, already_there: Callable[[], bool] = lambda: False) -> None:
        """Download version ``digest`` of ``rel`` into ``dest`` (replacing it), after checking its content digest.

        ``already_there()`` is asked again once the download is done: when another worker of this machine mirrored
        the same version meanwhile (and may be reading it), the download is dropped instead of replacing it.
        Raises :class:`StageError` when the version is gone or differs (republished or damaged meanwhile).
        """
        dest = Path(dest)
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp = dest.with_name(f".{dest.name}.tmp-{uuid.uuid4().hex[:8]}")
        key = self.key(version_key(rel, digest))
        try:
            if self.fs.isdir(key):
                self.fs.get(key + "/", str(tmp) + "/", recursive=True)
            else:
                self.fs.get_file(key, str(tmp))
            got = content_digest(tmp)
            if got != digest:
                raise StageError(f"{self.uri(version_key(rel, digest))}: content digest {got}, its manifest says "
                                 f"{digest} (changed or damaged); run `zipon run` again, or `zipon verify`")
            if not already_there():
                publish(tmp, dest)
        except FileNotFoundError:
            raise StageError(f"{self.uri(version_key(rel, digest))}: named by its manifest but gone (republished "
                             "meanwhile?); run again") from None
        finally:
            remove(tmp)

    def digest(self, rel: str, digest: str) -> str:
        """The content digest of the published version ``digest`` of ``rel``, read in place (a zarr store through
        zarr's ``FsspecStore``, decoded as :func:`pipeline.store.content_digest` does; a file as bytes)."""
        import zarr

        rel = version_key(rel, digest)
        h = new_digest()
        if self.fs.exists(self.key(f"{rel}/zarr.json")):
            store = zarr.storage.FsspecStore.from_url(self.uri(rel), read_only=True)
            hash_zarr_group(zarr.open_group(store, mode="r"), h)
        else:
            with self.fs.open(self.key(rel), "rb") as f:
                hash_stream(f, h)
        return f"{DIGEST_ALGO}:{h.hexdigest()}"

    def prune(self, rel: str, keep: str) -> None:
        """Delete the versions of ``rel`` other than ``keep`` (a digest)."""
        parent, name = rel.rsplit("/", 1)
        try:
            entries = self.fs.ls(self.key(parent), detail=False, refresh=True)
        except FileNotFoundError:
            return
        for entry in entries:
            base = entry.rstrip("/").rsplit("/", 1)[-1]
            if base.startswith(f"{name}@") and base != version_key(name, keep):
                self.fs.rm(entry, recursive=True)

    # ------------------------------------------------------------------ stages

    def pull_stage(self, ws: Workspace, scene: str, stage: str, outputs: tuple[str, ...] | None = None) -> str | None:
        """Mirror the published version of (scene, stage) into the local cache: its ``outputs`` (default: every one
        its manifest names; downloaded only when the local copy is not that version) and then its manifest. Returns
        the manifest's text (``None``: the stage was never published, and the local manifest is removed so the cache
        cannot claim it was)."""
        text = self.read_text(MANIFEST_KEY.format(scene=scene, stage=stage))
        local = ws.manifest(scene, stage)
        if text is None:
            remove(local)
            return None
        try:
            man = Manifest.model_validate_json(text)
        except ValueError as err:
            raise ArtifactError(f"{self.uri(MANIFEST_KEY.format(scene=scene, stage=stage))}: not a valid zipon "
                                f"manifest ({str(err).splitlines()[0]})") from None
        def mirrored(name: str, digest: str) -> bool:  # the local copy is that version (its manifest says so)
            have = Manifest.read(local)
            return (have is not None and name in have.outputs and have.outputs[name].digest == digest
                    and ws.artifact(name, scene).exists())

        for name in man.outputs if outputs is None else outputs:
            rec = man.outputs.get(name)
            if rec is not None and not mirrored(name, rec.digest):
                self.pull(ARTIFACTS[name].format(scene=scene), rec.digest, ws.artifact(name, scene),
                          lambda name=name, digest=rec.digest: mirrored(name, digest))
        if not local.is_file() or local.read_text(encoding="utf-8") != text:
            write_text_atomic(local, text)
        return text

    def publish_stage(self, ws: Workspace, scene: str, stage: str, outputs: tuple[str, ...]) -> None:
        """Publish the local cache's (scene, stage) (just built there): outputs first, the manifest last (the
        commit point), then delete the versions it no longer names."""
        man = Manifest.read(ws.manifest(scene, stage))
        if man is None:
            raise StageError(f"scene {scene} stage {stage}: no local manifest to publish ({ws.manifest(scene, stage)})")
        for name in outputs:
            self.push(ws.artifact(name, scene), ARTIFACTS[name].format(scene=scene), man.outputs[name].digest)
        self.write_text(MANIFEST_KEY.format(scene=scene, stage=stage), man.text())
        for name in outputs:
            self.prune(ARTIFACTS[name].format(scene=scene), man.outputs[name].digest)


MANIFEST_KEY = "manifests/" + MANIFEST


@contextmanager
def remote_stage(ws: Workspace, scene: str, stage: str, outputs: dict[str, tuple[str, ...]],
                 upstream: list[str]) -> Iterator[Callable[[], None]]:
    """Hold the object-store lock of (scene, stage), mirror it and its ``upstream`` stages into the local cache,
    and yield ``publish()``, which publishes the stage after checking its inputs were not republished meanwhile.

    ``outputs``: stage -> its output artifact names, for ``stage`` and every upstream stage.
    """
    remote = RemoteRoot(ws.remote)
    with remote.lock(LOCK.format(scene=scene, stage=stage), f"scene {scene} stage {stage}"):
        pulled = {up: remote.pull_stage(ws, scene, up, outputs[up]) for up in upstream}
        remote.pull_stage(ws, scene, stage, outputs[stage])

        def publish_now() -> None:
            for up, text in pulled.items():
                if remote.read_text(MANIFEST_KEY.format(scene=scene, stage=up)) != text:
                    raise StageError(f"scene {scene}: input stage {up} was republished on {remote.url} while stage "
                                     f"{stage} ran; its outputs are not published. Run again")
            remote.publish_stage(ws, scene, stage, outputs[stage])

        yield publish_now


def pull_all(ws: Workspace, pairs: list[tuple[str, str]], *, verify: bool = False) -> None:
    """Mirror every published (scene, stage) of ``pairs`` into the local cache (``zipon status`` and ``zipon verify``
    then read the mirror; every downloaded version's digest is checked on the way).

    ``verify``: first re-hash every published version IN PLACE (:meth:`RemoteRoot.digest`) against its manifest;
    raises :class:`ArtifactError` listing each one that differs or cannot be read.
    """
    remote = RemoteRoot(ws.remote)
    if verify:
        bad = []
        for scene, stage in pairs:
            text = remote.read_text(MANIFEST_KEY.format(scene=scene, stage=stage))
            if text is None:
                continue
            for name, rec in Manifest.model_validate_json(text).outputs.items():
                where = remote.uri(version_key(ARTIFACTS[name].format(scene=scene), rec.digest))
                try:
                    got = remote.digest(ARTIFACTS[name].format(scene=scene), rec.digest)
                except Exception as err:  # noqa: BLE001 - any read failure is the finding: the version is damaged
                    bad.append(f"{where}: unreadable ({type(err).__name__}: {str(err).splitlines()[0][:120]})")
                    continue
                if got != rec.digest:
                    bad.append(f"{where}: digest {got} != manifest {rec.digest}")
        if bad:
            raise ArtifactError(f"{len(bad)} published artifact(s) on {remote.url} do not match their manifests: "
                                + "; ".join(bad) + ". Rebuild them with zipon run --force")
    pull_stages(ws, pairs)


def pull_stages(ws: Workspace, pairs: list[tuple[str, str]]) -> None:
    """Mirror the published version of each (scene, stage) of ``pairs`` into the local cache, for a command that
    reads it there (``zipon query``, :func:`zipon.open`, ...): only versions not mirrored yet are downloaded, each
    digest-checked; a stage never published stays absent, so the reader reports it as not built."""
    remote = RemoteRoot(ws.remote)
    for scene, stage in pairs:
        remote.pull_stage(ws, scene, stage)
