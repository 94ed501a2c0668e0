"""``zipon`` commands that draw and query a scene's top-down products, floor by floor: render and query.

On a building (a scene of several floors) both work per floor: ``--floor N`` picks one floor (0 = the lowest);
without it, ``render`` writes one picture per floor (``WHAT_floor<id>.png``) and ``query`` answers from every floor,
each candidate with its floor.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Tuple

import typer
from rich.table import Table

from zipon.cli.common import app, open_scene, out

RENDERS = {
    "frames": "frame contact sheet (colour / depth / instances)",
    "plan": "ground-truth floor plan of a simulated scene",
    "obstacles": "occupancy grid (unknown / free / occupied)",
    "navigable": "navigable cells for the robot radius",
    "color": "top-surface colour map",
    "height": "max height above the floor",
    "vlmap": "the VLMap's features as colours (first three principal components)",
    "cfmap": "the ConceptFusion map's features as colours (first three principal components)",
    "goals": "goals, landmarks and names on the colour map",
    "routes": "episodes' start poses and geodesic routes on the colour map",
}
# one picture per floor of a building
PER_FLOOR = ("obstacles", "navigable", "color", "height", "vlmap", "cfmap", "goals", "routes")
# pictures of a region (read tile by tile: only the tiles the region meets)
REGIONAL = ("obstacles", "navigable", "color", "height", "vlmap", "cfmap")
REGION_HELP = ("X0 Y0 X1 Y1: only this box, world metres (x east, y north; see the metre axes of a whole-floor "
               "render); reads only the stored tiles it meets")


def _region_given(region) -> bool:
    """Whether ``--region`` was given (typer hands an unset tuple option as None or as Nones)."""
    return region is not None and not all(v is None for v in region)


def _region_option(sc, region, floors: list[int], option: str = "--region"):
    """``region`` (four numbers or None) as a :class:`~pipeline.region.Region`, checked against the grid of each of
    ``floors`` (an error naming ``option`` when it is empty, inverted or misses a floor's grid)."""
    if not _region_given(region):
        return None
    from pipeline.region import parse_region, region_window

    box = parse_region(region, option)
    recon = sc.recon
    for k in floors:
        region_window(recon.floor(k).grid, box, option)
    return box


def _floor_option(sc, floor: int | None, option: str = "--floor") -> int | None:
    """``floor`` checked against the scene's floors (an error naming ``option`` and the floors there are)."""
    if floor is None:
        return None
    floors = sc.floors
    if floor >= len(floors):
        from pipeline.errors import InputDataError

        names = ", ".join(f"{k} ({f.name}, {f.floor_z_m:.2f} m)" for k, f in enumerate(floors))
        raise InputDataError(f"got {floor}: scene {sc.name!r} has {len(floors)} floor{'s' if len(floors) != 1 else ''}"
                             f": {names}", field=option, expected=f"a floor 0..{len(floors) - 1}")
    return floor


@app.command()
def render(
    scene: str = typer.Argument(..., help="scene name"),
    what: str = typer.Option("color", "--what", "-w", help=" | ".join(RENDERS)),
    out_png: Optional[Path] = typer.Option(None, "--out", "-o", help="PNG path (default DATA/artifacts/SCENE/renders/"
                                           "WHAT.png; a building's floors: WHAT_floor<id>.png)"),
    floor: Optional[int] = typer.Option(None, "--floor", "-f", min=0, help="the floor to draw (0 = the lowest); "
                                        f"default: every floor of a building, one PNG each ({', '.join(PER_FLOOR)})"),
    region: Optional[Tuple[float, float, float, float]] = typer.Option(
        None, "--region", metavar="X0 Y0 X1 Y1", help=f"{REGION_HELP} ({', '.join(REGIONAL)})"),
):
    """Draw an artifact as a north-up PNG with a scale bar.

    Examples: `zipon render sim_00 --what navigable` · `zipon render sim_00 --what routes -o routes.png` ·
    `zipon render house --what color --floor 1` · `zipon render house --what vlmap` ·
    `zipon render house --what routes` (routes_floor0.png, routes_floor1.png: each floor's legs, the stairs marked) ·
    `zipon render office --what vlmap --floor 0 --region 10 5 20 12` (a 10 m x 7 m part, full resolution)
    """
    from pipeline.errors import ConfigError

    if what not in RENDERS:
        raise ConfigError(f"--what {what!r}: choose one of {', '.join(RENDERS)}")
    if floor is not None and what not in (*PER_FLOOR, "plan"):
        raise ConfigError(f"--floor {floor}: --what {what} is drawn for the whole scene; --floor applies to "
                          f"{', '.join(PER_FLOOR)}, plan")
    wants_region = _region_given(region)
    if wants_region and what not in REGIONAL:
        raise ConfigError(f"--region: --what {what} is drawn whole; --region applies to {', '.join(REGIONAL)}")
    sc = open_scene(scene)
    art = sc.path  # on an object store: the artifact's published version, mirrored on first use
    if what in PER_FLOOR:
        floors = [_floor_option(sc, floor)] if floor is not None else list(range(len(sc.floors)))
        box = _region_option(sc, region, floors)
        for k in floors:
            target = _floor_target(out_png or sc.workspace.renders(scene) / f"{what}.png", k, len(sc.floors))
            if what in ("vlmap", "cfmap"):
                from pipeline.maps.render import render_map_pca

                render_map_pca(sc.existing(what), target, floor=k, region=box)
            elif what in ("goals", "routes"):
                from pipeline.goals.render import render_goals

                render_goals(art("recon"), art("goals"), art("routes") if what == "routes" else None, what, target,
                             floor=k)
            else:
                from pipeline.recon.render import render_recon

                render_recon(art("recon"), what, target, floor=k, region=box)
            out.print(str(target), soft_wrap=True)
        return
    target = Path(out_png) if out_png else sc.workspace.renders(scene) / f"{what}.png"
    if what == "frames":
        from pipeline.pictures import frames_contact_sheet

        frames_contact_sheet(art("frames"), target)
    elif what == "plan":  # the ground truth's floors (a building's: one picture each)
        from pipeline.errors import InputDataError
        from pipeline.frames import FrameStore
        from pipeline.sim.topdown import render_scene_png

        gt = FrameStore(art("frames")).ground_truth
        if gt is None:
            raise ConfigError(f"scene {scene}: --what plan needs ground truth (a simulated scene)")
        floors = gt.all_floors
        if floor is not None and floor >= len(floors):
            names = ", ".join(f"{f.id} ({f.name}, {f.floor_z:.2f} m)" for f in floors)
            raise InputDataError(f"got {floor}: scene {scene!r}'s ground truth has {len(floors)} floor"
                                 f"{'s' if len(floors) != 1 else ''}: {names}", field="--floor",
                                 expected=f"a floor 0..{len(floors) - 1}")
        for k in [floor] if floor is not None else range(len(floors)):
            path = _floor_target(target, k, len(floors))
            render_scene_png(gt, path, floor=k)
            out.print(str(path))
        return
    out.print(str(target))


def _floor_target(path: Path, floor: int, n_floors: int) -> Path:
    """``path`` itself for a single-floor scene, else ``NAME_floor<k>.png`` beside it."""
    path = Path(path)
    return path if n_floors == 1 else path.with_name(f"{path.stem}_floor{floor}{path.suffix or '.png'}")


def _object_keys(scene) -> dict[int, str]:
    """Ground-truth instance id -> object key (``chair_0``) from the scene's goals, when built."""
    if not scene.path("goals").exists():
        return {}
    return {o.instance_id: o.key for o in scene.goals.objects.values() if o.instance_id}


def no_candidates_reason(result, qp) -> str:
    """Why a query found no candidates, with the number that fell short of its threshold (``qp`` = params.query)."""
    import cv2
    import numpy as np

    heat = result.heatmap
    what = f"no candidates for {result.text!r}"
    if not np.isfinite(heat).any():
        return f"{what}: the map has no observed cells"
    if not result.wins.any():
        best = float(np.nanmax(heat))
        why = (f"best {best:.4f} < {qp.min_probability:g}" if best < qp.min_probability else
               f"best {best:.4f}, but in no such cell does the query outscore every background prompt")
        return (f"{what}: no cell beats the background prompts {list(result.background)} with probability "
                f">= {qp.min_probability:g} ({why})")
    n, lab = cv2.connectedComponents(result.wins.astype(np.uint8), connectivity=8)
    cells = np.bincount(lab.ravel(), minlength=n)[1:]
    score = np.bincount(lab.ravel(), weights=np.nan_to_num(heat).ravel(), minlength=n)[1:] / np.maximum(cells, 1)
    area = cells * result.grid.cell_size_m ** 2
    big = area >= qp.min_candidate_area_m2 - 1e-12
    if not big.any():
        return f"{what} (largest winning area {area.max():.3f} m² < min {qp.min_candidate_area_m2:g} m²)"
    return f"{what} (best score {score[big].max():.2f} < min {qp.min_candidate_score:g})"


@app.command()
def query(
    scene: str = typer.Argument(..., help="scene name"),
    text: str = typer.Argument(..., help='what to look for, e.g. "chair" or "the red couch"'),
    map_name: str = typer.Option("vlmap", "--map", help="vlmap | cfmap"),
    pose: Optional[str] = typer.Option(None, "--pose", help="x,y,yaw (metres, metres, degrees) to measure "
                                       "candidates from; yaw counter-clockwise from +x (east)"),
    as_json: bool = typer.Option(False, "--json", metavar="", help="print the result as JSON"),
    png: Optional[Path] = typer.Option(None, "--png", help="write the heatmap and candidates over the colour map "
                                       "(a building's floors side by side)"),
    levels: Optional[str] = typer.Option(None, "--levels", help="top: score each cell by its top-down feature; "
                                         "max: by its best height level (a cfmap's voxels: the chair under a "
                                         "table); default: params query.levels"),
    floor: Optional[int] = typer.Option(None, "--floor", min=0, help="look on this floor only (0 = the lowest; the "
                                        "--pose stands on it); default: every floor of a building"),
    pose_floor: Optional[int] = typer.Option(None, "--pose-floor", min=0, help="when every floor is searched: the "
                                             "floor the --pose stands on (default 0); its candidates come first"),
    region: Optional[Tuple[float, float, float, float]] = typer.Option(
        None, "--region", metavar="X0 Y0 X1 Y1", help=f"look in this box only: {REGION_HELP}; candidates' cells "
        "are then those of the box's grid"),
):
    """Query a semantic map with text: a similarity heatmap and object candidates (floor, distance, angle in
    degrees, score, and the ground-truth object key such as `chair_0` when the scene has one).

    Examples: `zipon query sim_00 chair --pose 2,3,90` · `zipon query sim_00 "green plant" --map cfmap --png plant.png`
    · `zipon query sim_00 chair --map cfmap --levels max` · `zipon query house bed --floor 1` ·
    `zipon query office chair --region 10 5 20 12`

    The map is scored one stored tile at a time (memory: a tile's features), and with --region only the tiles
    the box meets are read.
    """
    import math

    from pipeline.errors import ConfigError
    from pipeline.maps.query import parse_pose
    from zipon.cli.common import G

    if not text.strip():
        raise typer.BadParameter("the text to look for is empty; give words such as chair or 'the red couch'",
                                 param_hint="TEXT")
    if floor is not None and pose_floor is not None and pose_floor != floor:
        raise ConfigError(f"--floor {floor} --pose-floor {pose_floor}: with --floor the pose stands on that floor; "
                          "leave out --pose-floor or give the same floor")
    if levels is not None:  # checked like every params key (a ConfigError names query.levels and the choices)
        G.overrides = (*G.overrides, f"query.levels={levels}")
    sc = open_scene(scene)
    view = sc.map(map_name)
    if floor is not None:
        view = view.floor(_floor_option(sc, floor))
    _floor_option(sc, pose_floor, "--pose-floor")
    box = _region_option(sc, region, [floor] if floor is not None else list(range(len(sc.floors))))
    result = view.query(text, parse_pose(pose, degrees=True) if pose else None, pose_floor=pose_floor or 0,
                        region=box)
    building = len(sc.floors) > 1
    keys = _object_keys(sc)
    if png:
        from pipeline.maps.render import render_query

        render_query(result, png)
    if as_json:
        doc = result.to_json()
        for c in doc["candidates"]:
            c["angle_deg"] = None if c["angle_rad"] is None else round(math.degrees(c["angle_rad"]), 3)
            c["gt_object"] = keys.get(c["gt_instance"]) if c.get("gt_instance") else None
        if doc["pose"] is not None:
            doc["pose_deg"] = [*doc["pose"][:2], round(math.degrees(doc["pose"][2]), 3)]
        import json

        out.print_json(json.dumps(doc))
        return
    if not result.candidates:
        per_floor = getattr(result, "floors", None) or [result]
        for r in per_floor:
            where = f"{r.floor_name}: " if building else ""
            out.print(where + no_candidates_reason(r, sc.params.query))
        if png:
            out.print(str(png))
        return
    names = [f.name for f in sc.floors]
    table = Table(title=f"{scene} {map_name}: {text!r}" + (f" on {names[floor]}" if building and floor is not None
                                                          else ""))
    for col in ("candidate", *(("floor",) if building else ()), "distance (m)", "angle (deg)", "score", "area (m²)",
                "ground truth"):
        table.add_column(col, no_wrap=col == "floor")
    for c in result.candidates:
        angle = None if c.angle_rad is None else math.degrees(c.angle_rad)
        gt = "" if not c.gt_instance else keys.get(c.gt_instance, f"{c.gt_class} (instance {c.gt_instance})")
        where = (names[c.floor],) if building else ()
        table.add_row(str(c.obj_id), *where, _fmt(c.distance_m), _fmt(angle), _fmt(c.score), _fmt(c.area_m2), gt)
    out.print(table)
    if png:
        out.print(str(png))


def _fmt(v) -> str:
    return "" if v is None else f"{v:.2f}" if isinstance(v, float) else str(v)


