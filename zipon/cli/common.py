"""What every ``zipon`` command shares: the app, the global options (:data:`G`), the consoles, and the helpers
that run the stage plan and print its outcomes and evaluation results. The commands live in
:mod:`zipon.cli.build`, :mod:`zipon.cli.inspect` and :mod:`zipon.cli.maps`; :mod:`zipon.cli` imports them and turns errors into
messages and exit codes."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

app = typer.Typer(
    add_completion=True,
    no_args_is_help=True,
    pretty_exceptions_show_locals=False,
    rich_markup_mode="markdown",
    help="**zipon** — raw RGB-D robot logs → versioned ZIPON datasets (scenes, semantic maps, goals, routes) "
    "and the orion_eval evaluator.\n\nStart with `zipon demo`; `zipon COMMAND --help` shows examples.",
)
console = Console(stderr=True)
out = Console(soft_wrap=True)  # stdout: what a command prints (paths, JSON) is never broken across lines


@dataclass
class Globals:
    params: Optional[Path] = None
    data_dir: Optional[str] = None  # a folder or an object-store URL (s3://bucket/prefix): kept a string
    manifests_dir: Optional[Path] = None
    overrides: tuple[str, ...] = ()
    quiet: bool = False
    command: str = ""  # the command being run, as typed: "status", "goals export" (set by the groups' callbacks)

    def workspace(self):
        from pipeline.paths import Workspace

        return Workspace.resolve(self.params, self.data_dir, self.manifests_dir)

    def load(self):
        from pipeline.paramsfile import load_params

        ws = self.workspace()
        params = load_params(ws.params_path, self.overrides)
        if ws.remote is not None:
            remote_root_ready(ws, params, self.command)
        return ws, params


G = Globals()


def open_scene(name: str):
    """The :class:`zipon.Scene` of ``name`` (a ConfigError naming the known scenes when there is none)."""
    from zipon.api import Dataset

    ws, params = G.load()
    return Dataset(ws, params)[name]


def _print_version(value: bool) -> None:
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            out.print(f"zipon {version('zipon')}", highlight=False)
        except PackageNotFoundError:  # run from a source tree that was never installed
            out.print("zipon (not installed: no package metadata; pip install -e . records it)", highlight=False)
        raise typer.Exit()


def subcommand(ctx: typer.Context) -> None:
    """A group's callback: record which command of it runs (``G.command``: "goals export")."""
    G.command = f"{ctx.info_name} {ctx.invoked_subcommand}"


