"""Semantic map quality against ground truth with the oracle encoder, clean and with noise.

For every ground-truth class: does the first candidate lie on an object of that class (pose-free
and from ``--poses`` navigable poses), and the IoU of the heatmap thresholded at 0.5 with the
class's footprints (:func:`pipeline.maps.evaluate.evaluate_map`). Prints one JSON object per line.

- default: the ray-cast box-room fixture, rebuilt per setting: clean; oracle feature noise
  (``noise_std``); oracle class confusion (``confusion``); depth noise (``depth_noise_m`` at 1 m,
  growing with depth^2, reconstruction rebuilt from the noisy depth).
- ``--workspace DIR``: also evaluate the vlmap/cfmap of every simulated scene already built in a
  zipon workspace (``zipon run`` with ``encoders.simulated=oracle``).

Run: ``.venv/bin/python benchmarks/quality_maps.py [--workspace /path/with/params.yaml]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pipeline.config import load_params, parse_params  # noqa: E402
from pipeline.frames import FrameStore  # noqa: E402
from pipeline.maps.build import build_map  # noqa: E402
from pipeline.maps.evaluate import evaluate_map, sample_poses  # noqa: E402
from pipeline.maps.query import open_query  # noqa: E402
from pipeline.recon import Recon  # noqa: E402
from pipeline.scene_gt import GTScene  # noqa: E402
from pipeline.store import artifact_attrs  # noqa: E402


def with_levels(mq):
    """``mq`` scoring each cell by its best voxel level (:class:`pipeline.maps.levels.LevelScorer`).

    A measurement shim until ``MapQuery.query`` calls ``LevelScorer.cell_scores`` itself (see
    pipeline/maps/levels.py): it replaces the top-down ``(s, bg_max, bg_lse)`` through the two
    private steps of the current query.
    """
    import types

    from pipeline.maps.levels import LevelScorer

    scorer = LevelScorer(mq.map)
    cls = type(mq)

    def background_for(self, q):
        bg_max, bg_lse, keep = cls._background_for(self, q)
        s = cls._scores(self, q, bg_max, bg_lse)
        bg = self._bg_feats[keep] if keep else None
        self._level_s, bg_max, bg_lse = scorer.cell_scores(q, bg, self.temperature, s, bg_max, bg_lse)
        return bg_max, bg_lse, keep

    mq._background_for = types.MethodType(background_for, mq)
    mq._scores = types.MethodType(lambda self, q, bg_max, bg_lse: self._level_s, mq)
    return mq


def evaluate(kind, frames, recon, map_path, params, n_poses, levels: bool = False):
    gt = GTScene.model_validate(FrameStore(frames).ground_truth)
    mq = open_query(map_path, params, recon_path=recon, frames_path=frames)
    if levels:
        from pipeline.maps.query import MapQuery

        mq = with_levels(MapQuery(mq.map, mq.encoder, mq.params, navigable=Recon(recon).navigable, gt=gt))
    poses = sample_poses(Recon(recon).navigable, mq.grid, n_poses, seed=1)
    return evaluate_map(mq, gt, poses)


def fixture_settings(n_poses: int, n_frames: int, width: int, height: int):
    from stages.reconstruct import reconstruct
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
                build_map(kind, d / "frames.zarr", d / "recon.zarr", out, params,
                          artifact_attrs(kind, 1, kind, "quality"), simulated=True)
                fig = evaluate(kind, d / "frames.zarr", d / "recon.zarr", out, params, n_poses)
                print(json.dumps({"bench": "quality", "scene": "box_room", "setting": name, "map": kind,
                                  "frames": n_frames, "image": f"{width}x{height}", **fig}), flush=True)


def workspace_scenes(path: Path, n_poses: int, overrides: list[str] = ()):
    from pipeline.paths import Workspace

    params = load_params(path, ["encoders.simulated=oracle", *overrides])
    ws = Workspace.resolve(path)
    for scene, src in params.scenes.items():
        if not src.simulated:
            continue
        frames, recon = ws.artifact("frames", scene), ws.artifact("recon", scene)
        for kind in ("vlmap", "cfmap"):
            m = ws.artifact(kind, scene)
            if not m.exists():
                continue
            for levels in (False, True) if kind == "cfmap" else (False,):
                fig = evaluate(kind, frames, recon, m, params, n_poses, levels)
                print(json.dumps({"bench": "quality", "scene": scene, "setting": "workspace (clean oracle)",
                                  "map": kind, "query": "max over levels" if levels else "top-down",
                                  "overrides": list(overrides), **fig}), flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--poses", type=int, default=10)
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--workspace", type=Path, default=None, help="params.yaml of a built workspace")
    ap.add_argument("--no-fixture", action="store_true")
    ap.add_argument("--set", action="append", default=[], help="params override for --workspace, e.g. "
                    "maps.min_candidate_score=0.7 (repeatable)")
    a = ap.parse_args()
    if not a.no_fixture:
        fixture_settings(a.poses, a.frames, a.width, a.height)
    if a.workspace is not None:
        workspace_scenes(a.workspace, a.poses, a.set)


if __name__ == "__main__":
    main()
