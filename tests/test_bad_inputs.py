"""The bad-input corpus: broken logs, params, goal files, tampered stores, read-only and full disks.

Every case runs the real ``zipon`` command (``zipon.cli.main``) against a copy of the tiny scene the
smoke test builds, and asserts the exact exit code, a message naming the file / field / topic and what
was expected, that no traceback reaches the user, and that nothing on disk changed (every file under
the workspace byte-identical, nothing added or removed).
"""

from __future__ import annotations

import errno
import io
import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import yaml

from zipon.cli import main
from tests.fixtures.raw_datasets import RawLog, make_recording, write_mcap, write_raw_log, write_tum

SCENE = "tiny"


# ----------------------------------------------------------------------------- workspace copies

@dataclass
class Ctx:
    """What a case works with: a copy of the built workspace and a scratch folder outside it."""

    root: Path  # params.yaml, data/, manifests/
    scratch: Path
    goals_doc: dict
    fault: tuple[int, Path] | None = None  # (errno, folder): writes under folder fail with that errno

    @property
    def data(self) -> Path:
        return self.root / "data"

    @property
    def art(self) -> Path:
        return self.data / "artifacts" / SCENE

    def argv(self, *args: str, params: Path | None = None) -> list[str]:
        return ["-q", "-p", str(params or self.root / "params.yaml"), "--data-dir", str(self.data),
                "--manifests-dir", str(self.root / "manifests"), *args]

    def file(self, name: str, content: str | bytes) -> Path:
        path = self.scratch / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
        return path


def tree_state(root: Path) -> dict[str, tuple]:
    """Every file under ``root`` -> (size, mtime ns, inode), every folder -> present: any write,
    replacement, addition or removal shows. Left out: lock files (they only say who ran last) and the
    runner's own ``.tmp`` folders (files left inside them still show)."""
    out = {}
    for path in sorted(root.rglob("*")):
        if path.name.endswith(".lock") or path.name == ".tmp":
            continue
        st = path.lstat()
        out[path.relative_to(root).as_posix()] = ("dir",) if path.is_dir() else (st.st_size, st.st_mtime_ns, st.st_ino)
    return out


def copy_workspace(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, symlinks=True)
    return dst


@pytest.fixture(scope="module")
def pristine(built_scene, tmp_path_factory):
    """A copy of the smoke test's built workspace, its state, and its exported goals document.

    Cases that only read it share it; cases that tamper with it get their own copy."""
    ws, _ = built_scene
    root = tmp_path_factory.mktemp("bad_inputs") / "ws"
    root.mkdir()
    shutil.copy(ws.params_path, root / "params.yaml")
    shutil.copytree(ws.data_dir, root / "data", ignore=shutil.ignore_patterns("renders", ".tmp", "*.lock"))
    shutil.copytree(ws.manifests_dir, root / "manifests")
    doc = tmp_path_factory.mktemp("goals") / "goals.yaml"
    assert main(["-q", "-p", str(root / "params.yaml"), "goals", "export", SCENE, "-o", str(doc)]) == 0
    return root, yaml.safe_load(doc.read_text()), tree_state(root)


@pytest.fixture
def scratch(tmp_path):
    return tmp_path


# ----------------------------------------------------------------------------- fault injection

def _fail_writes_under(monkeypatch, code: int, folder: Path) -> None:
    """Make every write under ``folder`` fail as a full (ENOSPC) or read-only (EROFS) disk would.

    Patches the os-level entry points Python file writes go through (``open`` in a writing mode,
    ``mkdir``, ``rename``/``replace``/``link``, ``unlink``/``rmdir``), so zarr, pathlib, shutil and the
    runner all meet the same ``OSError(code, strerror, filename)`` the kernel would raise.
    """
    folder = str(folder)

    def under(path) -> bool:
        try:
            return os.path.abspath(os.fsdecode(path)).startswith(folder)
        except TypeError:  # a file descriptor
            return False

    def deny(path):
        raise OSError(code, os.strerror(code), os.fsdecode(path))

    real_open = io.open

    def fake_open(file, mode="r", *args, **kwargs):
        if any(c in mode for c in "wax+") and under(file):
            deny(file)
        return real_open(file, mode, *args, **kwargs)

    monkeypatch.setattr(io, "open", fake_open)
    monkeypatch.setattr("builtins.open", fake_open)
    for name in ("mkdir", "unlink", "remove", "rmdir"):
        real = getattr(os, name)

        def one(path, *args, _real=real, **kwargs):
            if under(path):
                deny(path)
            return _real(path, *args, **kwargs)

        monkeypatch.setattr(os, name, one)
    for name in ("rename", "replace", "link"):
        real = getattr(os, name)

        def two(src, dst, *args, _real=real, **kwargs):
            if under(src) or under(dst):
                deny(dst)
            return _real(src, dst, *args, **kwargs)

        monkeypatch.setattr(os, name, two)
    real_os_open = os.open

    def os_open(path, flags, *args, **kwargs):
        if flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT) and under(path):
            deny(path)
        return real_os_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", os_open)


# ----------------------------------------------------------------------------- the corpus

@dataclass
class Case:
    make: Callable[[Ctx], list[str]]  # writes the bad input (or tampers with the copy); returns argv
    code: int
    says: tuple[str, ...]  # fragments of the message; "{root}" / "{scratch}" are filled in
    tampers: bool = False  # make() changes the workspace: the case gets its own copy
    xfail: str = ""
    never: tuple[str, ...] = ()  # fragments the message must not hold (advice that does not apply, a temp file)


CASES: dict[str, Case] = {}


def case(name: str, code: int, *says: str, tampers: bool = False, xfail: str = "", never: tuple[str, ...] = ()):
    def register(make):
        CASES[name] = Case(make, code, says, tampers, xfail, never)
        return make

    return register


# --- raw logs (zipon ingest LOG --scene tiny --force: the built frames must survive every failure)

REC = make_recording(n=8, h=24, w=32)


def ingest(c: Ctx, path: Path, *options: str, overrides: tuple[str, ...] = ()) -> list[str]:
    return c.argv(*overrides, "ingest", str(path), "--scene", SCENE, "--force", *options)


def good_log(c: Ctx, name: str = "good.mcap") -> Path:
    return write_mcap(c.scratch / name, REC)


