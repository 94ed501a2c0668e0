"""benchmarks/check_reference.py refuses bad command lines with exit status 2 and a message naming the argument.

The comparison itself needs clones of the reference repositories and runs from the script (README, "The real
encoders against their references"); these tests need none.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest


@pytest.fixture(scope="module")
def check():
    from benchmarks import check_reference

    return check_reference


@pytest.fixture()
def tum(tmp_path) -> Path:
    """A one-frame TUM RGB-D folder."""
    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    cv2.imwrite(str(tmp_path / "rgb" / "1.000000.png"), np.full((8, 8, 3), 100, np.uint8))
    cv2.imwrite(str(tmp_path / "depth" / "1.000100.png"), np.full((8, 8), 5000, np.uint16))
    (tmp_path / "rgb.txt").write_text("# color images\n1.000000 rgb/1.000000.png\n")
    (tmp_path / "depth.txt").write_text("# depth maps\n1.000100 depth/1.000100.png\n")
    return tmp_path


def fake_clone(root: Path, name: str, check) -> Path:
    marker = root / name / check.REFERENCES[name][1]
    marker.parent.mkdir(parents=True)
    marker.write_text("")
    return root / name


def run(check, capsys, *argv) -> tuple[int, str]:
    code = check.main([str(a) for a in argv])
    return code, capsys.readouterr().err


def test_no_reference_given(check, capsys, tum):
    code, err = run(check, capsys, "--frames", tum)
    assert code == 2
    assert "give at least one of --lseg PATH, --maskclip PATH, --conceptfusion PATH" in err


@pytest.mark.parametrize("name, repo", [("lseg", "isl-org/lang-seg"), ("maskclip", "chongzhou/MaskCLIP"),
                                        ("conceptfusion", "concept-fusion/concept-fusion")])
def test_a_folder_that_is_not_the_reference(check, capsys, tum, tmp_path, name, repo):
    code, err = run(check, capsys, f"--{name}", tmp_path / "elsewhere", "--frames", tum)
    assert code == 2
    assert f"--{name} {tmp_path / 'elsewhere'}: not a clone of {repo}" in err
    assert check.REFERENCES[name][1] in err


def test_bad_frames_folder_and_index(check, capsys, tum, tmp_path):
    clone = fake_clone(tmp_path, "lseg", check)
    code, err = run(check, capsys, "--lseg", clone, "--frames", tmp_path / "nothing")
    assert code == 2 and "no rgb.txt (a TUM RGB-D folder is expected)" in err
    code, err = run(check, capsys, "--lseg", clone, "--frames", tum, "--frame-index", 3)
    assert code == 2 and f"--frame-index 3: {tum / 'rgb.txt'} has 1 frames" in err


def test_lseg_crop_must_be_a_multiple_of_32(check, capsys, tum, tmp_path):
    clone = fake_clone(tmp_path, "lseg", check)
    code, err = run(check, capsys, "--lseg", clone, "--frames", tum, "--lseg-crop", 100)
    assert code == 2 and "--lseg-crop 100: must be a positive multiple of 32" in err


def test_refdeps_must_be_a_folder(check, capsys, tum, tmp_path):
    clone = fake_clone(tmp_path, "maskclip", check)
    code, err = run(check, capsys, "--maskclip", clone, "--frames", tum, "--refdeps", tmp_path / "none")
    assert code == 2 and f"--refdeps {tmp_path / 'none'}: not a folder" in err


def test_the_frame_is_read_with_its_nearest_depth(check, tum):
    rgb, depth, path = check.load_frame(tum, 0)
    assert rgb.shape == (8, 8, 3) and rgb.dtype == np.uint8 and path == tum / "rgb" / "1.000000.png"
    assert np.allclose(depth, 1.0)  # 5000 units per metre
