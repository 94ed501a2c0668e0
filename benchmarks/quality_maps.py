"""Semantic map quality against ground truth: perception-level segmentation figures next to published ones,
and the oracle's retrieval figures under controlled noise.

Segmentation (the figures the simulated perception models are calibrated on, ConceptFusion's protocol
as used in ConceptGraphs Table I): every map cell is labelled with the best-scoring text among the
scene's object classes and the background words (wall, floor, ceiling, other); over the ground-truth
object cells (``class_masks``; a cell the map never observed takes its nearest observed cell's label, as
the protocol labels each ground-truth point by its nearest map point; background cells are left out,
as Replica's wall / floor / ceiling are), per class accuracy = recall and IoU, then
``mAcc`` = mean accuracy over classes and ``F-mIoU`` = IoU weighted by each class's share of cells.

Modes (one JSON object per line, then a table):

- ``--workspace PARAMS``: every simulated scene built in that zipon workspace: its vlmap / cfmap as
  built (a building's: one row per floor, scored against that floor's ground truth), their segmentation figures, top-candidate hit rate and heatmap IoU
  (:func:`pipeline.maps.evaluate.evaluate_map`);
  with ``--rebuild ENCODER ...`` the maps are rebuilt in a temporary folder with each named encoder
  setting ('perception', 'oracle', ...) and ``--set`` overrides (a calibration sweep that leaves the
  workspace untouched);
- default fixture: the ray-cast box room with the oracle encoder, clean and with feature noise, class
  confusion and depth noise (``--no-fixture`` skips it).

Run: ``.venv/bin/python benchmarks/quality_maps.py --no-fixture --workspace W/params.yaml --rebuild perception oracle``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.ndimage import distance_transform_edt

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pipeline.paramsfile import load_params, parse_params  # noqa: E402
from pipeline.frames import FrameStore  # noqa: E402
from pipeline.maps.build import build_map  # noqa: E402
from pipeline.maps.config import MAP_CONFIGS  # noqa: E402
from pipeline.maps.evaluate import class_masks, evaluate_map, sample_poses  # noqa: E402
from pipeline.maps.query import MapQuery, gt_floor, open_query  # noqa: E402
from pipeline.encoder_params.perception import PUBLISHED  # noqa: E402
from pipeline.recon import Recon  # noqa: E402
from pipeline.scene_gt import GTScene  # noqa: E402
from pipeline.store import artifact_attrs  # noqa: E402

BACKGROUND_VOCAB = ("wall", "floor", "ceiling", "other")
#: the published row each map's simulated perception is set against
TARGET = {"simulated_lseg": "LSeg (privileged)", "simulated_cf": "ConceptFusion + SAM"}


def segmentation_metrics(mq: MapQuery, gt: GTScene) -> dict:
    """``{mAcc, F-mIoU, cells, per_class: {cls: {acc, iou, cells, confused_as}}}`` (percent) of map ``mq`` (see the
    docstring); ``confused_as``: the (up to 3) labels its cells took instead, percent of its cells."""
    grid = mq.grid
    masks = class_masks(gt, grid)
    classes = sorted(masks)
    label = np.full(grid.rows * grid.cols, -1, np.int64)
    for i, c in enumerate(classes):  # a cell in two classes' masks keeps the later class (rare: stacked objects)
        label[masks[c].ravel()] = i
    pred = np.full(grid.rows * grid.cols, -2, np.int64)
    names = classes + list(BACKGROUND_VOCAB)
    text = mq.text_features(names)
    pred[mq.map.cell] = mq.map.dot(text).argmax(axis=1)
    # a ground-truth cell the map never observed takes the label of the nearest observed cell (the protocol
    # labels each ground-truth point by its nearest map point)
    seen = (pred >= 0).reshape(grid.rows, grid.cols)
    if seen.any():
        _, (rr, cc) = distance_transform_edt(~seen, return_indices=True)
        pred = pred.reshape(grid.rows, grid.cols)[rr, cc].ravel()
    ev = label >= 0
    n_eval = int(ev.sum())
    per_class, accs, fiou = {}, [], 0.0
    for i, c in enumerate(classes):
        g, p = label == i, (pred == i) & ev
        tp, n = int((g & p).sum()), int(g.sum())
        union = int((g | p).sum())
        acc, iou = tp / max(n, 1), tp / max(union, 1)
        # what the class's cells were labelled as instead, most cells first (the per-class confusion)
        wrong = np.bincount(pred[g & ~p] + 2, minlength=len(names) + 2)[2:]
        confused = {names[j]: round(100 * int(wrong[j]) / max(n, 1), 1) for j in np.argsort(-wrong)[:3] if wrong[j]}
        per_class[c] = {"acc": round(100 * acc, 2), "iou": round(100 * iou, 2), "cells": n, "confused_as": confused}
        accs.append(acc)
        fiou += iou * n / max(n_eval, 1)
    return {"mAcc": round(100 * float(np.mean(accs)), 2) if accs else 0.0, "F-mIoU": round(100 * fiou, 2),
            "cells": n_eval, "per_class": per_class}


def evaluate(frames, recon, map_path, params, n_poses, floor: int = 0) -> dict:
    """Figures of floor ``floor``'s map against that floor's ground truth (:func:`pipeline.maps.query.gt_floor`)."""
    mq = open_query(map_path, params, recon_path=recon, frames_path=frames, floor=floor)
    gt = gt_floor(FrameStore(frames).ground_truth, mq.map.floor)
    poses = sample_poses(Recon(recon).floor(floor).navigable, mq.grid, n_poses, seed=1)
    out = segmentation_metrics(mq, gt)
    retrieval = evaluate_map(mq, gt, poses)
    return {"encoder": mq.map.encoder["name"], "kind": mq.map.encoder.get("kind", ""), "mAcc": out["mAcc"],
            "F-mIoU": out["F-mIoU"], "seg_cells": out["cells"], "hit_rate": retrieval["hit_rate"],
            "mean_iou": retrieval["mean_iou"], "per_class": out["per_class"]}


def workspace_scenes(path: Path, n_poses: int, rebuild: list[str], overrides: list[str],
                     only: list[str] | None = None, maps: tuple[str, ...] = ("vlmap", "cfmap")) -> list[dict]:
    """Figures of every simulated scene's maps in the workspace (as built, or rebuilt per encoder setting)."""
    from pipeline.paths import Workspace

    ws = Workspace.resolve(path)
    rows = []
    settings = rebuild or [None]
    with tempfile.TemporaryDirectory() as tmp:
        for setting in settings:
            params = load_params(path, ([f"encoders.simulated={setting}"] if setting else []) + list(overrides))
            for scene, src in params.scenes.items():
                if not src.simulated or (only and scene not in only):
                    continue
                frames, recon = ws.artifact("frames", scene), ws.artifact("recon", scene)
                if not frames.exists() or not recon.exists():
                    continue
                for kind in maps:
                    m = ws.artifact(kind, scene)
                    if setting is not None:
                        m = Path(tmp) / f"{setting}-{scene}-{kind}.zarr"
                        build_map(MAP_CONFIGS[kind].from_params(params, scene), frames, recon, m,
                                  artifact_attrs(kind, 1, kind, "quality"), runtime=params.run)
                    elif not m.exists():
                        continue
                    for floor in range(len(Recon(recon).floors)):  # a building: each floor against its own truth
                        fig = evaluate(frames, recon, m, params, n_poses, floor)
                        row = {"bench": "quality", "scene": scene, "map": kind, "floor": floor,
                               "setting": setting or "as built", "overrides": list(overrides), **fig}
                        print(json.dumps(row), flush=True)
                        rows.append(row)
    return rows