@case("mcap-truncated", 1, "{scratch}/cut.mcap", "truncated or corrupt", "mcap recover")
def _(c):
    data = good_log(c).read_bytes()
    return ingest(c, c.file("cut.mcap", data[: len(data) // 2]))


@case("mcap-empty", 1, "{scratch}/empty.mcap", "not a readable MCAP log")
def _(c):
    return ingest(c, c.file("empty.mcap", b""))


@case("mcap-garbage", 1, "{scratch}/junk.mcap", "not a readable MCAP log")
def _(c):
    return ingest(c, c.file("junk.mcap", np.random.default_rng(0).bytes(4096)))


@case("mcap-corrupt-chunk", 1, "{scratch}/flipped.mcap", "MCAP")
def _(c):
    data = bytearray(good_log(c).read_bytes())
    mid = len(data) // 2
    data[mid : mid + 64] = bytes(64)  # zeroes inside a compressed chunk: its CRC no longer matches
    return ingest(c, c.file("flipped.mcap", bytes(data)))


@case("mcap-no-depth-topic", 1, "{scratch}/nodepth.mcap", "ingest.topics.depth", "/cam/color/image_raw")
def _(c):
    return ingest(c, write_raw_log(c.scratch / "nodepth.mcap", REC, skip=("depth",)))


@case("mcap-no-pose", 1, "{scratch}/nopose.mcap", "ingest.topics.pose")
def _(c):
    return ingest(c, write_raw_log(c.scratch / "nopose.mcap", REC, skip=("pose",)))


@case("mcap-no-colour", 1, "{scratch}/norgb.mcap", "ingest.topics.rgb")
def _(c):
    return ingest(c, write_raw_log(c.scratch / "norgb.mcap", REC, skip=("rgb",)))


@case("mcap-topic-not-in-log", 1, "{scratch}/good.mcap", "/nope", "not in the log")
def _(c):
    return ingest(c, good_log(c), overrides=("-S", "ingest.topics.rgb=/nope"))


@case("mcap-topic-wrong-type", 1, "{scratch}/raw.mcap", "/cam/pose", "PoseStamped")
def _(c):
    return ingest(c, write_raw_log(c.scratch / "raw.mcap", REC), overrides=("-S", "ingest.topics.depth=/cam/pose"))


@case("mcap-colour-encoding", 1, "{scratch}/yuv.mcap", "/cam/color/image_raw", "yuv422", "encoding")
def _(c):
    return ingest(c, write_raw_log(c.scratch / "yuv.mcap", REC, rgb_encoding="yuv422"))


@case("mcap-depth-encoding", 1, "{scratch}/d8.mcap", "/cam/depth/image_raw", "depth image is uint8",
      "expected uint16 or float32")
def _(c):
    return ingest(c, write_raw_log(c.scratch / "d8.mcap", REC, depth_encoding="mono8"))


@case("mcap-camera-info-size", 1, "{scratch}/info.mcap", "32x24")
def _(c):
    from pipeline.geometry import Intrinsics

    return ingest(c, write_raw_log(c.scratch / "info.mcap", REC, info_intr=Intrinsics.from_hfov(64, 48, 90.0)))


@case("mcap-depth-never-matches", 1, "{scratch}/late.mcap", "depth")
def _(c):
    return ingest(c, write_raw_log(c.scratch / "late.mcap", REC, depth_stamps=REC.stamps + 5 * 10**9))


def _log_with_pose(c: Ctx, name: str, bad_frame: int, q) -> Path:
    log = RawLog(c.scratch / name)
    for i in range(len(REC)):
        s = int(REC.stamps[i])
        log.image("/cam/color/image_raw", s, REC.rgb[i], "rgb8")
        log.image("/cam/depth/image_raw", s, REC.depth_mm[i], "16UC1")
        log.camera_info("/cam/color/camera_info", s, REC.intrinsics)
        log.pose("/cam/pose", s, REC.poses[i], q_override=q if i == bad_frame else None)
    return log.close()


@case("mcap-nan-pose", 1, "{scratch}/nan.mcap", "/cam/pose", "finite")
def _(c):
    return ingest(c, _log_with_pose(c, "nan.mcap", 3, [np.nan, 0.0, 0.0, 1.0]))


@case("mcap-non-rigid-pose", 1, "{scratch}/scaled.mcap", "/cam/pose", "not a rotation")
def _(c):
    return ingest(c, _log_with_pose(c, "scaled.mcap", 3, [0.0, 0.0, 0.0, 2.0]))


@case("ingest-missing-path", 1, "{scratch}/absent.mcap", "not found")
def _(c):
    return ingest(c, c.scratch / "absent.mcap")


@case("ingest-unknown-format", 1, "scenes.tiny.format", "'mcap'")
def _(c):
    return ingest(c, good_log(c), "--format", "bogus")


@case("tum-nan-pose", 1, "groundtruth.txt", "finite")
def _(c):
    root = write_tum(c.scratch, REC)
    lines = (root / "groundtruth.txt").read_text().splitlines()
    parts = lines[5].split()
    lines[5] = " ".join(parts[:4] + ["nan"] + parts[5:])
    (root / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    return ingest(c, root, "--format", "tum")


@case("tum-bad-timestamp", 1, "rgb.txt", "not a number")
def _(c):
    root = write_tum(c.scratch, REC)
    lines = (root / "rgb.txt").read_text().splitlines()
    lines[3] = "12:30 " + lines[3].split()[1]
    (root / "rgb.txt").write_text("\n".join(lines) + "\n")
    return ingest(c, root)


@case("tum-missing-depth-list", 1, "depth.txt")
def _(c):
    root = write_tum(c.scratch, REC)
    (root / "depth.txt").unlink()
    return ingest(c, root, "--format", "tum")


# --- params files (the lead's strict config; -p FILE with the built data and manifests)

def with_params(c: Ctx, text: str | bytes, *cmd: str) -> list[str]:
    return c.argv(*(cmd or ("params",)), params=c.file("params.yaml", text))


BASE = "scenes:\n  tiny: {source: simulate}\n"


@case("params-bool-for-int", 1, "simulate.frames", "boolean")
def _(c):
    return with_params(c, BASE + "simulate: {frames: true}\n")


@case("params-frames-too-few", 1, "simulate.frames")
def _(c):
    return with_params(c, BASE + "simulate: {frames: 1}\n")


@case("params-nan", 1, "reconstruct.voxel_size_m", "finite")
def _(c):
    return with_params(c, BASE + "reconstruct: {voxel_size_m: .nan}\n")


@case("params-floors-too-close", 1, "reconstruct.floors", "floor 1 (floor_z_m 1.0) must lie at least 1.8 m above")
def _(c):
    return with_params(c, BASE + "reconstruct: {floors: [{floor_z_m: 0.0}, {floor_z_m: 1.0}]}\n")


@case("floors-pinned-without-surface", 1, "reconstruct.floors[1].floor_z_m: no floor at 3.00 m",
      "upward-facing surface points")
def _(c):
    params = yaml.safe_load((c.root / "params.yaml").read_text())
    params.setdefault("reconstruct", {})["floors"] = [{"floor_z_m": 0.0}, {"floor_z_m": 3.0}]
    return with_params(c, yaml.safe_dump(params), "run", "--stage", "reconstruct", "--force", "--scheduler", "sync")


@case("params-unknown-scheduler", 1, "run.scheduler", "fastest")
def _(c):
    return with_params(c, BASE + "run: {scheduler: fastest}\n")


@case("params-unknown-key", 1, "reconstruct.voxel_sise_m")
def _(c):
    return with_params(c, BASE + "reconstruct: {voxel_sise_m: 0.05}\n")


@case("params-string-for-number", 1, "reconstruct.voxel_size_m", "string")
def _(c):
    return with_params(c, BASE + "reconstruct: {voxel_size_m: '0.05'}\n")


@case("params-not-yaml", 1, "{scratch}/params.yaml", "YAML")
def _(c):
    return with_params(c, BASE + "simulate: {frames: [1, 2\n")


@case("params-not-utf8", 1, "{scratch}/params.yaml", "UTF-8")
def _(c):
    return with_params(c, BASE.encode() + b"# caf\xe9\n")


@case("params-not-a-mapping", 1, "{scratch}/params.yaml", "mapping")
def _(c):
    return with_params(c, "- tiny\n- other\n")


@case("params-missing-file", 1, "{scratch}/nowhere.yaml", "not found")
def _(c):
    return c.argv("params", params=c.scratch / "nowhere.yaml")


@case("params-p-is-a-folder", 1, "{scratch}/folder", "is a folder, not a file", never=("not found",))
def _(c):
    (c.scratch / "folder").mkdir()
    return c.argv("params", params=c.scratch / "folder")


@case("params-p-is-a-fifo", 1, "{scratch}/pipe", "is a FIFO (named pipe), not a file", never=("not found",))
def _(c):
    os.mkfifo(c.scratch / "pipe")  # opened for reading, it would block until a writer came
    return c.argv("params", params=c.scratch / "pipe")


@case("params-p-is-dev-zero", 1, "/dev/zero", "is a character device, not a file", never=("not found",))
def _(c):
    return c.argv("params", params=Path("/dev/zero"))


@case("params-5000-digit-integer", 1, "override grid.rows", "holds an integer of 5000 digits")
def _(c):
    return c.argv("-S", "grid.rows=" + "9" * 5000, "status")


@case("params-huge-integer-in-file", 1, "{scratch}/p.yaml", "simulate.seed: an integer of 40 digits is out of range")
def _(c):
    return c.argv("params", params=c.file("p.yaml", BASE + "simulate: {seed: " + "9" * 40 + "}\n"))


@case("params-voxel-rounds-to-zero", 1, "reconstruct.voxel_size_m: 1e-09 m is below 0.001 m")
def _(c):
    return c.argv("-S", "reconstruct.voxel_size_m=0.000000001", "run", "-s", SCENE, "--stage", "reconstruct", "--force")


@case("params-grid-of-1e7-rows", 1, "grid.rows: 10,000,000 cells of 0.05 m span 500,000 m")
def _(c):
    return c.argv("-S", "grid.rows=10000000", "run", "-s", SCENE, "--stage", "reconstruct", "--force")


@case("params-grid-beyond-memory", 1, "grid.rows x grid.cols: 150,000 x 150,000 cells need about", "memory")
def _(c):
    return c.argv("-S", "grid.rows=150000", "-S", "grid.cols=150000", "-S", "grid.cell_size_m=0.05", "status")


@case("params-simulated-width-1e6", 1, "simulate.width: 1,000,000 pixels (expected at most 16,384)")
def _(c):
    return c.argv("-S", "simulate.width=1000000", "run", "-s", SCENE, "--stage", "simulate", "--force")


@case("data-dir-s3-without-bucket", 1, "--data-dir s3://: no bucket named (expected s3://BUCKET",
      never=("Traceback",))
def _(c):
    return ["-q", "-p", str(c.root / "params.yaml"), "--data-dir", "s3://", "status"]


@case("params-bad-override", 1, "simulate.frames")
def _(c):
    return c.argv("-S", "simulate.frames=many", "params")


@case("params-building-not-simulated", 1, "scenes.tiny", "'building' describes a simulated scene",
      "source: simulate")
def _(c):
    return with_params(c, "scenes:\n  tiny: {source: a.mcap, building: {kind: house}}\n")


@case("params-building-stories", 1, "scenes.tiny.building.stories", "less than or equal to 3")
def _(c):
    return with_params(c, "scenes:\n  tiny: {source: simulate, building: {kind: house, stories: 4}}\n")


@case("params-building-kind", 1, "scenes.tiny.building.kind", "'apartment', 'house' or 'office'")
def _(c):
    return with_params(c, "scenes:\n  tiny: {source: simulate, building: {kind: castle}}\n")


@case("params-building-office-size", 1, "scenes.tiny.building", "size_m must be two extents of 10-200 m")
def _(c):
    return with_params(c, "scenes:\n  tiny: {source: simulate, building: {kind: office, size_m: [5, 40]}}\n")


@case("params-source-missing", 1, "{scratch}/gone.mcap", "scenes.tiny")
def _(c):
    return with_params(c, f"scenes:\n  tiny: {{source: {c.scratch}/gone.mcap}}\n", "run", "--stage", "ingest")


# --- goal files (zipon goals import tiny FILE: params.yaml and the built goals must not change)

def goals_import(c: Ctx, doc: dict | bytes, name: str = "edit.yaml") -> list[str]:
    text = doc if isinstance(doc, bytes) else yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)
    return c.argv("goals", "import", SCENE, str(c.file(name, text)))


def first_object(c: Ctx) -> str:
    return next(iter(c.goals_doc["objects"]))


@case("goals-not-utf8", 1, "{scratch}/edit.yaml", "UTF-8")
def _(c):
    text = yaml.safe_dump(c.goals_doc, sort_keys=False, allow_unicode=True).encode("utf-8")
    return goals_import(c, text.replace(b"format: zipon-goals", b"format: zipon-goals # \xff\xfe"))


@case("goals-nan-position", 1, "{scratch}/edit.yaml", "position_xy", "finite")
def _(c):
    c.goals_doc["objects"][first_object(c)]["position_xy"] = [float("nan"), 1.0]
    return goals_import(c, c.goals_doc)


@case("goals-inf-position-json", 1, "{scratch}/edit.json", "position_xy", "finite")
def _(c):
    c.goals_doc["objects"][first_object(c)]["position_xy"] = [1.0, float("inf")]
    return c.argv("goals", "import", SCENE, str(c.file("edit.json", json.dumps(c.goals_doc))))


@case("goals-bool-for-int", 1, "{scratch}/edit.yaml", "format_version", "boolean")
def _(c):
    c.goals_doc["format_version"] = True
    return goals_import(c, c.goals_doc)


@case("goals-bool-for-number", 1, "{scratch}/edit.yaml", "position_xy", "boolean")
def _(c):
    c.goals_doc["objects"][first_object(c)]["position_xy"] = [True, 1.0]
    return goals_import(c, c.goals_doc)


@case("goals-unknown-object", 1, "{scratch}/edit.yaml", "goals[0].objects[1]", "sofa_99")
def _(c):
    c.goals_doc["goals"][0]["objects"].append("sofa_99")
    return goals_import(c, c.goals_doc)


@case("goals-object-not-in-scene", 1, "{scratch}/edit.yaml", "objects.sofa_99", "does not exist")
def _(c):
    c.goals_doc["objects"]["sofa_99"] = {"class": "sofa", "identity": "a sofa", "position_xy": [1.0, 1.0]}
    return goals_import(c, c.goals_doc)


@case("goals-duplicate-names", 1, "{scratch}/edit.yaml", "not unique")
def _(c):
    c.goals_doc["goals"][1]["name"] = c.goals_doc["goals"][0]["name"].upper()
    return goals_import(c, c.goals_doc)


@case("goals-wrong-scene", 1, "{scratch}/edit.yaml", "scene", "'elsewhere'")
def _(c):
    c.goals_doc["scene"] = "elsewhere"
    return goals_import(c, c.goals_doc)


@case("goals-unknown-field", 1, "{scratch}/edit.yaml", "goals[0].colour")
def _(c):
    c.goals_doc["goals"][0]["colour"] = "red"
    return goals_import(c, c.goals_doc)


@case("goals-bad-type", 1, "{scratch}/edit.yaml", "goals[0].type")
def _(c):
    c.goals_doc["goals"][0]["type"] = "huge"
    return goals_import(c, c.goals_doc)


@case("goals-not-yaml", 1, "{scratch}/edit.yaml", "not valid YAML")
def _(c):
    return goals_import(c, b"format: zipon-goals\ngoals: [\n")


@case("goals-empty-file", 1, "{scratch}/edit.yaml", "expected a mapping")
def _(c):
    return goals_import(c, b"")


@case("goals-missing-file", 1, "{scratch}/absent.yaml", "not found")
def _(c):
    return c.argv("goals", "import", SCENE, str(c.scratch / "absent.yaml"))


def objects_file(c: Ctx, first: dict) -> list[str]:
    """An objects file (goals.objects: file) whose first object is ``first`` over a valid one."""
    obj = {"key": "chair_0", "cls": "chair", "instance_id": 1, "footprint": [[0, 0], [1, 0], [1, 1]],
           "mass_center": [0.7, 0.3], **first}
    path = c.file("objects.yaml", yaml.safe_dump({"rooms": [], "objects": [obj]}))
    return c.argv("-S", "goals.objects=file", "-S", f"goals.objects_files.{SCENE}={path}",
                  "run", "--stage", "goals", "--force", "--scheduler", "sync")


@case("objects-file-bool-for-int", 1, "{scratch}/objects.yaml", "objects[0].instance_id", "boolean")
def _(c):
    return objects_file(c, {"instance_id": True})


@case("objects-file-nan-footprint", 1, "{scratch}/objects.yaml", "objects[0].footprint[1][0]", "finite")
def _(c):
    return objects_file(c, {"footprint": [[0, 0], [float("nan"), 0], [1, 1]]})


# --- tampered stores (zipon verify / status --verify: every artifact reported, corrupt ones included)

def chunk_of(store: Path, array: str) -> Path:
    return next(p for p in sorted((store / array / "c").rglob("*")) if p.is_file())


@case("verify-changed-attr", 1, "recon", "digest", "1 of ", tampers=True)
def _(c):
    meta = c.art / "recon.zarr" / "zarr.json"
    doc = json.loads(meta.read_text())
    doc["attributes"]["robot_radius_m"] = 0.5
    meta.write_text(json.dumps(doc))
    return c.argv("verify")


@case("verify-corrupt-chunk", 1, "unreadable", "{root}/data/artifacts/tiny/recon.zarr/occupancy/c/", "does not decode", tampers=True)
def _(c):
    chunk_of(c.art / "recon.zarr", "occupancy").write_bytes(b"not blosc at all")
    return c.argv("verify")


@case("verify-corrupt-zarr-json", 1, "{root}/data/artifacts/tiny/frames.zarr/zarr.json", "not valid JSON", tampers=True)
def _(c):
    meta = c.art / "frames.zarr" / "zarr.json"
    meta.write_text(meta.read_text()[:40])
    return c.argv("verify")


@case("verify-deleted-array", 1, "goals", "digest", tampers=True)
def _(c):
    shutil.rmtree(c.art / "routes.zarr" / next(p.name for p in sorted((c.art / "routes.zarr").iterdir()) if p.is_dir()))
    return c.argv("verify")


@case("verify-deleted-artifact", 1, "missing", "{root}/data/artifacts/tiny/recon_mesh.ply", tampers=True)
def _(c):
    (c.art / "recon_mesh.ply").unlink()
    return c.argv("verify")


@case("verify-no-manifest", 1, "no manifest", "{root}/data/artifacts/tiny/cfmap.zarr", tampers=True)
def _(c):
    (c.root / "manifests" / SCENE / "cfmap.json").unlink()
    return c.argv("verify")


@case("verify-corrupt-manifest", 1, "{root}/manifests/tiny/vlmap.json", "manifest unreadable", tampers=True)
def _(c):
    (c.root / "manifests" / SCENE / "vlmap.json").write_text("{not json")
    return c.argv("verify")


@case("verify-manifest-not-utf8", 1, "{root}/manifests/tiny/vlmap.json", "manifest unreadable", tampers=True)
def _(c):
    (c.root / "manifests" / SCENE / "vlmap.json").write_bytes(b"\xff\xfe{")
    return c.argv("verify")


@case("status-manifest-nested-deep", 1, "{root}/manifests/tiny/goals.json", "not a valid zipon manifest",
      "recursion limit", tampers=True)
def _(c):
    (c.root / "manifests" / SCENE / "goals.json").write_text("[" * 100_000)
    return c.argv("status")


@case("verify-scene-not-in-params", 1, "ghost", "not in params.yaml", "no manifest", tampers=True)
def _(c):
    shutil.copytree(c.art / "goals.zarr", c.data / "artifacts" / "ghost" / "goals.zarr")
    return c.argv("verify")


@case("status-verify-tampered", 1, "content differs", "recon unreadable", "{root}/data/artifacts/tiny/recon.zarr",
      tampers=True)
def _(c):
    chunk_of(c.art / "recon.zarr", "occupancy").write_bytes(b"not blosc at all")
    return c.argv("status", "--verify")


# --- disks that refuse writes (ENOSPC / EROFS / EACCES raised by every write under the data root)

@case("disk-full-run", 1, "No space left on device", "{root}/data/", "ENOSPC", "free some space")
def _(c):
    c.fault = (errno.ENOSPC, c.data)
    return c.argv("run", "--stage", "reconstruct", "--force", "--scheduler", "sync")


@case("read-only-run", 1, "Read-only file system", "{root}/data/", "EROFS", "writable")
def _(c):
    c.fault = (errno.EROFS, c.data)
    return c.argv("run", "--stage", "routes", "--force", "--scheduler", "sync")


@case("read-only-render", 1, "Read-only file system", "{root}/data/artifacts/tiny/renders", "EROFS")
def _(c):
    c.fault = (errno.EROFS, c.data)
    return c.argv("render", SCENE, "--what", "navigable")


@case("read-only-ingest", 1, "Read-only file system", "{root}/data/", "EROFS", "writable")
def _(c):
    c.fault = (errno.EROFS, c.data)
    return ingest(c, good_log(c))


@case("read-only-goals-import", 1, "Read-only file system", "EROFS")
def _(c):
    c.fault = (errno.EROFS, c.data)
    c.goals_doc["goals"][0]["feedback"]["landmark"] = "It is next to the window."
    return goals_import(c, c.goals_doc)


@case("read-only-workspace-goals-import", 1, "Read-only file system", "{root}/", "EROFS")
def _(c):
    c.fault = (errno.EROFS, c.root)
    c.goals_doc["goals"][0]["feedback"]["landmark"] = "It is next to the window."
    return goals_import(c, c.goals_doc)


@case("disk-full-render", 1, "No space left on device", "{root}/data/artifacts/tiny/renders", "ENOSPC")
def _(c):
    c.fault = (errno.ENOSPC, c.data)
    return c.argv("render", SCENE, "--what", "obstacles")


@case("permission-denied-render-out", 1, "Permission denied", "{scratch}/locked", "EACCES")
def _(c):
    c.fault = (errno.EACCES, c.scratch / "locked")
    return c.argv("render", SCENE, "--what", "plan", "-o", str(c.scratch / "locked" / "plan.png"))


@case("disk-full-manifests", 1, "No space left on device", "{root}/manifests/", "ENOSPC")
def _(c):
    c.fault = (errno.ENOSPC, c.root / "manifests")
    return c.argv("run", "--stage", "goals", "--force", "--scheduler", "sync")


# --- hostile documents: alias bombs, deep nesting, oversized files (bounded parsing, pipeline/userfiles.py)

def alias_bomb(indent: str = "") -> str:
    """'Billion laughs': nine anchors, each a list of nine aliases of the one before (9**9 leaves expanded)."""
    lines = [f'{indent}a0: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    lines += [f"{indent}a{i}: &a{i} [" + ",".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 10)]
    return "\n".join(lines) + "\n"


@case("params-alias-bomb", 1, "{scratch}/params.yaml", "aliases expanded")
def _(c):
    return with_params(c, BASE + alias_bomb())


@case("params-alias-bomb-nested", 1, "{scratch}/params.yaml", "aliases expanded")
def _(c):
    return with_params(c, BASE + "ingest:\n  topics:\n" + alias_bomb("    "))


@case("params-recursive-alias", 1, "{scratch}/params.yaml", "recursive")
def _(c):
    return with_params(c, BASE + "simulate: &s {frames: *s}\n")


@case("params-deep-nesting", 1, "{scratch}/params.yaml", "nest")
def _(c):
    return with_params(c, BASE + "simulate: " + "[" * 200 + "]" * 200 + "\n")


@case("params-too-large", 1, "{scratch}/params.yaml", "bytes")
def _(c):
    return with_params(c, BASE + "# " + "x" * (5 << 20) + "\n")


@case("params-override-alias-bomb", 1, "override simulate.frames", "aliases expanded")
def _(c):
    return c.argv("-S", "simulate.frames=" + alias_bomb().replace("\n", ", ").join("{}"), "params")


@case("goals-alias-bomb", 1, "{scratch}/edit.yaml", "aliases expanded")
def _(c):
    return goals_import(c, (yaml.safe_dump(c.goals_doc, sort_keys=False) + "extra:\n" + alias_bomb("  ")).encode())


@case("goals-json-too-deep", 1, "{scratch}/edit.json", "nest")
def _(c):
    return c.argv("goals", "import", SCENE, str(c.file("edit.json", "[" * 100_000 + "]" * 100_000)))


@case("objects-file-alias-bomb", 1, "{scratch}/objects.yaml", "aliases expanded")
def _(c):
    path = c.file("objects.yaml", "rooms: []\nobjects: []\nbomb:\n" + alias_bomb("  "))
    return c.argv("-S", "goals.objects=file", "-S", f"goals.objects_files.{SCENE}={path}",
                  "run", "--stage", "goals", "--force", "--scheduler", "sync")


@case("rosbag2-metadata-alias-bomb", 1, "{scratch}/bag_sqlite/metadata.yaml", "aliases expanded")
def _(c):
    from tests.fixtures.raw_datasets import write_bag

    bag = write_bag(c.scratch, REC, "ros2")
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text() + "bomb:\n" + alias_bomb("  "))
    return ingest(c, bag)


# --- decoding faults: every image decoded strictly, every error names the file and frame

def _cut(path: Path, fraction: float) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])


@case("replica-jpeg-truncated", 1, "{scratch}/Replica/room0/results/frame000002.jpg", "frame 2", "truncated")
def _(c):
    from tests.fixtures.raw_datasets import write_replica

    root = write_replica(c.scratch, REC)
    _cut(root / "results/frame000002.jpg", 0.4)
    return ingest(c, root)


@case("tum-png-cut", 1, "rgb/", "frame 4", "truncated")
def _(c):
    root = write_tum(c.scratch, REC)
    _cut(root / "rgb" / sorted(p.name for p in (root / "rgb").iterdir())[4], 0.6)
    return ingest(c, root)


@case("tum-png-bad-crc", 1, "depth/", "frame 1", "fails its CRC")
def _(c):
    root = write_tum(c.scratch, REC)
    f = root / "depth" / sorted(p.name for p in (root / "depth").iterdir())[1]
    data = bytearray(f.read_bytes())
    data[len(data) // 2] ^= 0x01  # inside IDAT: its CRC no longer matches
    f.write_bytes(bytes(data))
    return ingest(c, root)


@case("tum-groundtruth-only-comments", 1, "groundtruth.txt", "no poses listed", "blank or a comment")
def _(c):
    root = write_tum(c.scratch, REC)
    (root / "groundtruth.txt").write_text("# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n")
    return ingest(c, root)


@case("ros1-compressed-jpeg-truncated", 1, "{scratch}/cut.bag", "/camera/color/image_raw/compressed", "frame 3",
      "truncated")
def _(c):
    import cv2

    from tests.fixtures.raw_datasets import BagLog

    bag = BagLog(c.scratch / "cut.bag", "ros1")
    for i in range(len(REC)):
        s = int(REC.stamps[i])
        jpg = cv2.imencode(".jpg", REC.rgb[i][..., ::-1])[1].tobytes()
        bag.pose("/camera/pose", s, REC.poses[i])
        bag.compressed("/camera/color/image_raw/compressed", s, "rgb8; jpeg compressed bgr8",
                       jpg[: int(len(jpg) * 0.4)] if i == 3 else jpg)
        bag.image("/camera/depth/image_raw", s, REC.depth_mm[i], "16UC1")
        bag.camera_info("/camera/color/camera_info", s, REC.intrinsics)
    return ingest(c, bag.close())


def seven_scenes(c: Ctx, intrinsics: str | None = None) -> Path:
    """A 7-Scenes sequence seq-01 under scratch, with ``camera-intrinsics.txt`` above it as 3DMatch ships it."""
    from tests.fixtures.raw_datasets import write_7scenes

    root = write_7scenes(c.scratch, REC)
    if intrinsics is not None:
        (c.scratch / "camera-intrinsics.txt").write_text(intrinsics)
    return root


@case("sevenscenes-intrinsics-garbage", 1, "{scratch}/camera-intrinsics.txt", "not numeric", "fx 0 cx")
def _(c):
    return ingest(c, seven_scenes(c, "fx = 585\nfy = 585\n"))


@case("sevenscenes-intrinsics-skew", 1, "{scratch}/camera-intrinsics.txt", "not a pinhole camera matrix")
def _(c):
    return ingest(c, seven_scenes(c, "28 1 16\n0 28 12\n0 0 1\n"))


@case("sevenscenes-intrinsics-outside-image", 1, "{scratch}/camera-intrinsics.txt", "do not fit", "32x24")
def _(c):
    return ingest(c, seven_scenes(c, "5.7034e+02 0 3.2e+02\n0 5.7034e+02 2.4e+02\n0 0 1\n"))


@case("sevenscenes-depth-size", 1, "{scratch}/seq-01/frame-000003.depth.png", "{scratch}/seq-01/frame-000003.color.png",
      "16x12", "32x24")
def _(c):
    import cv2

    root = seven_scenes(c)
    depth = root / "frame-000003.depth.png"
    cv2.imwrite(str(depth), cv2.imread(str(depth), cv2.IMREAD_UNCHANGED)[::2, ::2])
    return ingest(c, root)


# --- paths and texts that are not what the option wants

@case("status-manifests-dir-is-a-file", 1, "--manifests-dir", "{scratch}/manifests.txt", "not a folder")
def _(c):
    argv = c.argv("status")
    argv[argv.index("--manifests-dir") + 1] = str(c.file("manifests.txt", "not a folder\n"))
    return argv


@case("status-data-dir-is-a-file", 1, "--data-dir", "{scratch}/data.txt", "not a folder")
def _(c):
    argv = c.argv("status")
    argv[argv.index("--data-dir") + 1] = str(c.file("data.txt", "not a folder\n"))
    return argv


@case("read-only-goals-export-out", 1, "{scratch}/ro/goals.yaml", "Read-only file system", "writable file system",
      never=(".tmp-", "--data-dir"))
def _(c):
    (c.scratch / "ro").mkdir()
    c.fault = (errno.EROFS, c.scratch / "ro")
    return c.argv("goals", "export", SCENE, "-o", str(c.scratch / "ro" / "goals.yaml"))


@case("read-only-render-out", 1, "{scratch}/ro/", "Read-only file system", "writable file system",
      never=("--data-dir",))
def _(c):
    (c.scratch / "ro").mkdir()
    c.fault = (errno.EROFS, c.scratch / "ro")
    return c.argv("render", SCENE, "--what", "navigable", "-o", str(c.scratch / "ro" / "nav.png"))


@case("read-only-query-png", 1, "{scratch}/ro/", "Read-only file system", "writable file system",
      never=("--data-dir",))
def _(c):
    (c.scratch / "ro").mkdir()
    c.fault = (errno.EROFS, c.scratch / "ro")
    return c.argv("query", SCENE, "chair", "--png", str(c.scratch / "ro" / "q.png"))


# --- usage errors (click's exit code 2)

@case("usage-unknown-option", 2, "--bogus")
def _(c):
    return c.argv("run", "--bogus")


@case("usage-missing-scene", 2, "--scene")
def _(c):
    return c.argv("ingest", str(c.scratch / "x.mcap"))


@case("usage-query-empty-text", 2, "TEXT", "empty")
def _(c):
    return c.argv("query", SCENE, "")


@case("usage-query-blank-text", 2, "TEXT", "empty")
def _(c):
    return c.argv("query", SCENE, "   ")


# --- stored human-answered episodes (zipon eval -f human reads them back as user input)

HUMAN_RECORD = {"scene": SCENE, "method": "cow", "feedback": "human", "seed": 0, "goal": "?", "goal_type": "big",
                "episode": "e0", "success": True, "spl": 0.5, "sit": 1.0, "talk_turns": 1, "steps": 12,
                "travelled_m": 3.2, "geodesic_m": 1.6, "collisions": 0, "end": "found", "final_distance_m": 0.4}


def human_eval(c: Ctx, *records: dict, strict: bool = False) -> list[str]:
    path = c.data / "eval" / "human" / f"{SCENE}.episodes.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    return c.argv("eval", "-s", SCENE, "-m", "cow", "-f", "human", "--out", str(c.scratch / "ev"),
                  *(["--strict"] if strict else []))


@case("eval-human-string-for-number", 1, "data/eval/human/tiny.episodes.jsonl", "field spl", "line 2",
      "Input should be a valid number", tampers=True)
def _(c):
    good = {**HUMAN_RECORD, "goal": c.goals_doc["goals"][0]["id"]}
    return human_eval(c, good, {**good, "spl": "0.5"})


@case("eval-human-missing-field", 1, "data/eval/human/tiny.episodes.jsonl", "field success", "line 1",
      "Field required", tampers=True)
def _(c):
    return human_eval(c, {k: v for k, v in HUMAN_RECORD.items() if k != "success"})


@case("eval-human-nan", 1, "data/eval/human/tiny.episodes.jsonl", "field travelled_m", "finite number", tampers=True)
def _(c):
    return human_eval(c, {**HUMAN_RECORD, "goal": c.goals_doc["goals"][0]["id"], "travelled_m": float("nan")})


@case("eval-human-removed-goal-strict", 1, "data/eval/human/tiny.episodes.jsonl", "field goal",
      "goal 'removed_goal' is not in scene tiny's goals store", tampers=True)
def _(c):
    return human_eval(c, {**HUMAN_RECORD, "goal": "removed_goal"}, strict=True)


@case("usage-eval-negative-seed", 2, "--seed-list", "negative")
def _(c):
    return c.argv("eval", "--seed-list", "-3", "--out", str(c.scratch / "eval"))


@case("usage-eval-out-is-a-file", 2, "--out", "is a file")
def _(c):
    return c.argv("eval", "--out", str(c.file("params.yaml", BASE)))


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.xfail(strict=True, reason=CASES[n].xfail))
                                  if CASES[n].xfail else n for n in CASES])
