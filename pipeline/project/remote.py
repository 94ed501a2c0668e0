"""``zipon push`` / ``zipon pull``: a dataset version's artifacts to and from a DVC remote, with DVC's own API.

``pull`` restores the version git has checked out (its ``dvc.lock``) and changes nothing local unless it can restore
all of it: it first asks the remote what it holds, so an unreachable remote is one line naming
the remote and the artifact it was asked about, and a version whose data the remote lacks names every artifact
missing, before anything is fetched or checked out (it asks for the object of each artifact ``dvc.lock`` records:
``dvc status --cloud`` says nothing of a folder whose listing is missing). Only then are the objects fetched into DVC's cache and checked
out into ``data/``, where DVC replaces only files its cache holds (a file with changes no version records is kept,
and the pull fails naming it).
"""

from __future__ import annotations

from contextlib import chdir, contextmanager
from dataclasses import dataclass

from pipeline.config import Params
from pipeline.errors import ZiponError
from pipeline.paths import Workspace
from pipeline.engine.stagegraph import StageSpec, plan


class RemoteError(ZiponError):
    """A DVC remote that cannot be reached, or lacks data of the version asked for."""


@dataclass
class Transfer:
    remote: str
    url: str
    files: int  # objects pushed or fetched
    artifacts: list[str]  # "scene/artifact" of the version


def _artifacts(ws: Workspace, params: Params, stages: dict[str, StageSpec]) -> dict[str, str]:
    """``{path relative to the project: "scene/artifact"}`` of every artifact of the version, in plan order."""
    found = {}
    for scene, stage in plan(stages, params, list(params.scenes)):
        for name in stages[stage].outputs:
            rel = ws.artifact(name, scene).relative_to(ws.root).as_posix()
            found[rel] = f"{scene}/{name}"
    return found


def _open(ws: Workspace):
    from dvc.repo import Repo

    from pipeline import logs
    from pipeline.engine.dvcfile import dvc_lock_target

    logs.tame_driven()
    why = dvc_lock_target(ws)
    if why:
        raise ZiponError(f"cannot push or pull: {why}")
    if not (ws.root / "dvc.lock").is_file():
        raise ZiponError(f"{ws.root / 'dvc.lock'}: missing; this version records no artifacts (build it with "
                         "`zipon run`, or check out a version that has one)")
    try:
        return Repo(str(ws.root))
    except Exception as err:  # noqa: BLE001 - DVC's own errors have no common base worth naming
        raise ZiponError(f"DVC cannot open {ws.root} ({type(err).__name__}: {err})") from None


def _remote(repo, name: str | None) -> tuple[str, str]:
    remotes = repo.config.get("remote", {})
    chosen = name or repo.config.get("core", {}).get("remote")
    if not chosen:
        raise ZiponError("no DVC remote named and no default one: add one with `dvc remote add -d NAME URL` "
                         f"(remotes: {', '.join(remotes) or 'none'})")
    if chosen not in remotes:
        raise ZiponError(f"no DVC remote {chosen!r} in {repo.root_dir} (remotes: {', '.join(remotes) or 'none'})")
    return chosen, str(remotes[chosen].get("url", ""))


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0] if text else ''}".rstrip(": ")


def _recorded(ws: Workspace, artifacts: dict[str, str]) -> list[tuple[str, str, str, str]]:
    """``(scene/artifact, path, object id, hash name)`` of every artifact ``dvc.lock`` records, in plan order."""
    from pipeline.userfiles import parse_yaml, read_user_text

    lock = parse_yaml(read_user_text(ws.root / "dvc.lock"), origin=ws.root / "dvc.lock") or {}
    oids = {}
    for stage in (lock.get("stages") or {}).values():
        for entry in stage.get("outs") or []:
            if isinstance(entry, dict) and entry.get("md5"):
                oids[entry["path"]] = (entry["md5"], entry.get("hash", "md5-dos2unix"))
    return [(label, rel, *oids[rel]) for rel, label in artifacts.items() if rel in oids]


