"""The reader contract: every registered reader runs the same round trip (known arrays -> raw format ->
frames.zarr) plus format detection."""

from __future__ import annotations

from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path

import numpy as np
import pytest


from pipeline import plugins
from pipeline.config import IngestParams
from pipeline.errors import ConfigError, InputDataError, MissingInputError
from pipeline.frames import FrameStore
from pipeline.paramsfile import parse_params
from pipeline.readers import Opened, all_readers, detect_format, open_reader
from pipeline.readers.ingest import ingest_path
from tests.fixtures.raw_datasets import (decoded, make_recording, navchat_expected_poses, write_7scenes, write_bag,
                                         write_mcap, write_navchat, write_replica, write_scannet, write_tum)


@dataclass
class Case:
    path: Path
    rgb: np.ndarray
    depth_mm: np.ndarray
    instance: np.ndarray | None
    poses: np.ndarray
    stamps: np.ndarray
    pose_tol: float


def _mcap(tmp: Path) -> Case:
    rec = make_recording(6)
    return Case(write_mcap(tmp / "log.mcap", rec), rec.rgb, rec.depth_mm, rec.instance, rec.poses, rec.stamps, 1e-9)


def _rosbag(tmp: Path) -> Case:
    rec = make_recording(6)
    return Case(write_bag(tmp, rec, "ros1"), rec.rgb, rec.depth_mm, rec.instance, rec.poses, rec.stamps, 1e-9)


def _jpeg_folder(root: Path, colour: str, rec) -> Case:
    """A folder format with JPEG colour (``colour`` names frame i's file) and synthesised 30 Hz stamps."""
    stamps = np.round(np.arange(len(rec)) * 1e9 / 30.0).astype(np.int64)
    rgb = decoded([root / colour.format(i=i) for i in range(len(rec))])
    return Case(root, rgb, rec.depth_mm, None, rec.poses, stamps, 1e-12)


def _replica(tmp: Path) -> Case:
    rec = make_recording(6)
    return _jpeg_folder(write_replica(tmp, rec), "results/frame{i:06d}.jpg", rec)


def _scannet(tmp: Path) -> Case:
    rec = make_recording(6)
    return _jpeg_folder(write_scannet(tmp, rec), "color/{i}.jpg", rec)


def _tum(tmp: Path) -> Case:
    rec = make_recording(6)
    # poses come at 3x the camera rate, so the reader's frames are interpolated (smooth path: ~1e-4 m).
    return Case(write_tum(tmp, rec), rec.rgb, rec.depth_mm, None, rec.poses, rec.stamps, 2e-3)


def _7scenes(tmp: Path) -> Case:
    rec = make_recording(6)
    stamps = np.round(np.arange(6) * 1e9 / 30.0).astype(np.int64)
    return Case(write_7scenes(tmp, rec), rec.rgb, rec.depth_mm, None, rec.poses, stamps, 1e-12)


def _navchat(tmp: Path) -> Case:
    rec = make_recording(6)
    stamps = np.round(np.arange(6) * 1e9 / 30.0).astype(np.int64)
    return Case(write_navchat(tmp, rec), rec.rgb, rec.depth_mm, rec.instance, navchat_expected_poses(6), stamps, 1e-9)


FACTORIES = {"mcap": _mcap, "rosbag": _rosbag, "replica": _replica, "scannet": _scannet, "tum": _tum, "7scenes": _7scenes, "navchat": _navchat}


def test_every_reader_has_a_contract_case_a_layout_and_a_name_params_accept():
    readers = all_readers()
    assert set(FACTORIES) == set(readers) == set(plugins.BUILT_IN_READERS)
    for name, cls in readers.items():
        assert cls.name == name and cls.layout.startswith("a")
        parsed = parse_params({"scenes": {"s": {"source": "x", "format": name}}})
        assert parsed.scenes["s"].format == name
    with pytest.raises(ConfigError, match=r"scenes.s.format: .*unknown format 'tumm'.*'mcap', 'rosbag', 'tum'"):
        parse_params({"scenes": {"s": {"source": "x", "format": "tumm"}}})


def test_unknown_format_named_to_open_reader(tmp_path):
    with pytest.raises(InputDataError, match=r"unknown format 'tumm' \(expected one of \['mcap', .*'scannet'\] or 'auto'"):
        open_reader(tmp_path, IngestParams(), "tumm")


@pytest.mark.parametrize("fmt", sorted(FACTORIES))
class TestReaderContract:
    def test_detects_its_format(self, fmt, tmp_path):
        case = FACTORIES[fmt](tmp_path)
        assert detect_format(case.path) == fmt
        assert open_reader(case.path, IngestParams()).name == fmt

    def test_open_returns_what_samples_reads_and_the_reader_keeps_nothing(self, fmt, tmp_path):
        case = FACTORIES[fmt](tmp_path)
        reader = open_reader(case.path, IngestParams())
        opened = reader.open()
        assert isinstance(opened, Opened) and is_dataclass(opened.state)
        with pytest.raises(AttributeError):  # frozen: samples() reads the state, never changes it
            setattr(opened.state, fields(opened.state)[0].name, None)
        rgb_stamps = [s.stamp_ns for s in reader.samples(opened) if s.stream == "rgb"]
        assert rgb_stamps == case.stamps.tolist()
        assert set(vars(reader)) == {"path", "params"}

    def test_round_trip(self, fmt, tmp_path):
        case = FACTORIES[fmt](tmp_path)
        out = tmp_path / "frames.zarr"
        summary = ingest_path(case.path, out, IngestParams(block_frames=4), log=lambda m: None)
        fs = FrameStore(out)
        n = len(case.stamps)
        assert summary["matched_frames"] == fs.n_frames == n
        assert all(not reasons for reasons in summary["unmatched"].values())
        assert np.array_equal(fs.group["rgb"][:], case.rgb)
        assert np.array_equal(fs.group["depth"][:], case.depth_mm)
        assert np.array_equal(fs.stamps(), case.stamps)
        assert np.abs(fs.poses() - case.poses).max() <= case.pose_tol
        assert fs.has_instance == (case.instance is not None)
        if case.instance is not None:
            assert np.array_equal(fs.group["instance"][:], case.instance)
        prov = fs.attrs["provenance"]
        assert prov["format"] == fmt and prov["conversions"]
        assert fs.attrs["matching"]["matched_frames"] == n
        assert fs.block_frames == 4


def test_detect_unknown_folder(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(InputDataError, match=r"file .*: cannot tell the format of this path \(expected a ROS 2") as err:
        detect_format(tmp_path)
    for name, cls in all_readers().items():  # the message is composed from the registry
        assert f"{cls.layout} ({name})" in str(err.value)
    with pytest.raises(MissingInputError, match="raw data not found"):
        detect_format(tmp_path / "absent")


def test_rosbag2_folder_is_mcap(tmp_path):
    bag = tmp_path / "bag"
    bag.mkdir()
    write_mcap(bag / "bag_0.mcap", make_recording(2))
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    assert detect_format(bag) == "mcap"