def test_bad_input(name, pristine, tmp_path, capsys, monkeypatch):
    bad = CASES[name]
    shared, goals_doc, state = pristine
    if bad.tampers:
        root = copy_workspace(shared, tmp_path / "ws")
    else:
        root = shared
        assert tree_state(root) == state, "an earlier case changed the shared workspace"
    (tmp_path / "scratch").mkdir()
    ctx = Ctx(root, tmp_path / "scratch", json.loads(json.dumps(goals_doc)))
    argv = bad.make(ctx)
    before = tree_state(ctx.root)
    capsys.readouterr()
    with monkeypatch.context() as m:
        if ctx.fault:
            _fail_writes_under(m, *ctx.fault)
        code = main(argv)
    out, err = capsys.readouterr()
    text = " ".join((out + err).split())  # rich wraps at spaces; compare on single spaces
    assert "Traceback" not in out + err, out + err
    assert code == bad.code, f"exit {code}, expected {bad.code}:\n{out}{err}"
    for fragment in bad.says:
        fragment = fragment.format(root=ctx.root, scratch=ctx.scratch)
        assert fragment in text, f"{fragment!r} not in the output:\n{out}{err}"
    for fragment in bad.never:
        assert fragment not in text, f"{fragment!r} in the output:\n{out}{err}"
    after = tree_state(ctx.root)
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    assert not changed, f"the failed command changed {changed}"