def _locate(repo, ws: Workspace, remote: str, url: str, artifacts: dict[str, str]) -> list[str]:
    """The artifacts whose data neither the remote nor DVC's local cache holds, as ``scene/artifact (path)``. A remote
    that cannot be asked raises :class:`RemoteError` naming it and the artifact asked about."""
    odbs: dict = {}
    nowhere = []
    for label, rel, oid, hash_name in _recorded(ws, artifacts):
        shown = f"{label} ({rel})"
        try:
            if hash_name not in odbs:
                odbs[hash_name] = repo.cloud.get_remote_odb(remote, "pull", hash_name=hash_name)
            odb = odbs[hash_name]
            odb.fs.info(odb.oid_to_path(oid))  # not odb.exists: fsspec's exists() says False when it cannot ask
            on_remote = True
        except FileNotFoundError:
            on_remote = False
        except Exception as err:  # noqa: BLE001 - botocore, OSError, DVC: each a different base
            raise RemoteError(f"remote {remote} ({url}) unreachable while asking for {shown} ({_first_line(err)}); "
                              "nothing local was changed") from None
        cache = repo.cache.local if hash_name == "md5" else repo.cache.legacy
        if not on_remote and not cache.exists(oid):
            nowhere.append(shown)
    return nowhere


@contextmanager
def _on_remote(ws: Workspace, params: Params, stages: dict[str, StageSpec], remote: str | None, lacking: str):
    """The open DVC repo (working directory: the project) and the remote's ``(name, url)``, once every artifact of
    the checked-out version was found on the remote or in DVC's cache; ``lacking`` words the error otherwise."""
    repo = _open(ws)
    with repo, chdir(ws.root):  # DVC resolves stage paths from the working directory
        name, url = _remote(repo, remote)
        missing = _locate(repo, ws, name, url, _artifacts(ws, params, stages))
        if missing:
            raise RemoteError(lacking.format(remote=f"remote {name} ({url})", artifacts=", ".join(missing)))
        yield repo, name, url


def pull(ws: Workspace, params: Params, stages: dict[str, StageSpec], remote: str | None = None) -> Transfer:
    """Restore the checked-out version's artifacts from ``remote`` (default: the project's default remote)."""
    with _on_remote(ws, params, stages, remote, "{remote} lacks the data of this version: {artifacts} (`zipon push` "
                    "them from the clone that built them); nothing local was changed") as (repo, name, url):
        try:
            fetched = repo.fetch(remote=name)
        except Exception as err:  # noqa: BLE001 - as in _locate
            raise RemoteError(f"remote {name} ({url}): fetching the data of this version failed "
                              f"({_first_line(err)}); nothing local was changed") from None
        try:
            repo.checkout()
        except Exception as err:  # noqa: BLE001 - DVC's CheckoutError, ConfirmRemoveError: no common base
            raise ZiponError(f"{ws.data_dir}: restoring the fetched version failed ({_first_line(err)}); "
                             "files with changes no version records were kept") from None
    return Transfer(name, url, int(fetched or 0), sorted(_artifacts(ws, params, stages).values()))


def push(ws: Workspace, params: Params, stages: dict[str, StageSpec], remote: str | None = None,
         all_tags: bool = False) -> Transfer:
    """Send the checked-out version's artifacts (from DVC's cache) to ``remote``; with ``all_tags`` those of every
    git tag too (each one's ``dvc.lock``), whose objects DVC's cache kept when ``zipon run`` recorded them."""
    with _on_remote(ws, params, stages, remote, "cannot push to {remote}: neither DVC's cache here nor the remote "
                    "holds {artifacts} (build them with `zipon run`)") as (repo, name, url):
        try:
            pushed = repo.push(remote=name)
            tags = repo.scm.list_tags() if all_tags else []
            if tags:  # DVC 3.67's push(all_tags=True) to a remote that is not the default one fails after the
                # transfer, updating the workspace's meta: the tags' versions go without the workspace
                pushed += repo.push(remote=name, revs=tags, workspace=False)
        except Exception as err:  # noqa: BLE001 - as in _locate
            raise RemoteError(f"remote {name} ({url}): pushing failed ({_first_line(err)})") from None
    return Transfer(name, url, int(pushed or 0), sorted(_artifacts(ws, params, stages).values()))