def print_table(rows: list[dict]) -> None:
    """Mean mAcc / F-mIoU per (map, encoder) over scenes (a building's floors each count), next to the published
    rows they are set against."""
    if not rows:
        return
    groups: dict[tuple[str, str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["map"], r["encoder"], r["setting"]), []).append(r)
    print(f"\n{'map':6} {'perception (encoder)':28} {'scenes':>6} {'mAcc':>6} {'F-mIoU':>7}   published (Replica)")
    for (kind, enc, _), rs in sorted(groups.items()):
        target = TARGET.get(enc)
        pub = PUBLISHED.get(target) if target else None
        ref = f"{target}: {pub['mAcc']:.1f} / {pub['F-mIoU']:.1f}" if pub else "(ground-truth diagnostic: no model)"
        print(f"{kind:6} {enc:28} {len({r['scene'] for r in rs}):6d} {np.mean([r['mAcc'] for r in rs]):6.1f} "
              f"{np.mean([r['F-mIoU'] for r in rs]):7.1f}   {ref}")
    print("published rows: " + "; ".join(f"{k} {v['mAcc']}/{v['F-mIoU']}" for k, v in PUBLISHED.items())
          + f" ({PUBLISHED['ConceptFusion']['source']})")


def fixture_settings(n_poses: int, n_frames: int, width: int, height: int):
    """The ray-cast box room with the oracle: clean, feature noise, class confusion, depth noise."""
    from pipeline.recon.build import reconstruct
    from tests.fixtures.recon_scenes import write_box_room_frames

    settings = [
        ("clean", 0.0, {}),
        ("noise_std=0.5", 0.0, {"noise_std": 0.5}),
        ("noise_std=1.0", 0.0, {"noise_std": 1.0}),
        ("confusion=0.1", 0.0, {"confusion": 0.1}),
        ("confusion=0.3", 0.0, {"confusion": 0.3}),
        ("depth_noise=0.01", 0.01, {}),
        ("depth_noise=0.03", 0.03, {}),
    ]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        built = {}
        for name, depth_noise, oracle in settings:
            params = parse_params({"scenes": {"box": {"source": "simulate"}}, "grid": {"rows": 100, "cols": 160},
                                   "encoders": {"simulated": "oracle", "oracle": oracle}})
            if depth_noise not in built:
                d = tmp / f"d{depth_noise}"
                frames, _ = write_box_room_frames(d / "frames.zarr", n_frames=n_frames, width=width, height=height,
                                                  depth_noise_m=depth_noise)
                reconstruct(frames, d / "recon.zarr", d / "recon_mesh.ply", d / "recon_points.ply",
                            params.reconstruct, params.grid)
                built[depth_noise] = d
            d = built[depth_noise]
            for kind in ("vlmap", "cfmap"):
                out = tmp / f"{name}-{kind}.zarr"
                build_map(MAP_CONFIGS[kind].from_params(params, "box"), d / "frames.zarr", d / "recon.zarr", out,
                          artifact_attrs(kind, 1, kind, "quality"), runtime=params.run)
                fig = evaluate(d / "frames.zarr", d / "recon.zarr", out, params, n_poses)
                fig.pop("per_class")
                print(json.dumps({"bench": "quality", "scene": "box_room", "setting": name, "map": kind,
                                  "frames": n_frames, "image": f"{width}x{height}", **fig}), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--poses", type=int, default=10)
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--workspace", type=Path, default=None, help="params.yaml of a built workspace")
    ap.add_argument("--rebuild", nargs="*", default=[], metavar="ENCODER",
                    help="rebuild the workspace's maps in a temporary folder with encoders.simulated=ENCODER "
                    "(e.g. perception oracle)")
    ap.add_argument("--scenes", nargs="*", default=None, help="only these workspace scenes")
    ap.add_argument("--maps", nargs="+", choices=("vlmap", "cfmap"), default=["vlmap", "cfmap"],
                    help="only these maps (a sweep of one model's settings rebuilds only its map)")
    ap.add_argument("--no-fixture", action="store_true")
    ap.add_argument("--set", action="append", default=[], help="params override for --workspace, e.g. "
                    "encoders.simulated_lseg.object_confusion=0.3 (repeatable)")
    a = ap.parse_args()
    if not a.no_fixture:
        fixture_settings(a.poses, a.frames, a.width, a.height)
    if a.workspace is not None:
        print_table(workspace_scenes(a.workspace, a.poses, a.rebuild, a.set, a.scenes, tuple(a.maps)))


if __name__ == "__main__":
    main()