def test_corpus_is_large_enough():
    assert len(CASES) >= 40


# ----------------------------------------------------------------------------- real read-only and full disks

ZIPON = "import sys; from zipon.cli import main; sys.exit(main(sys.argv[1:]))"


def _namespaces_work() -> str:
    """'' when this machine lets a process mount in its own user + mount namespace, else why not."""
    if shutil.which("unshare") is None:
        return "no unshare command"
    probe = subprocess.run(["unshare", "--user", "--map-root-user", "--mount", "sh", "-c",
                            "mount -t tmpfs -o size=64k tmpfs /mnt"], capture_output=True, text=True, timeout=60)
    return "" if probe.returncode == 0 else f"cannot mount in a user namespace: {probe.stderr.strip()}"


@pytest.fixture(scope="module")
def namespaces():
    why = _namespaces_work()
    if why:
        pytest.skip(f"a real read-only / full file system needs mount namespaces ({why}); "
                    "the fault-injection cases above cover the same paths")


def _zipon_in_namespace(mounts: str, argv: list[str]) -> subprocess.CompletedProcess:
    """Run zipon in a private mount namespace after ``mounts`` (shell commands) ran there."""
    script = f'{mounts} && code="$1" && shift && exec "$0" -c "$code" "$@"'
    return subprocess.run(["unshare", "--user", "--map-root-user", "--mount", "sh", "-c", script,
                           sys.executable, ZIPON, *argv], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).resolve().parents[1],
                          env={**os.environ, "COLUMNS": "250", "HF_HUB_OFFLINE": "1"})


