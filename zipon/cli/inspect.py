"""``zipon`` commands that look at built artifacts: goals, annotate, encoders, recon-eval, eval, view (render and
query: :mod:`zipon.cli.maps`)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from zipon.cli.common import G, app, console, open_scene, out, print_eval, print_outcomes, subcommand


goals_app = typer.Typer(help="Review and edit goals: export for people, import their edits, navchat layout. "
                        "Example: `zipon goals export sim_00 -o goals.yaml`",
                        no_args_is_help=True)
app.add_typer(goals_app, name="goals")
goals_app.callback()(subcommand)


@goals_app.command("export")
def goals_export(
    scene: str = typer.Argument(..., help="scene name"),
    out_file: Path = typer.Option(..., "--out", "-o", help="FILE.yaml or FILE.json"),
):
    """Write a scene's goals (name, type, room, feedback) as readable YAML/JSON.

    Example: `zipon goals export sim_00 --out sim_00_goals.yaml`
    """
    from pipeline.goals.edits import export_goals

    out.print(str(export_goals(open_scene(scene).path("goals"), out_file)))


@goals_app.command("import")
def goals_import(
    scene: str = typer.Argument(..., help="scene name"),
    edit_file: Path = typer.Argument(..., help="an edited export (YAML/JSON)"),
):
    """Validate an edited goals file, rebuild goals and routes with it, then register it in params.yaml
    (goals.edits). When the rebuild fails, params.yaml and the built goals and routes stay as they were.

    Example: `zipon goals import sim_00 sim_00_goals.yaml`
    """
    from pipeline.goals.edits import EditNotSaved, save_goals_edit, validate_edit
    from stages import STAGES

    sc = open_scene(scene)
    doc = validate_edit(edit_file, sc.path("goals"))  # on an object store: the published goals, mirrored first
    ws = sc.workspace
    try:
        saved = save_goals_edit(ws, scene, doc, STAGES, overrides=G.overrides, show_progress=not G.quiet)
    except EditNotSaved as err:
        if err.outcomes:
            print_outcomes(err.outcomes)
        if err.restored:
            console.print(f"rebuilt {scene}'s {' and '.join(err.restored)} without the edit")
        raise
    print_outcomes(saved.outcomes)
    out.print(f"stored {saved.path}; {ws.params_path.name} goals.edits.{scene} updated")
    if saved.dvc_note:
        console.print(f"[dim]{saved.dvc_note}[/dim]")


@app.command()
def annotate(
    scene: Optional[str] = typer.Argument(None, help="scene to open first (default: the first in params.yaml)"),
    port: int = typer.Option(8765, "--port", min=1, max=65535, help="TCP port"),
    host: str = typer.Option("127.0.0.1", "--host", help="address to listen on; any other than 127.0.0.1 / "
                             "localhost needs the printed token in the URL"),
):
    """Serve a local web page to see a scene in metres and edit its objects, goals and feedback (saving is
    `zipon goals import`'s transaction). Stop it with Ctrl-C.

    Examples: `zipon annotate sim_00` · `zipon annotate --port 9000` · `zipon annotate --host 0.0.0.0`
    """
    import secrets
    import socket
    import threading

    import uvicorn

    from zipon.annotate.server import LOOPBACK, create_app

    G.load()  # the params file is valid (and on an object store this command is refused, saying why)
    token = None if host in LOOPBACK else secrets.token_urlsafe(24)
    application = create_app(G.params, G.data_dir, G.manifests_dir, scene=scene, overrides=G.overrides,
                             token=token, allowed_hosts=LOOPBACK if token is None else None)
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:  # a clear error, not uvicorn's
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as err:
            from pipeline.errors import ConfigError

            raise ConfigError(f"--host {host} --port {port}: cannot listen there ({err.strerror}); pick another "
                              f"--port") from None
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    url = f"http://{shown}:{port}/" + (f"?token={token}" if token else "") + (f"#{scene}" if scene else "")
    out.print(f"zipon annotate: open {url}\n(Ctrl-C stops it)", soft_wrap=True)
    threading.Thread(target=application.state.workbench.warm, name="annotate-warm", daemon=True).start()
    uvicorn.run(application, host=host, port=port, log_level="warning")


@goals_app.command("export-navchat")
def goals_export_navchat(
    scene: str = typer.Argument(..., help="scene name"),
    folder: Path = typer.Option(..., "--out", "-o", help="folder for objects.json and final.json"),
):
    """Write objects.json / final.json in navchat's layout (cells on goals.navchat_grid; goals imported from
    navchat come back as shipped where nothing was edited).

    Example: `zipon goals export-navchat sim_00 -o navchat/sim_00`
    """
    from pipeline.frames import FrameStore
    from pipeline.goals.navchat import export_scene, write_navchat
    from pipeline.goals.store import Goals

    sc = open_scene(scene)  # on an object store its published goals and frames are mirrored on first use
    ws, params = sc.workspace, sc.params
    goals = Goals(sc.path("goals"))
    frames = FrameStore(sc.path("frames")) if sc.path("frames").exists() else None
    objects_json, final_json = export_scene(goals, params.goals, frames, scene, ws.root)
    write_navchat(folder, objects_json, final_json)
    out.print(f"{folder}/objects.json, {folder}/final.json")


@app.command("recon-eval")
def recon_eval(
    frames: Path = typer.Argument(..., help="a frames.zarr (any sequence)"),
    holdout_every: int = typer.Option(6, "--holdout-every", min=2, help="hold out every N-th frame"),
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
encoders_app.callback()(subcommand)


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
    simulated: bool = typer.Option(False, "--simulated", metavar="", help="resolve as for a simulated scene"),
):
    """Build the configured encoder from its local weights, run one frame and one query, print its identity.

    Example: `zipon encoders check --which cfmap`
    """
    import json

    from pipeline.encoders import check_encoder

    _, params = G.load()
    report = check_encoder(params.encoders, which, simulated=simulated, runtime=params.run)
    out.print_json(json.dumps(report, default=str))


@app.command("eval")
def eval_cmd(
    out_dir: Path = typer.Option(Path("eval_out"), "--out", "-o", help="folder for results.json, report.html, episode logs"),
    scenes: list[str] = typer.Option([], "--scene", "-s", help="scenes (repeatable; default: params eval.scenes)"),
    methods: list[str] = typer.Option([], "--method", "-m", help="human | cow | vlmap | cf | orion, a name an "
                                      "installed package registers (entry points zipon.agents), or module:Class of "
                                      "your own Agent subclass (repeatable; default: eval.methods)"),
    feedback: list[str] = typer.Option([], "--feedback", "-f", help="feedback settings (repeatable; default: all simulated ones); 'human': the episodes a person "
                                        "answered in `zipon annotate` (tab Play), reported as their own setting"),
    seeds: Optional[int] = typer.Option(None, "--seeds", min=1, help="number of seeds: 0 .. N-1 (default: params "
                                        "eval.seeds)"),
    seed_list: list[int] = typer.Option([], "--seed-list", help="explicit seeds (repeatable) instead of --seeds"),
    strict: bool = typer.Option(False, "--strict", help="-f human: refuse stored episodes of goals a later goals "
                                "edit removed (default: leave them out with a warning naming them)"),
):
    """Run ORION-style agents on the built artifacts; write SR / SPL / SIT as JSON and an HTML report.

    Examples: `zipon eval --out eval_out` · `zipon eval -s sim_00 -m orion -m vlmap -f descriptive --seeds 2` ·
    `zipon eval -m mypkg.agents:Greedy --seed-list 3`
    """
    from pipeline.errors import ConfigError
    from zipon.api import Dataset
    from zipon.evaluate import run_eval

    if seeds is not None and seed_list:
        raise ConfigError("--seeds N (a count) and --seed-list (explicit seeds) exclude each other")
    negative = [s for s in seed_list if s < 0]
    if negative:
        raise typer.BadParameter(f"seeds {negative} are negative; seeds are whole numbers 0 or more",
                                 param_hint="--seed-list")
    if out_dir.exists() and not out_dir.is_dir():
        raise typer.BadParameter(f"{out_dir} is a file; give a folder for results.json, report.html and the "
                                 "episode logs", param_hint="--out")
    agents = [_agent_class(m) if ":" in m else m for m in methods] or None
    results = run_eval(Dataset(*G.load()), out_dir, scenes=scenes or None, agents=agents, feedback=feedback or None,
                       seeds=seed_list or seeds, progress=not G.quiet, strict=strict)
    print_eval(results, out_dir)


def _agent_class(spec: str):
    """``module:Class`` -> the class (checked to be an Agent by zipon.run_eval); errors name the spec."""
    import importlib

    from pipeline.errors import ConfigError

    module, _, name = spec.partition(":")
    try:
        obj = importlib.import_module(module)
        for part in name.split("."):
            obj = getattr(obj, part)
    except (Exception, SystemExit) as err:  # noqa: BLE001 - the user's module: whatever its import raises, one line
        what = f"SystemExit({err.code!r})" if isinstance(err, SystemExit) else f"{type(err).__name__}: {err}"
        raise ConfigError(f"--method {spec!r}: cannot import it ({what}); expected module:Class of an Agent "
                          f"subclass importable from here") from None
    return obj


@app.command()
def view(
    scene: str = typer.Argument(..., help="scene name"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="FILE.rrd (default DATA/artifacts/SCENE/"
                                            "renders/SCENE.rrd)"),
    episode: Optional[str] = typer.Option(None, "--episode", "-e", help="replay this evaluated episode (a routes "
                                          "episode id, e.g. chair_0/1) step by step with its dialogue"),
    eval_dir: Optional[Path] = typer.Option(None, "--eval", help="evaluation folder holding episodes/ (default: "
                                            "DATA/eval/demo, what zipon demo writes)"),
    method: Optional[str] = typer.Option(None, "--method", "-m", help="with --episode: the agent's run to replay"),
    feedback: Optional[str] = typer.Option(None, "--feedback", "-f", help="with --episode: the feedback setting"),
    seed: Optional[int] = typer.Option(None, "--seed", help="with --episode: the seed"),
    text: Optional[str] = typer.Option(None, "--query", help="map query drawn as a heatmap (default: the class of "
                                       "the first goal)"),
    max_frames: int = typer.Option(240, "--max-frames", min=1, help="at most this many evenly spaced frames"),
    mesh_voxel: float = typer.Option(0.04, "--mesh-voxel", min=0.0, help="merge mesh vertices within this size, "
                                     "metres (0 = the full TSDF mesh)"),
    mesh_top: float = typer.Option(2.2, "--mesh-top", help="leave out mesh triangles above this height over the "
                                   "floor, metres (the ceiling hides the rooms from above); a negative value keeps all"),
):
    """Write a rerun recording of a scene: frames (colour, depth) on a timeline with the camera and trajectory,
    the TSDF mesh, top-down grids and a query heatmap as textured planes, goals as labelled 3D boxes, routes,
    and an evaluated episode replayed step by step with its dialogue. Open it with `rerun FILE.rrd`.

    Examples: `zipon view sim_00` · `zipon view sim_00 --episode chair_0/0 -m orion -f mixed -o chair.rrd`
    """
    from pipeline.viewer import write_recording

    sc = open_scene(scene)
    sc.mirror()  # on an object store: the scene's published artifacts (the recording reads them all)
    ws, params = sc.workspace, sc.params
    target = out_file or ws.renders(scene) / f"{scene}.rrd"
    s = write_recording(ws, params, scene, target, episode=episode, eval_dir=eval_dir, method=method,
                        feedback=feedback, seed=seed, query=text, max_frames=max_frames, mesh_voxel_m=mesh_voxel,
                        mesh_top_m=mesh_top if mesh_top >= 0 else None)
    parts = [f"{s['frames']} frames", f"{s.get('mesh_vertices', 0):,} mesh vertices",
             f"grids {', '.join(s.get('grids', [])) or 'none'}", f"{s.get('goal_boxes', 0)} goal boxes",
             f"{s.get('routes', 0)} routes"]
    if episode:
        parts.append(f"episode {s['episode']}: {s['steps']} steps, {s['dialogue']} dialogue turns")
    out.print(f"{target}  ({s['bytes'] / 1e6:.1f} MB: {'; '.join(parts)})\nopen it with: rerun {target}")


@goals_app.command("template")
def goals_template(
    scene: str = typer.Argument(..., help="scene name (its built recon or goals give real coordinates)"),
    out_file: Path = typer.Option(..., "--out", "-o", help="FILE.yaml: an objects file to edit"),
):
    """Write a commented objects file to start your own scene's goals from (then set goals.objects: file and
    goals.objects_files.SCENE: FILE in params.yaml).

    The file lists the scene's objects when goals were built, else one example object in the middle of the
    reconstruction; every field is explained in a comment. Example: `zipon goals template lab -o lab_objects.yaml`
    """
    from pipeline.goals.template import objects_template

    sc = open_scene(scene)
    text = objects_template(scene, goals_path=sc.path("goals"), recon_path=sc.path("recon"))
    if out_file.suffix.lower() not in (".yaml", ".yml"):
        from pipeline.errors import InputDataError

        raise InputDataError(f"got {out_file}", field="--out", expected="a .yaml file (the template has comments)")
    from pipeline.store import write_text_atomic

    write_text_atomic(out_file, text)
    out.print(f"{out_file}\nthen in params.yaml: goals: {{objects: file, objects_files: {{{scene}: {out_file}}}}}")


@goals_app.command("schema")
def goals_schema(
    what: str = typer.Option("goals", "--what", "-w", help="goals (an exported/edited goals file) | objects "
                             "(an objects file, goals.objects_files)"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="write here instead of printing"),
):
    """Print the JSON Schema of the goals file or the objects file, for editors that validate YAML/JSON.

    Examples: `zipon goals schema > goals.schema.json` · `zipon goals schema --what objects -o objects.schema.json`
    """
    import json

    from pipeline.goals.template import json_schema

    text = json.dumps(json_schema(what), indent=2) + "\n"
    if out_file is None:
        out.print(text, end="", markup=False, highlight=False, soft_wrap=True)
        return
    from pipeline.store import write_text_atomic

    write_text_atomic(out_file, text)
    out.print(str(out_file))
