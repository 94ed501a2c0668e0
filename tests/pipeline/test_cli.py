import pytest

from pipeline.cli import app, main


def test_every_command_has_help_with_an_example(capsys):
    import typer.main

    def walk(group, prefix):
        for name, command in group.commands.items():
            assert "zipon" in (command.help or ""), f"zipon {prefix}{name} --help lacks an example"
            if hasattr(command, "commands"):
                walk(command, f"{prefix}{name} ")

    walk(typer.main.get_command(app), "")


def test_config_error_is_a_message_and_exit_1(tmp_path, capsys):
    (tmp_path / "params.yaml").write_text("scenes:\n  s0: {source: simulate}\ningest:\n  block_frames: -1\n")
    code = main(["--params", str(tmp_path / "params.yaml"), "status"])
    err = capsys.readouterr().err
    assert code == 1
    assert "ingest.block_frames: Input should be greater than 0" in err
    assert "Traceback" not in err


def test_missing_params_file(tmp_path, capsys):
    assert main(["--params", str(tmp_path / "nope.yaml"), "status"]) == 1
    assert "params file not found" in capsys.readouterr().err


def test_unknown_scene_is_named(tmp_path, capsys):
    (tmp_path / "params.yaml").write_text("scenes:\n  s0: {source: simulate}\n")
    assert main(["--params", str(tmp_path / "params.yaml"), "run", "-s", "kitchen"]) == 1
    assert "unknown scene(s) ['kitchen']" in capsys.readouterr().err


def test_usage_error_exit_code(capsys):
    assert main(["run", "--no-such-option"]) == 2


def test_simulate_then_ingest_from_the_command_line(tmp_path, capsys):
    """`zipon simulate` writes MCAP logs; `zipon ingest` turns one into a frame store with its manifest."""
    from pipeline.frames import FrameStore
    from pipeline.manifest import Manifest

    (tmp_path / "params.yaml").write_text("scenes: {}\n")
    base = ["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", str(tmp_path / "data"),
            "-S", "simulate.width=160", "-S", "simulate.height=120", "-S", "simulate.rooms_min=2",
            "-S", "simulate.rooms_max=2"]
    assert main(base + ["simulate", "--scenes", "1", "--frames", "5", "--seed", "3", "--out", str(tmp_path / "logs")]) == 0
    log = tmp_path / "logs" / "sim_00.mcap"
    assert log.is_file() and not any((tmp_path / "logs" / ".tmp").iterdir())
    assert main(base + ["ingest", str(log), "--scene", "cli_scene"]) == 0
    store = FrameStore(tmp_path / "data" / "artifacts" / "cli_scene" / "frames.zarr")
    assert store.n_frames == 5 and store.intrinsics.width == 160 and store.ground_truth is not None
    man = Manifest.read(tmp_path / "manifests" / "cli_scene" / "ingest.json")
    assert man.summary["matched_frames"] == 5
