"""``zipon`` commands that build and check the dataset: run, stage, status, verify, simulate, ingest, params, dvc,
demo."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape
from rich.table import Table

from pipeline import plugins
from zipon.cli.common import G, app, console, out, print_eval, print_outcomes, run_stages


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
    if not run_stages(scene, stage or None, force, scheduler):
        raise typer.Exit(1)


@app.command("stage")
def stage_cmd(
    name: str = typer.Argument(..., help="stage name, e.g. ingest"),
    scene: str = typer.Option(..., "--scene", "-s", help="scene name from params.yaml"),
    force: bool = typer.Option(False, "--force", metavar="", help="rerun even when up to date"),
):
    """Run one stage of one scene (what dvc.yaml calls). Example: `zipon stage ingest --scene sim_00`"""
    if not run_stages([scene], [name], force, "sync", record_dvc=False):
        raise typer.Exit(1)


@app.command()
def status(
    check: bool = typer.Option(False, "--check", metavar="", help="exit 1 when any stage is stale (for CI and scripts)"),
    rehash: bool = typer.Option(False, "--verify", metavar="", help="also re-hash every built output against its manifest "
                                "(as `zipon verify` does); exit 1 when content differs"),
):
    """Show which stages are up to date and, for the others, what changed: the code files, the params keys
    (`params: maps.level_height_m 0.1 -> 0.2`) or the inputs. In a DVC project (a versioned dataset) also whether
    the dataset card (DATASET.md, dataset.json) states the current version; `--check` fails while it does not.

    Examples: `zipon status` · `zipon status --check && echo dataset current`
    """
    from rich.markup import escape

    from pipeline.engine.stagegraph import plan, staleness
    from stages import STAGES

    ws, params = G.load()
    table = Table(title=f"zipon status ({ws.data_dir})")
    for col in ("scene", "stage", "state"):
        table.add_column(col, overflow="fold")
    stale, bad_content = 0, []
    for scene, stage in plan(STAGES, params, list(params.scenes)):
        why = staleness(ws, params, STAGES, STAGES[stage], scene)
        if rehash:
            from pipeline.engine.verify import content_staleness

            tampered = content_staleness(ws, STAGES[stage], scene)
            if tampered:
                why = "; ".join(filter(None, [why, f"content differs from the manifest: {tampered}"]))
                bad_content.append(f"{scene}/{stage}: {tampered}")
        stale += bool(why)
        table.add_row(scene, stage, f"[yellow]stale: {escape(why)}[/]" if why else "[green]up to date[/]")
    out.print(table)
    out.print(f"{stale} stale stage(s)")
    from pipeline.engine.dvcfile import dvc_lock_target

    versioned = not dvc_lock_target(ws, G.overrides)  # a DVC project: dvc.lock follows the runs
    card, dvc_files = _project_staleness(ws, params) if versioned else ("", [])
    if card:  # a versioned dataset states itself in its card
        stale += 1
        console.print(f"[yellow]dataset card stale[/yellow]: {escape(card)} (`zipon card` rewrites it)",
                      highlight=False, soft_wrap=True)
    for line in dvc_files:  # DVC sees a code or params change only once these are rewritten
        console.print(f"[yellow]for DVC[/yellow]: {escape(line)} (`zipon dvc` or `zipon run` rewrites it)",
                      highlight=False, soft_wrap=True)
    for line in bad_content:  # one unwrapped line each, so paths can be copied
        console.print(f"[red]content differs[/red] {escape(line)}", highlight=False, soft_wrap=True)
    if bad_content:
        console.print(f"[red]{len(bad_content)} stage(s) whose content differs from their manifests[/red] "
                      "(`zipon verify` lists every artifact; rebuild with `zipon run --force`)")
    if (check and stale) or bad_content:
        raise typer.Exit(1)


def _project_staleness(ws, params) -> tuple[str, list[str]]:
    """Why the dataset card is stale ('' if it is not), and what of dvc.yaml and the code identities is not current."""
    from pipeline.engine.dvcfile import dvc_files_problems
    from pipeline.project.card import card_staleness
    from stages import STAGES

    return card_staleness(ws, params, STAGES), dvc_files_problems(ws, params, STAGES)


@app.command()
def verify():
    """Re-hash every artifact on disk and compare it with its manifest (corrupt ones, ones without a manifest and
    scenes no longer in the params file included); exit 1 on any mismatch. Example: `zipon verify`"""
    from pipeline.engine.verify import verify_all
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

    Example: `zipon simulate --scenes 10 --frames 1400` gives the paper's ~14k frames. Build them with
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
    path: Path = typer.Argument(..., exists=False, help="raw log or dataset folder (see --format)"),
    scene: str = typer.Option(..., "--scene", "-s", help="scene name for the artifacts"),
    fmt: str = typer.Option("auto", "--format", help=f"auto | {' | '.join(plugins.BUILT_IN_READERS)} | a reader an "
                            "installed package registers (zipon.readers entry points)"),
    force: bool = typer.Option(False, "--force", metavar="", help="rerun even when up to date"),
):
    """Ingest one raw log or dataset folder into DATA/artifacts/SCENE/frames.zarr (with its manifest).

    Examples: `zipon ingest robot.mcap --scene kitchen` · `zipon ingest rgbd_dataset_freiburg1_desk --scene desk --format tum`
    """
    from pipeline.paramsfile import parse_params
    from pipeline.engine.runner import run_many
    from stages import STAGES

    ws, params = G.load()
    raw = params.model_dump(mode="json")
    # plain data, validated with the rest: a bad --format is a ConfigError naming scenes.<scene>.format
    raw["scenes"] = {**raw["scenes"], scene: {"source": str(Path(path).resolve()), "format": fmt}}
    params = parse_params(raw, origin="zipon ingest")
    outcomes = run_many(ws, params, STAGES, [(scene, "ingest")], force=force, scheduler="sync",
                        show_progress=not G.quiet)
    ok = print_outcomes(outcomes)
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
    from pipeline.paramsfile import parse_params, params_yaml

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
def dvc_cmd(check: bool = typer.Option(False, "--check", metavar="",
                                       help="only check dvc.yaml and the code identity files are current (exit 1 if not)")):
    """Write dvc.yaml from the stage registry and params.yaml (so `dvc repro` runs the same DAG), and each stage's
    code identity `.zipon/code/STAGE.json` (zipon's version and the stage's code digest) that dvc.yaml lists as the
    stage's code. Run it after upgrading zipon: DVC then sees exactly the stages whose code changed.

    Examples: `zipon dvc && dvc repro` · `zipon dvc --check` (CI: names a dvc.yaml edited by hand)
    """
    from pipeline.engine.dvcfile import dvc_files_problems, write_dvc_files
    from stages import STAGES

    ws, params = G.load()
    if check:
        problems = dvc_files_problems(ws, params, STAGES)
        for line in problems:
            console.print(f"[red]out of date[/red] {escape(str(ws.root))}/{escape(line)}", highlight=False,
                          soft_wrap=True)
        if problems:
            console.print("[red]regenerate with `zipon dvc`[/red]")
            raise typer.Exit(1)
        out.print(f"{ws.root / 'dvc.yaml'} and the code identity files are current")
        return
    written = write_dvc_files(ws, params, STAGES)
    out.print("\n".join(f"wrote {p}" for p in written) or f"{ws.root / 'dvc.yaml'} and the code identity files are "
              "current", highlight=False, soft_wrap=True)


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

    ok = run_stages([], None, False, scheduler)
    ws, params = G.load()
    built = [s for s in params.scenes if ws.artifact("routes", s).exists()]
    from zipon.api import Dataset

    dataset = Dataset(ws, params)
    pictures = render_all([dataset[s] for s in params.scenes])
    report = None
    if ok and eval_seeds and built:  # a building too: its cross-floor episodes are reported apart
        from zipon.evaluate import run_eval

        eval_dir = ws.data_dir / "eval" / "demo"
        results = run_eval(dataset, eval_dir, scenes=built, seeds=eval_seeds, progress=not G.quiet)
        print_eval(results, eval_dir)
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
