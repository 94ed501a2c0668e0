"""``zipon`` commands of a dataset project (:mod:`pipeline.project`): init, card, diff, push, pull."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape

from zipon.cli.common import G, app, console, out


@app.command("init")
def init_cmd(directory: Path = typer.Argument(..., help="the project folder (new, empty, or a zipon project to complete)")):
    """Make a dataset project: a commented params.yaml, .gitignore, README.md, git and DVC initialised offline
    (analytics and update checks off), dvc.yaml and the stages' code identity files. A folder that is not empty
    and not a zipon project is refused.

    Example: `zipon init ds && cd ds && zipon run && git add -A && git commit -m v1 && git tag v1`
    """
    from pipeline.project.init import init_project
    from stages import STAGES

    result = init_project(directory, STAGES)
    for what in result.initialised:
        out.print(f"initialised {what} in {result.root}", highlight=False, soft_wrap=True)
    for path in result.written:
        out.print(f"wrote {path}", highlight=False, soft_wrap=True)
    if not result.written and not result.initialised:
        out.print(f"{result.root} is already a complete zipon project", highlight=False, soft_wrap=True)
        return
    out.print(f"next: cd {result.root}, list your scenes in params.yaml, then `zipon run` and commit "
              "(README.md says how to version, push and restore)", highlight=False, soft_wrap=True)


@app.command("card")
def card_cmd(check: bool = typer.Option(False, "--check", metavar="", help="only check the card states the current "
                                        "version (exit 1 if not)")):
    """Write the dataset card beside params.yaml: DATASET.md and its machine-readable twin dataset.json (scenes,
    stage versions and artifact digests, params digest, goals and feedback, encoders, licences, zipon's version,
    how to restore and cite). `zipon run` refreshes it.

    Examples: `zipon card` · `zipon card --check`
    """
    from pipeline.project.card import card_staleness, write_card
    from stages import STAGES

    ws, params = G.load()
    if check:
        why = card_staleness(ws, params, STAGES)
        if why:
            console.print(f"[red]dataset card stale[/red]: {escape(str(ws.root))}/{escape(why)}; run `zipon card`",
                          highlight=False, soft_wrap=True)
            raise typer.Exit(1)
        out.print(f"{ws.root / 'dataset.json'} states the current version", highlight=False, soft_wrap=True)
        return
    written = write_card(ws, params, STAGES)
    out.print("\n".join(f"wrote {p}" for p in written) or "the dataset card is current", highlight=False, soft_wrap=True)


@app.command("diff")
def diff_cmd(
    rev_a: str = typer.Argument(..., help="a git revision of the dataset project (tag, branch, commit)"),
    rev_b: str = typer.Argument("HEAD", help="another revision (default HEAD)"),
    as_json: bool = typer.Option(False, "--json", metavar="", help="print the comparison as JSON"),
):
    """Name what changed between two versions of the dataset project, from git alone (nothing is built or
    pulled): params keys, stages rebuilt and why, artifacts whose digests differ, goals added, removed or edited.

    Examples: `zipon diff v1 v2` · `zipon diff v1 --json`
    """
    from pipeline.project.diff import diff_text, diff_versions, json_text

    d = diff_versions(G.workspace(), rev_a, rev_b)
    if as_json:
        out.print(json_text(d), end="", markup=False, highlight=False, soft_wrap=True)
        return
    for line in diff_text(d):
        out.print(line, markup=False, highlight=False, soft_wrap=True)


REMOTE = typer.Option(None, "--remote", "-r", help="DVC remote name (default: the project's default remote)")


@app.command("push")
def push_cmd(remote: Optional[str] = REMOTE,
             all_tags: bool = typer.Option(False, "--all-tags", metavar="", help="also every git tag's version")):
    """Send the artifacts of the checked-out version to a DVC remote (a folder, s3://...). An unreachable remote is
    one line naming the remote and the artifact asked about, exit 1.

    Example: `zipon push --all-tags` (after `dvc remote add -d storage s3://bucket/ds`), then `git push --tags`
    """
    from pipeline.project.remote import push
    from stages import STAGES

    ws, params = G.load()
    done = push(ws, params, STAGES, remote, all_tags)
    out.print(f"remote {done.remote} ({done.url}): {done.files} file(s) pushed; it holds the "
              f"{len(done.artifacts)} artifacts of this version" + (" and of every tag" if all_tags else ""), highlight=False, soft_wrap=True)


@app.command("pull")
def pull_cmd(remote: Optional[str] = REMOTE):
    """Restore the artifacts of the checked-out version (its dvc.lock) from a DVC remote. Nothing local changes
    unless all of it can be restored: a version whose data the remote lacks names the artifacts missing, and an
    unreachable remote names the remote and the artifact, exit 1.

    Example: `zipon pull && zipon verify` (after `git checkout v1`)
    """
    from pipeline.project.remote import pull
    from stages import STAGES

    ws, params = G.load()
    done = pull(ws, params, STAGES, remote)
    out.print(f"remote {done.remote} ({done.url}): {done.files} file(s) fetched; the {len(done.artifacts)} "
              "artifacts of this version are restored (`zipon verify` re-hashes them)", highlight=False, soft_wrap=True)