def test_real_read_only_data_dir(namespaces, pristine, tmp_path):
    """The data root bind-mounted read-only (EROFS even for root): ingest fails naming the path."""
    root = copy_workspace(pristine[0], tmp_path / "ws")
    log = write_mcap(tmp_path / "good.mcap", REC)
    before = tree_state(root)
    data = root / "data"
    ctx = Ctx(root, tmp_path, {})
    proc = _zipon_in_namespace(f"mount --bind {data} {data} && mount -o remount,bind,ro {data}", ingest(ctx, log))
    text = " ".join((proc.stdout + proc.stderr).split())
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "Traceback" not in text
    assert f"{data}/" in text and "Read-only file system [EROFS]" in text and "writable" in text, text
    assert tree_state(root) == before


def test_real_full_disk(namespaces, pristine, tmp_path):
    """A 512 KiB file system under the scene's stage folder fills up while ingest writes frames.zarr (ENOSPC):
    the run fails naming the path, the published frames and manifests stay as they were."""
    root = copy_workspace(pristine[0], tmp_path / "ws")
    before = tree_state(root)
    ctx = Ctx(root, tmp_path, {})
    tmp = ctx.art / ".tmp"
    tmp.mkdir(exist_ok=True)
    proc = _zipon_in_namespace(f"mount -t tmpfs -o size=512k tmpfs {tmp}",
                               ctx.argv("run", "--stage", "ingest", "--force", "--scheduler", "sync"))
    text = " ".join((proc.stdout + proc.stderr).split())
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "Traceback" not in text
    assert f"{tmp}/" in text and "No space left on device [ENOSPC]" in text and "free some space" in text, text
    assert tree_state(root) == before


