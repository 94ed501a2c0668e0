"""A large floor against an apartment, stage by stage: peak RSS and wall seconds per frame (one JSON object per line).

    .venv/bin/python benchmarks/bench_large_floor.py [--workdir DIR] [--size 100 60] [--office-frames 1500]
        [--apartment-frames 300] [--width 320] [--height 240] [--report-only]

Builds, in ``DIR/office`` and ``DIR/apartment``, a simulated office (``building: {kind: office, size_m: SIZE}``)
and an apartment at the same image size, every stage in its own process (``zipon -q stage STAGE --scene S``, with
``run: {scheduler: sync, workers: 1}``), so each manifest's ``timing.peak_rss_mb`` is that stage's alone. Then
prints one row per stage: both scenes' peak RSS and seconds per frame and the office's per-frame time over the
apartment's (the issue asks every stage <= 3 GB and the per-frame time within 20 % of an apartment's), and a
row for reconstruct's tiling (tiles fused, the most TSDF blocks one tile held, of how many). ``--report-only``
reads the manifests of an earlier build in ``DIR``. A stage that fails is reported with its exit status and the
last lines it printed, and the later stages of that scene are not run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from _common import ROOT, emit

STAGES = ("simulate", "ingest", "reconstruct", "vlmap", "cfmap", "goals", "routes")


def write_params(folder: Path, scene: dict, frames: int, width: int, height: int) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "params.yaml").write_text(json.dumps({
        "scenes": {"s": scene}, "simulate": {"frames": frames, "width": width, "height": height},
        "run": {"scheduler": "sync", "workers": 1}}) + "\n")


def build(folder: Path) -> dict[str, str]:
    """Run every stage of scene ``s`` in ``folder``, one process each; returns the failures (stage -> output tail)."""
    zipon = str(Path(sys.executable).with_name("zipon"))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "HF_HUB_OFFLINE": "1"}
    for stage in STAGES:
        done = subprocess.run([zipon, "-q", "stage", stage, "--scene", "s"], cwd=folder, env=env,
                              capture_output=True, text=True)
        if done.returncode != 0:
            return {stage: f"exit {done.returncode}: " + (done.stdout + done.stderr)[-600:]}
    return {}


def stage_figures(folder: Path, scene: str = "s") -> dict[str, dict]:
    """Per stage: peak RSS (MB), wall seconds and the scene's frame count, from the manifests of ``scene``."""
    frames = None
    out = {}
    for stage in STAGES:
        path = folder / "manifests" / scene / f"{stage}.json"
        if not path.exists():
            continue
        manifest = json.loads(path.read_text())
        if stage == "ingest":
            frames = manifest["summary"].get("matched_frames")
        out[stage] = {"peak_rss_mb": manifest["timing"]["peak_rss_mb"], "seconds": manifest["timing"]["seconds"],
                      "summary": manifest["summary"]}
    for figures in out.values():
        figures["frames"] = frames
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", type=Path, default=None, help="where both scenes are built (default: a temp folder)")
    ap.add_argument("--size", type=float, nargs=2, default=(100.0, 60.0), help="the office's x, y extent, metres")
    ap.add_argument("--office-frames", type=int, default=1500)
    ap.add_argument("--apartment-frames", type=int, default=300)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--report-only", action="store_true", help="read the manifests of an earlier build in --workdir")
    ap.add_argument("--office", default=None, metavar="DIR:SCENE", help="with --report-only: the office's project "
                    "folder and scene name, when not --workdir/office and s")
    ap.add_argument("--apartment", default=None, metavar="DIR:SCENE", help="the same for the apartment")
    args = ap.parse_args()
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="bench_large_floor_"))
    scenes = {"office": ({"source": "simulate", "building": {"kind": "office", "size_m": list(args.size)}},
                         args.office_frames),
              "apartment": ({"source": "simulate"}, args.apartment_frames)}
    failed = {}
    if not args.report_only:
        for name, (scene, frames) in scenes.items():
            write_params(workdir / name, scene, frames, args.width, args.height)
            failed[name] = build(workdir / name)
    def where(name: str, given: str | None) -> tuple[Path, str]:
        if given is None:
            return workdir / name, "s"
        folder, scene = given.rsplit(":", 1)
        return Path(folder), scene

    office = stage_figures(*where("office", args.office))
    apartment = stage_figures(*where("apartment", args.apartment))
    for stage in STAGES:
        o, a = office.get(stage), apartment.get(stage)
        row = {"run": "large_floor", "stage": stage, "size_m": list(args.size), "width": args.width,
               "height": args.height}
        for name, fig in (("office", o), ("apartment", a)):
            if fig is not None:
                row[f"{name}_frames"] = fig["frames"]
                row[f"{name}_peak_rss_mb"] = fig["peak_rss_mb"]
                row[f"{name}_s_per_frame"] = round(fig["seconds"] / max(fig["frames"] or 1, 1), 4)
        if o is not None and a is not None:
            row["per_frame_ratio"] = round(row["office_s_per_frame"] / max(row["apartment_s_per_frame"], 1e-9), 3)
            row["rss_ok"] = o["peak_rss_mb"] <= 3072
        for name in scenes:
            if stage in failed.get(name, {}):
                row[f"{name}_failed"] = failed[name][stage]
        emit(**row)
    if "reconstruct" in office:
        s = office["reconstruct"]["summary"]
        emit(run="large_floor_recon", grid_shape=s.get("grid_shape"), points=s.get("points"),
             mesh_vertices=s.get("mesh_vertices"), tsdf_blocks=s.get("tsdf_blocks"), tiles=s.get("tiles"),
             seconds_fuse=s.get("seconds_fuse"), seconds_extract=s.get("seconds_extract"),
             seconds_grids=s.get("seconds_grids"))


if __name__ == "__main__":
    main()