@app.callback()
def _globals(
    ctx: typer.Context,
    params: Optional[Path] = typer.Option(None, "--params", "-p", help="params file (default ./params.yaml)"),
    data_dir: Optional[str] = typer.Option(
        None, "--data-dir", envvar="ZIPON_DATA",
        help="data root: a folder (default: data/ beside params.yaml) or an object store, s3://bucket/prefix"
    ),
    manifests_dir: Optional[Path] = typer.Option(
        None, "--manifests-dir", envvar="ZIPON_MANIFESTS", help="manifests root (default: manifests/ beside params.yaml)"
    ),
    overrides: list[str] = typer.Option(
        [], "--set", "-S", help="override a param for this run, e.g. -S simulate.frames=100 (repeatable)"
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", metavar="", help="warnings and errors only, no progress bars"),
    verbose: int = typer.Option(0, "--verbose", "-v", count=True, metavar="", show_default=False,
                                help="more detail: -v debug messages, -vv also DVC's and dask's own"),
    version: bool = typer.Option(False, "--version", metavar="", is_eager=True, callback=_print_version,
                                 help="print zipon's version and exit"),
):
    from pipeline import logs

    G.params, G.data_dir, G.manifests_dir, G.overrides, G.quiet = params, data_dir, manifests_dir, tuple(overrides), quiet
    G.command = ctx.invoked_subcommand or ""
    logs.configure(-1 if quiet else verbose, console)


# ----------------------------------------------------------------------------- helpers

# What each command does on an object-store data root (--data-dir s3://bucket/prefix, pipeline.engine.fsroot; the README's
# "Data root on an object store" says the same). run, stage: build in the local mirror holding the object store's
# lock, then publish. status, verify: mirror every published stage first. Commands that read artifacts bring the
# published versions of what they read into the mirror and read it there (zipon.Scene.path, zipon.Dataset.mirror).
# goals import also rebuilds goals and routes as stages, which publishes them. The rest read no artifacts.
REMOTE_COMMANDS = ("run", "stage", "status", "verify", "query", "render", "view", "eval", "goals export",
                   "goals export-navchat", "goals template", "goals import", "goals schema", "params", "encoders list",
                   "encoders check", "recon-eval",
                   # a dataset project's: they read git (diff) or write a new project folder (init), never the data root
                   "diff", "init")
# Commands that would write into the data root outside the stages (nothing would publish it): refused, saying why.
REMOTE_REFUSED = {
    "simulate": "writes its logs into the data root's raw/ folder outside any stage, so they would not be published; "
                "list the scenes in params.yaml with source: simulate and `zipon run` builds and publishes their logs "
                "(stage simulate)",
    "ingest": "builds a scene that params.yaml does not list; add it under scenes: in params.yaml and run "
              "`zipon run -s SCENE --stage ingest`, which publishes it",
    "dvc": "writes dvc.yaml for DVC, which tracks outputs in a local data root; on an object store the manifests "
           "record every published version (`zipon status`, `zipon verify`)",
    "demo": "builds, draws and evaluates in one local data root; on an object store run `zipon run`, then "
            "`zipon eval` or `zipon render`, which read the published artifacts",
    "annotate": "serves a workbench over one local data root; on an object store review goals with "
                "`zipon goals export` and save edits with `zipon goals import`, which republishes goals and routes",
    # a dataset project's versions are DVC's: artifacts in the project's local data root, pushed to a DVC remote
    "card": "describes the version DVC recorded in a dataset project's local data root; on an object store the "
            "manifests record every published version (`zipon status`, `zipon verify`)",
    "push": "sends a dataset project's local artifacts to its DVC remote; with an object store as the data root "
            "`zipon run` has already published them",
    "pull": "restores a dataset project's version from its DVC remote into its local data root; on an object store "
            "every command mirrors what it reads",
}


def remote_root_ready(ws, params, command: str) -> None:
    """On an object-store data root (:mod:`pipeline.engine.fsroot`): refuse the commands that would write into it outside
    the stages, and for ``status`` / ``verify`` mirror every published stage into the local cache first (digests
    checked). Commands that read artifacts mirror the scenes they open themselves (:meth:`zipon.Dataset.mirror`)."""
    from pipeline.errors import ConfigError
    from pipeline.engine.fsroot import pull_all
    from pipeline.engine.stagegraph import plan
    from stages import STAGES

    from pipeline.engine.fsroot import RemoteRoot

    command = command or "(no command)"
    if command in REMOTE_REFUSED:
        raise ConfigError(f"--data-dir {ws.remote}: zipon {command} {REMOTE_REFUSED[command]}")
    if command not in REMOTE_COMMANDS:
        raise ConfigError(f"--data-dir {ws.remote}: zipon {command} works on a local data root only; on an object "
                          f"store zipon {', '.join(REMOTE_COMMANDS)} work. After one of them the local mirror is "
                          f"{ws.data_dir}: pass it as --data-dir (and --manifests-dir {ws.manifests_dir})")
    RemoteRoot(ws.remote).check()  # credentials, bucket and endpoint, once, before any stage
    if command in ("status", "verify"):
        pull_all(ws, plan(STAGES, params, list(params.scenes)), verify=command == "verify")


def print_outcomes(outcomes) -> bool:
    table = Table(title="zipon run", show_lines=False)
    for col in ("scene", "stage", "status", "seconds", "note"):
        table.add_column(col)
    styles = {"ran": "green", "skipped": "dim", "failed": "red", "blocked": "yellow"}
    for o in outcomes:
        note = o.reason if o.status != "failed" else o.error.splitlines()[0]
        table.add_row(o.scene, o.stage, f"[{styles[o.status]}]{o.status}[/]", f"{o.seconds:.1f}" if o.seconds else "", note)
    out.print(table)
    failed = [o for o in outcomes if o.status == "failed"]
    for o in failed:
        console.print(f"[red]error[/red] {o.scene}/{o.stage}: {escape(o.error)}", highlight=False, soft_wrap=True)
    return not failed


def select_scenes(params, scenes: list[str]) -> list[str]:
    from pipeline.errors import ConfigError

    if not scenes:
        return list(params.scenes)
    unknown = [s for s in scenes if s not in params.scenes]
    if unknown:
        raise ConfigError(f"unknown scene(s) {unknown}; params.yaml scenes: {sorted(params.scenes)}")
    return scenes


def run_stages(scenes: list[str], stages_wanted: list[str] | None, force: bool, scheduler: str | None,
         record_dvc: bool = True) -> bool:
    """Run the plan; then record what is built in dvc.lock (not for `zipon stage`, which `dvc repro` calls
    while it holds DVC's lock and records the result itself)."""
    from pipeline.errors import ConfigError
    from pipeline.engine.stagegraph import plan
    from pipeline.engine.runner import run_many
    from stages import STAGES

    ws, params = G.load()
    for s in stages_wanted or []:
        if s not in STAGES:
            raise ConfigError(f"unknown stage {s!r}; stages: {list(STAGES)}")
    pairs = plan(STAGES, params, select_scenes(params, scenes), stages_wanted)
    outcomes = run_many(ws, params, STAGES, pairs, force=force, scheduler=scheduler, show_progress=not G.quiet)
    ok = print_outcomes(outcomes)
    if record_dvc:
        from pipeline.engine.dvcfile import sync_dvc_lock

        done = [(o.scene, o.stage) for o in outcomes if o.status in ("ran", "skipped")]
        note = sync_dvc_lock(ws, params, STAGES, done, G.overrides)
        if note:
            console.print(f"[dim]{note}[/dim]")
    return ok


def print_eval(results: dict, out_dir: Path) -> None:
    """The evaluation's mean SR / SPL / SIT table, its run notes and where its results and report are."""
    table = Table(title="orion_eval: mean over seeds (%)")
    for col in ("method", "feedback", "SR", "SPL", "SIT", "episodes"):
        table.add_column(col)
    for method, by_feedback in results["overall"].items():
        for setting, m in by_feedback.items():
            table.add_row(method, setting, f"{m['SR']:.1f}", f"{m['SPL']:.1f}", f"{m['SIT']:.1f}", str(m["episodes"]))
    out.print(table)
    if results.get("by_floors"):  # a building was evaluated: its episodes on the start's floor and across floors
        floors = Table(title="orion_eval: buildings, goal on the start's floor or another (%)")
        for col in ("method", "floors", "feedback", "SR", "SPL", "SIT", "episodes"):
            floors.add_column(col)
        for method, by_kind in results["by_floors"].items():
            for kind, by_feedback in by_kind.items():
                for setting, m in by_feedback.items():
                    floors.add_row(method, kind, setting, f"{m['SR']:.1f}", f"{m['SPL']:.1f}", f"{m['SIT']:.1f}",
                                   str(m["episodes"]))
        out.print(floors)
    from orion_eval.report import run_notes

    for note in run_notes(results["run"]):  # which perception built the maps, what detection ran on
        out.print(note)
    out.print(f"results: {Path(out_dir) / 'results.json'}\nreport:  {Path(out_dir) / 'report.html'}")
