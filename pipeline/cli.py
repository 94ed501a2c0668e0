"""The ``zipon`` command line. Only this module turns errors into messages and exit codes."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from pipeline.errors import ZiponError

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_show_locals=False,
    rich_markup_mode="markdown",
    help="**zipon** — raw RGB-D robot logs → versioned ZIPON datasets (scenes, semantic maps, goals, routes) "
    "and the orion_eval evaluator.\n\nStart with `zipon demo`; `zipon COMMAND --help` shows examples.",
)
console = Console(stderr=True)
out = Console()


@dataclass
class Globals:
    params: Optional[Path] = None
    data_dir: Optional[Path] = None
    manifests_dir: Optional[Path] = None
    overrides: tuple[str, ...] = ()
    quiet: bool = False

    def workspace(self):
        from pipeline.paths import Workspace

        return Workspace.resolve(self.params, self.data_dir, self.manifests_dir)

    def load(self):
        from pipeline.config import load_params

        ws = self.workspace()
        return ws, load_params(ws.params_path, self.overrides)


G = Globals()


@app.callback()
def _globals(
    params: Optional[Path] = typer.Option(None, "--params", "-p", help="params file (default ./params.yaml)"),
    data_dir: Optional[Path] = typer.Option(
        None, "--data-dir", envvar="ZIPON_DATA", help="data root (default: data/ beside params.yaml)"
    ),
    manifests_dir: Optional[Path] = typer.Option(
        None, "--manifests-dir", envvar="ZIPON_MANIFESTS", help="manifests root (default: manifests/ beside params.yaml)"
    ),
    overrides: list[str] = typer.Option(
        [], "--set", "-S", help="override a param for this run, e.g. -S simulate.frames=100 (repeatable)"
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", metavar="", help="no progress bars"),
):
    G.params, G.data_dir, G.manifests_dir, G.overrides, G.quiet = params, data_dir, manifests_dir, tuple(overrides), quiet


# ----------------------------------------------------------------------------- helpers

def _print_outcomes(outcomes) -> bool:
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


def _scenes(params, scenes: list[str]) -> list[str]:
    from pipeline.errors import ConfigError

    if not scenes:
        return list(params.scenes)
    unknown = [s for s in scenes if s not in params.scenes]
    if unknown:
        raise ConfigError(f"unknown scene(s) {unknown}; params.yaml scenes: {sorted(params.scenes)}")
    return scenes


def _run(scenes: list[str], stages_wanted: list[str] | None, force: bool, scheduler: str | None,
         record_dvc: bool = True) -> bool:
    """Run the plan; then record what is built in dvc.lock (not for `zipon stage`, which `dvc repro` calls
    while it holds DVC's lock and records the result itself)."""
    from pipeline.errors import ConfigError
    from pipeline.runner import plan, run_many
    from stages import STAGES

    ws, params = G.load()
    for s in stages_wanted or []:
        if s not in STAGES:
            raise ConfigError(f"unknown stage {s!r}; stages: {list(STAGES)}")
    pairs = plan(STAGES, params, _scenes(params, scenes), stages_wanted)
    outcomes = run_many(ws, params, STAGES, pairs, force=force, scheduler=scheduler, show_progress=not G.quiet)
    ok = _print_outcomes(outcomes)
    if record_dvc:
        from pipeline.dvcfile import sync_dvc_lock

        done = [(o.scene, o.stage) for o in outcomes if o.status in ("ran", "skipped")]
        note = sync_dvc_lock(ws, params, STAGES, done, G.overrides)
        if note:
            console.print(f"[dim]{note}[/dim]")
    return ok


# ----------------------------------------------------------------------------- commands

@app.command()
def run(
    scene: list[str] = typer.Option([], "--scene", "-s", help="only these scenes (repeatable; default: all in params)"),
    stage: list[str] = typer.Option([], "--stage", help="only these stages (repeatable)"),
    force: bool = typer.Option(False, "--force", metavar="", help="rerun even when up to date"),
    scheduler: Optional[str] = typer.Option(
        None, "--scheduler", help="sync | threads | processes | a dask.distributed address (default: params run.scheduler)"
    ),
):
    """Run the stage DAG for the scenes in params.yaml, skipping stages whose inputs and params are unchanged.

    Examples: `zipon run` · `zipon run -s sim_00 --stage ingest --force` · `zipon run --scheduler tcp://host:8786`
    """
    if not _run(scene, stage or None, force, scheduler):
        raise typer.Exit(1)


@app.command("stage")
def stage_cmd(
    name: str = typer.Argument(..., help="stage name, e.g. ingest"),
    scene: str = typer.Option(..., "--scene", "-s", help="scene name from params.yaml"),
    force: bool = typer.Option(False, "--force", metavar="", help="rerun even when up to date"),
):
    """Run one stage of one scene (what dvc.yaml calls). Example: `zipon stage ingest --scene sim_00`"""
    if not _run([scene], [name], force, "sync", record_dvc=False):
        raise typer.Exit(1)


@app.command()
def status(
    check: bool = typer.Option(False, "--check", metavar="", help="exit 1 when any stage is stale (for CI and scripts)"),
    rehash: bool = typer.Option(False, "--verify", metavar="", help="also re-hash every built output against its manifest "
                                "(as `zipon verify` does); exit 1 when content differs"),
):
    """Show which stages are up to date and, for the others, what changed: the code files, the params keys
    (`params: maps.level_height_m 0.1 -> 0.2`) or the inputs.

    Examples: `zipon status` · `zipon status --check && echo dataset current`
    """
    from rich.markup import escape

    from pipeline.runner import plan, staleness
    from stages import STAGES

    ws, params = G.load()
    table = Table(title=f"zipon status ({ws.data_dir})")
    for col in ("scene", "stage", "state"):
        table.add_column(col, overflow="fold")
    stale, bad_content = 0, []
    for scene, stage in plan(STAGES, params, list(params.scenes)):
        why = staleness(ws, params, STAGES, STAGES[stage], scene)
        if rehash:
            from pipeline.verify import content_staleness

            tampered = content_staleness(ws, STAGES[stage], scene)
            if tampered:
                why = "; ".join(filter(None, [why, f"content differs from the manifest: {tampered}"]))
                bad_content.append(f"{scene}/{stage}: {tampered}")
        stale += bool(why)
        table.add_row(scene, stage, f"[yellow]stale: {escape(why)}[/]" if why else "[green]up to date[/]")
    out.print(table)
    out.print(f"{stale} stale stage(s)")
    for line in bad_content:  # one unwrapped line each, so paths can be copied
        console.print(f"[red]content differs[/red] {escape(line)}", highlight=False, soft_wrap=True)
    if bad_content:
        console.print(f"[red]{len(bad_content)} stage(s) whose content differs from their manifests[/red] "
                      "(`zipon verify` lists every artifact; rebuild with `zipon run --force`)")
    if (check and stale) or bad_content:
        raise typer.Exit(1)


@app.command()
def verify():
    """Re-hash every artifact on disk and compare it with its manifest (corrupt ones, ones without a manifest and
    scenes no longer in the params file included); exit 1 on any mismatch. Example: `zipon verify`"""
    from pipeline.verify import verify_all
    from stages import STAGES

    ws, params = G.load()
    rows = verify_all(ws, params, STAGES)
    table = Table(title="zipon verify")
    for col in ("scene", "stage", "artifact", "result"):
        table.add_column(col, overflow="fold")
    bad = 0
    for r in rows:
        bad += not r.ok
        note = f" [yellow]({escape(r.note)})[/]" if r.note else ""
        table.add_row(r.scene, r.stage, r.artifact, ("[green]ok[/]" if r.ok else f"[red]{escape(r.problem)}[/]") + note)
    out.print(table)
    for r in rows:  # one unwrapped line each, so paths can be copied
        if not r.ok:
            note = f" ({r.note})" if r.note else ""
            console.print(f"[red]mismatch[/red] {r.scene}/{r.stage}/{r.artifact}: {escape(r.problem + note)}",
                          highlight=False, soft_wrap=True)
    if bad:
        console.print(f"[red]{bad} of {len(rows)} artifact(s) do not match their manifests[/red]")
        raise typer.Exit(1)
    out.print(f"{len(rows)} artifact(s) match their manifests")


@app.command()
def simulate(
    scenes: int = typer.Option(2, "--scenes", "-n", min=1, help="number of scenes"),
    frames: Optional[int] = typer.Option(None, "--frames", "-f", min=1, help="frames per scene (default: params)"),
    seed: Optional[int] = typer.Option(None, "--seed", help="base seed (default: params)"),
    prefix: str = typer.Option("sim_", "--prefix", help="scene names are PREFIX00, PREFIX01, ..."),
    out_dir: Optional[Path] = typer.Option(None, "--out", help="folder for the logs (default: DATA/raw)"),
):
    """Write procedural indoor scenes as ROS 2 MCAP logs (the embedded default data).

    `zipon simulate --scenes 10 --frames 1400` gives the paper's ~14k frames. Build them with
    `zipon ingest DATA/raw/sim_00.mcap --scene sim_00`, or list them in params.yaml with `source: simulate`.
    """
    from pipeline.sim import simulate_scene
    from pipeline.store import new_tmp_dir, publish, remove

    ws, params = G.load()
    sim = params.simulate.model_copy(update={k: v for k, v in (("frames", frames), ("seed", seed)) if v is not None})
    target = Path(out_dir) if out_dir else ws.artifact("raw_log", "x").parent
    target.mkdir(parents=True, exist_ok=True)
    for i in range(scenes):
        name = f"{prefix}{i:02d}"
        tmp = new_tmp_dir(target / ".tmp", name)
        try:
            summary = simulate_scene(name, sim, tmp / f"{name}.mcap")
            publish(tmp / f"{name}.mcap", target / f"{name}.mcap")
        finally:
            remove(tmp)
        out.print(f"{name}: {target / f'{name}.mcap'}  ({summary.get('frames')} frames, "
                  f"{summary.get('objects')} objects, {summary.get('rooms')} rooms)")


@app.command()
def ingest(
    path: Path = typer.Argument(..., exists=False, help="MCAP log, TUM / 7-Scenes / navchat folder"),
    scene: str = typer.Option(..., "--scene", "-s", help="scene name for the artifacts"),
    fmt: str = typer.Option("auto", "--format", help="auto | mcap | rosbag | tum | 7scenes | navchat | replica | scannet"),
    force: bool = typer.Option(False, "--force", metavar="", help="rerun even when up to date"),
):
    """Ingest one raw log or dataset folder into DATA/artifacts/SCENE/frames.zarr (with its manifest).

    Examples: `zipon ingest robot.mcap --scene kitchen` · `zipon ingest ../shared/data/real/tum_fr1_rpy_head30 --scene tum --format tum`
    """
    from pipeline.config import parse_params
    from pipeline.runner import run_many
    from stages import STAGES

    ws, params = G.load()
    raw = params.model_dump(mode="json")
    # plain data, validated with the rest: a bad --format is a ConfigError naming scenes.<scene>.format
    raw["scenes"] = {**raw["scenes"], scene: {"source": str(Path(path).resolve()), "format": fmt}}
    params = parse_params(raw, origin="zipon ingest")
    outcomes = run_many(ws, params, STAGES, [(scene, "ingest")], force=force, scheduler="sync",
                        show_progress=not G.quiet)
    ok = _print_outcomes(outcomes)
    if not ok:
        raise typer.Exit(1)
    out.print(f"frames: {ws.artifact('frames', scene)}\nTo build the rest with `zipon run`, add to params.yaml:\n"
              f"  scenes:\n    {scene}: {{source: {Path(path).resolve()}, format: {fmt}}}")


@app.command("params")
def params_cmd(
    defaults: bool = typer.Option(False, "--defaults", metavar="", help="print every tunable with its default"),
    write: bool = typer.Option(False, "--write", metavar="", help="rewrite params.yaml in place, complete and documented"),
):
    """Print the resolved params (or the full defaults, a starting params.yaml); `--write` completes params.yaml.

    Examples: `zipon params --defaults` · `zipon params --write` (after upgrading zipon)
    """
    from pipeline.config import parse_params, params_yaml

    if defaults:
        params = parse_params({"scenes": {"sim_00": {"source": "simulate"}}})
    else:
        ws, params = G.load()
    text = params_yaml(params)
    if write and not defaults:
        from pipeline.store import write_text_atomic

        write_text_atomic(ws.params_path, text)
        out.print(f"wrote {ws.params_path}")
        return
    out.print(text, end="", markup=False, highlight=False, soft_wrap=True)


@app.command("dvc")
def dvc_cmd(check: bool = typer.Option(False, "--check", metavar="", help="only check dvc.yaml is current (exit 1 if not)")):
    """Write dvc.yaml from the stage registry and params.yaml (so `dvc repro` runs the same DAG).

    Example: `zipon dvc && dvc repro`
    """
    from pipeline.dvcfile import render_dvc_yaml
    from stages import STAGES

    ws, params = G.load()
    text = render_dvc_yaml(ws, params, STAGES)
    path = ws.root / "dvc.yaml"
    if check:
        if not path.is_file() or path.read_text() != text:
            console.print(f"[red]{path} is out of date: run zipon dvc[/red]", soft_wrap=True)
            raise typer.Exit(1)
        out.print(f"{path} is current")
        return
    from pipeline.store import write_text_atomic

    write_text_atomic(path, text)
    out.print(f"wrote {path}")


# Commands on built artifacts live in their own module; importing it registers them here.
from pipeline import cli_inspect  # noqa: E402,F401
from pipeline.cli_inspect import _print_eval  # noqa: E402


@app.command()
def demo(
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help="dask scheduler (default: params run.scheduler)"),
    eval_seeds: int = typer.Option(1, "--eval-seeds", min=0, help="seeds of the closing evaluation (0 = skip it)"),
):
    """The main job on the embedded default data: simulate the demo scenes, run every stage, draw pictures,
    evaluate the agents, and print where everything is.

    Example: `zipon demo` (a few minutes on 2 cores), then open the PNGs and report.html it lists.
    """
    from pipeline.demo import render_all

    ok = _run([], None, False, scheduler)
    ws, params = G.load()
    built = [s for s in params.scenes if ws.artifact("routes", s).exists()]
    pictures = render_all(ws, params, list(params.scenes))
    report = None
    if ok and eval_seeds and built:
        from orion_eval.run import run_eval

        eval_dir = ws.data_dir / "eval" / "demo"
        results = run_eval(ws, params, eval_dir, scenes=built, seeds=list(range(eval_seeds)), progress=not G.quiet)
        _print_eval(results, eval_dir)
        report = eval_dir / "report.html"
    table = Table(title="zipon demo: where things are")
    table.add_column("what", no_wrap=True)
    table.add_column("path", overflow="fold")
    for scene in params.scenes:
        table.add_row(f"{scene} artifacts", str(ws.artifact("frames", scene).parent))
        table.add_row(f"{scene} manifests", str(ws.manifest(scene, "x").parent))
    for p in pictures:
        table.add_row("picture", str(p))
    if report:
        table.add_row("evaluation report", str(report))
    out.print(table)
    if not ok:
        raise typer.Exit(1)


# ----------------------------------------------------------------------------- entry point

def main(argv: list[str] | None = None) -> int:
    """Console entry: run the app; turn zipon errors and OS errors (disk full, read-only, permissions)
    into a one-line message naming the path and exit code 1; usage errors exit 2."""
    from typer._click.exceptions import ClickException

    from pipeline.errors import os_error_message

    try:
        # standalone_mode=False: typer RETURNS the code of typer.Exit(n) instead of raising it.
        code = app(args=argv, standalone_mode=False, prog_name="zipon")
    except ZiponError as err:
        console.print(f"[red]error:[/red] {escape(str(err))}", highlight=False, soft_wrap=True)
        return 1
    except OSError as err:  # after ZiponError: MissingInputError is a FileNotFoundError too
        console.print(f"[red]error:[/red] {escape(os_error_message(err))}", highlight=False, soft_wrap=True)
        return 1
    except typer.Exit as e:
        return e.exit_code
    except typer.Abort:
        console.print("aborted")
        return 130
    except ClickException as e:  # usage errors: typer's own message and exit code 2
        e.show()
        return e.exit_code
    return code if isinstance(code, int) else 0


def entry() -> None:
    sys.exit(main())
