"""``zipon`` commands that look at built artifacts: render, query, goals, encoders, recon-eval, eval.

Registered on the app of :mod:`pipeline.cli` when that module imports this one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from pipeline.cli import G, _run, app, out


RENDERS = {
    "frames": "frame contact sheet (colour / depth / instances)",
    "plan": "ground-truth floor plan of a simulated scene",
    "obstacles": "occupancy grid (unknown / free / occupied)",
    "navigable": "navigable cells for the robot radius",
    "color": "top-surface colour map",
    "height": "max height above the floor",
    "goals": "goals, landmarks and names on the colour map",
    "routes": "episodes' start poses and geodesic routes on the colour map",
}


@app.command()
def render(
    scene: str = typer.Argument(..., help="scene name"),
    what: str = typer.Option("color", "--what", "-w", help=" | ".join(RENDERS)),
    out_png: Optional[Path] = typer.Option(None, "--out", "-o", help="PNG path (default DATA/artifacts/SCENE/renders/WHAT.png)"),
):
    """Draw an artifact as a north-up PNG with a scale bar.

    Examples: `zipon render sim_00 --what navigable` · `zipon render sim_00 --what routes -o routes.png`
    """
    from pipeline.errors import ConfigError

    if what not in RENDERS:
        raise ConfigError(f"--what {what!r}: choose one of {', '.join(RENDERS)}")
    ws, params = G.load()
    target = Path(out_png) if out_png else ws.renders(scene) / f"{what}.png"
    art = lambda name: ws.artifact(name, scene)  # noqa: E731
    if what == "frames":
        from pipeline.pictures import frames_contact_sheet

        frames_contact_sheet(art("frames"), target)
    elif what == "plan":
        from pipeline.frames import FrameStore
        from pipeline.scene_gt import GTScene
        from pipeline.sim.topdown import render_scene_png

        gt = FrameStore(art("frames")).ground_truth
        if gt is None:
            raise ConfigError(f"scene {scene}: --what plan needs ground truth (a simulated scene)")
        render_scene_png(GTScene.model_validate(gt), target)
    elif what in ("goals", "routes"):
        from pipeline.goals.render import render_goals

        render_goals(art("recon"), art("goals"), art("routes") if what == "routes" else None, what, target)
    else:
        from pipeline.recon.render import render_recon

        render_recon(art("recon"), what, target)
    out.print(str(target))


goals_app = typer.Typer(help="Review and edit goals: export for people, import their edits, navchat layout. "
                        "Example: `zipon goals export sim_00 -o goals.yaml`",
                        no_args_is_help=True)
app.add_typer(goals_app, name="goals")


@goals_app.command("export")
def goals_export(
    scene: str = typer.Argument(..., help="scene name"),
    out_file: Path = typer.Option(..., "--out", "-o", help="FILE.yaml or FILE.json"),
):
    """Write a scene's goals (name, type, room, feedback) as readable YAML/JSON.

    Example: `zipon goals export sim_00 --out sim_00_goals.yaml`
    """
    from pipeline.goals.edits import export_goals

    ws, _ = G.load()
    out.print(str(export_goals(ws.artifact("goals", scene), out_file)))


@goals_app.command("import")
def goals_import(
    scene: str = typer.Argument(..., help="scene name"),
    edit_file: Path = typer.Argument(..., help="an edited export (YAML/JSON)"),
):
    """Validate an edited goals file, register it in params.yaml (goals.edits) and rebuild goals and routes.

    Example: `zipon goals import sim_00 sim_00_goals.yaml`
    """
    from pipeline.goals.edits import import_goals, record_goals_edit

    ws, _ = G.load()
    rel = import_goals(edit_file, ws.artifact("goals", scene), ws.root)
    record_goals_edit(ws.params_path, scene, rel)
    out.print(f"stored {rel}; params.yaml goals.edits.{scene} updated")
    if not _run([scene], ["goals", "routes"], False, "sync"):
        raise typer.Exit(1)


@goals_app.command("export-navchat")
def goals_export_navchat(
    scene: str = typer.Argument(..., help="scene name"),
    folder: Path = typer.Option(..., "--out", "-o", help="folder for objects.json and final.json"),
):
    """Write objects.json / final.json in navchat's layout (cells on the scene's grid).

    Example: `zipon goals export-navchat sim_00 -o navchat/sim_00`
    """
    from pipeline.goals.navchat import export_navchat, write_navchat
    from pipeline.goals.store import Goals

    ws, _ = G.load()
    goals = Goals(ws.artifact("goals", scene))
    objects_json, final_json = export_navchat(goals.object_set(), goals.document, goals.grid,
                                              goals.attrs.get("landmarks"))
    write_navchat(folder, objects_json, final_json)
    out.print(f"{folder}/objects.json, {folder}/final.json")


@app.command()
def query(
    scene: str = typer.Argument(..., help="scene name"),
    text: str = typer.Argument(..., help='what to look for, e.g. "chair" or "the red couch"'),
    map_name: str = typer.Option("vlmap", "--map", help="vlmap | cfmap"),
    pose: Optional[str] = typer.Option(None, "--pose", help="x,y,yaw (metres, radians) to measure candidates from"),
    as_json: bool = typer.Option(False, "--json", help="print the result as JSON"),
    png: Optional[Path] = typer.Option(None, "--png", help="write the heatmap and candidates over the colour map"),
):
    """Query a semantic map with text: a similarity heatmap and object candidates (id, distance, angle).

    Examples: `zipon query sim_00 chair --pose 2,3,0` · `zipon query sim_00 "green plant" --map cfmap --png plant.png`
    """
    from pipeline.errors import ConfigError
    from pipeline.maps.query import parse_pose, query_map

    if map_name not in ("vlmap", "cfmap"):
        raise ConfigError(f"--map {map_name!r}: choose vlmap or cfmap")
    ws, params = G.load()
    result = query_map(ws.artifact(map_name, scene), ws.artifact("recon", scene), text,
                       parse_pose(pose) if pose else None, params=params, frames_path=ws.artifact("frames", scene))
    if png:
        from pipeline.maps.render import render_query

        render_query(result, png)
    if as_json:
        out.print_json(result.to_json_text())
        return
    table = Table(title=f"{scene} {map_name}: {text!r}")
    for col in ("obj_id", "distance (m)", "angle (deg)", "score", "area (m²)", "ground truth"):
        table.add_column(col)
    import math

    for c in result.candidates:
        angle = None if c.angle_rad is None else math.degrees(c.angle_rad)
        gt = "" if c.gt_class is None else f"{c.gt_class} #{c.gt_instance}"
        table.add_row(str(c.obj_id), _fmt(c.distance_m), _fmt(angle), _fmt(c.score), _fmt(c.area_m2), gt)
    out.print(table)
    if png:
        out.print(str(png))


def _fmt(v) -> str:
    return "" if v is None else f"{v:.2f}" if isinstance(v, float) else str(v)


@app.command("recon-eval")
def recon_eval(
    frames: Path = typer.Argument(..., help="a frames.zarr (any sequence)"),
    holdout_every: int = typer.Option(10, "--holdout-every", min=2, help="hold out every N-th frame"),
    recon: Optional[Path] = typer.Option(None, "--recon", help="score this recon.zarr's grids against the ground "
                                         "truth the frames carry (simulated scenes) instead"),
):
    """Fuse all but every N-th frame, ray-cast depth at the held-out poses, print the depth error as JSON.

    With `--recon`, print the grids' IoU against the simulator's ground truth instead.
    Examples: `zipon recon-eval data/artifacts/tum/frames.zarr --holdout-every 6`;
    `zipon recon-eval data/artifacts/sim_00/frames.zarr --recon data/artifacts/sim_00/recon.zarr`
    """
    import json

    from pipeline.recon.evaluate import evaluate_holdout

    _, params = G.load()
    if recon is None:
        figures = evaluate_holdout(frames, params.reconstruct, holdout_every)
    else:
        from pipeline.recon.evaluate import evaluate_grids

        figures = evaluate_grids(frames, recon, params.reconstruct)
    out.print_json(json.dumps({"frames": str(frames), **figures}))


encoders_app = typer.Typer(help="Open-vocabulary encoders: list them, check that one loads and runs. "
                           "Example: `zipon encoders check --which vlmap`", no_args_is_help=True)
app.add_typer(encoders_app, name="encoders")


@encoders_app.command("list")
def encoders_list():
    """List the encoders and which one each map stage uses. Example: `zipon encoders list`"""
    from pipeline.encoders import ENCODERS

    _, params = G.load()
    enc = params.encoders
    for name in sorted(ENCODERS):
        uses = [w for w in ("vlmap", "cfmap") if getattr(enc, w) == name]
        if enc.simulated == name:
            uses.append("simulated scenes")
        tag = " (diagnostic: ground truth)" if ENCODERS[name].diagnostic else ""
        out.print(f"{name}{tag}" + (f"  <- {', '.join(uses)}" if uses else ""))


@encoders_app.command("check")
def encoders_check(
    which: str = typer.Option("vlmap", "--which", help="vlmap | cfmap | an encoder name"),
    simulated: bool = typer.Option(False, "--simulated", help="resolve as for a simulated scene"),
):
    """Build the configured encoder from its local weights, run one frame and one query, print its identity.

    Example: `zipon encoders check --which cfmap`
    """
    import json

    from pipeline.encoders import check_encoder

    _, params = G.load()
    out.print_json(json.dumps(check_encoder(params.encoders, which, simulated=simulated), default=str))


@app.command("eval")
def eval_cmd(
    out_dir: Path = typer.Option(Path("eval_out"), "--out", "-o", help="folder for results.json, report.html, episode logs"),
    scenes: list[str] = typer.Option([], "--scenes", "-s", help="scenes (repeatable; default: params eval/scenes)"),
    methods: list[str] = typer.Option([], "--methods", "-m", help="human | cow | vlmap | cf | orion (repeatable)"),
    feedback: list[str] = typer.Option([], "--feedback", "-f", help="feedback settings (repeatable; default: all)"),
    seeds: list[int] = typer.Option([], "--seeds", help="seeds (repeatable; default: params eval.seeds)"),
):
    """Run ORION-style agents on the built artifacts; write SR / SPL / SIT as JSON and an HTML report.

    Examples: `zipon eval --out eval_out` · `zipon eval -s sim_00 -m orion -m vlmap -f descriptive --seeds 0`
    """
    from orion_eval.run import run_eval

    ws, params = G.load()
    results = run_eval(ws, params, out_dir, scenes=scenes or None, methods=methods or None,
                       feedback=feedback or None, seeds=seeds or None, progress=not G.quiet)
    _print_eval(results, out_dir)


def _print_eval(results: dict, out_dir: Path) -> None:
    table = Table(title="orion_eval: mean over seeds (%)")
    for col in ("method", "feedback", "SR", "SPL", "SIT", "episodes"):
        table.add_column(col)
    for method, by_feedback in results["overall"].items():
        for setting, m in by_feedback.items():
            table.add_row(method, setting, f"{m['SR']:.1f}", f"{m['SPL']:.1f}", f"{m['SIT']:.1f}", str(m["episodes"]))
    out.print(table)
    out.print(f"results: {Path(out_dir) / 'results.json'}\nreport:  {Path(out_dir) / 'report.html'}")