# ----------------------------------------------------------------------------- goals import is all or nothing

def test_goals_import_whose_routes_fail_changes_nothing(pristine, tmp_path, monkeypatch, capsys):
    """The goals stage rebuilds with the edit, then routes fails: params.yaml keeps its bytes, the stored
    edit is removed, and goals are rebuilt without the edit (same content digest as before)."""
    import stages.routes
    from pipeline.errors import StageError
    from pipeline.engine.manifest import Manifest

    root = copy_workspace(pristine[0], tmp_path / "ws")
    (tmp_path / "scratch").mkdir()
    c = Ctx(root, tmp_path / "scratch", json.loads(json.dumps(pristine[1])))
    params_text = (root / "params.yaml").read_bytes()
    manifests = {s: Manifest.read(root / "manifests" / SCENE / f"{s}.json") for s in ("goals", "routes")}

    def routes_fail(ctx):
        raise StageError("no route reaches the edited goal")  # a failure after goals was rebuilt

    monkeypatch.setattr(stages.routes, "run", routes_fail)
    c.goals_doc["goals"][0]["feedback"]["landmark"] = "It is next to the window."
    code = main(goals_import(c, c.goals_doc))
    out, err = capsys.readouterr()
    assert code == 1 and "Traceback" not in out + err
    assert "no route reaches the edited goal" in err and "params.yaml unchanged" in " ".join(err.split())
    assert (root / "params.yaml").read_bytes() == params_text
    assert not (root / "goals_edits").exists()
    for stage, before in manifests.items():
        after = Manifest.read(root / "manifests" / SCENE / f"{stage}.json")
        assert (after.params_digest, after.inputs, after.outputs) == (before.params_digest, before.inputs,
                                                                      before.outputs), stage


def test_goals_import_whose_dvc_lock_record_fails_changes_nothing(pristine, tmp_path, monkeypatch, capsys):
    """Goals and routes rebuild with the edit and params.yaml records it, then dvc.lock cannot be written: the whole
    save is undone (params.yaml, dvc.lock, the stored edit, the built goals and routes), exit 1 saying so."""
    import pipeline.engine.dvcfile
    from pipeline.engine.manifest import Manifest
    from pipeline.errors import ZiponError

    root = copy_workspace(pristine[0], tmp_path / "ws")
    (tmp_path / "scratch").mkdir()
    c = Ctx(root, tmp_path / "scratch", json.loads(json.dumps(pristine[1])))
    (root / "dvc.lock").write_text("schema: '2.0'\nstages: {}\n")
    kept = {name: (root / name).read_bytes() for name in ("params.yaml", "dvc.lock")}
    manifests = {s: Manifest.read(root / "manifests" / SCENE / f"{s}.json") for s in ("goals", "routes")}

    def dvc_fails(*args, **kwargs):
        (root / "dvc.lock").write_text("half written\n")
        raise ZiponError("recording them in dvc.lock failed (OSError: No space left on device)")

    monkeypatch.setattr(pipeline.engine.dvcfile, "sync_dvc_lock", dvc_fails)
    c.goals_doc["goals"][0]["feedback"]["landmark"] = "It is next to the window."
    code = main(goals_import(c, c.goals_doc))
    out, err = capsys.readouterr()
    text = " ".join(err.split())
    assert code == 1 and "Traceback" not in out + err
    assert "dvc.lock could not be recorded, so the whole save was undone" in text and "params.yaml unchanged" in text
    assert {name: (root / name).read_bytes() for name in kept} == kept
    assert not (root / "goals_edits").exists()
    for stage, before in manifests.items():
        after = Manifest.read(root / "manifests" / SCENE / f"{stage}.json")
        assert (after.params_digest, after.inputs, after.outputs) == (before.params_digest, before.inputs,
                                                                      before.outputs), stage


def test_goals_import_records_the_edit_once_rebuilt(pristine, tmp_path, capsys):
    """The good path beside the failures above: the edit is rebuilt into goals.zarr, then params.yaml names it."""
    from pipeline.goals.store import Goals
    from pipeline.engine.manifest import Manifest

    root = copy_workspace(pristine[0], tmp_path / "ws")
    (tmp_path / "scratch").mkdir()
    c = Ctx(root, tmp_path / "scratch", json.loads(json.dumps(pristine[1])))
    c.goals_doc["goals"][0]["feedback"]["landmark"] = "It is next to the window."
    assert main(goals_import(c, c.goals_doc)) == 0, capsys.readouterr()
    rel = yaml.safe_load((root / "params.yaml").read_text())["goals"]["edits"][SCENE]
    assert (root / rel).is_file() and rel.startswith("goals_edits/tiny-")
    assert Goals(c.art / "goals.zarr").document.goals[0].feedback.landmark == "It is next to the window."
    assert Manifest.read(root / "manifests" / SCENE / "goals.json").params[f"goals.edits.{SCENE}"] == rel
