import logging

import pytest

from zipon.cli import app, main


def test_every_command_has_help_with_an_example(capsys):
    import typer.main

    def walk(group, prefix):
        for name, command in group.commands.items():
            text = " ".join((command.help or "").split())
            assert "Example" in text and f"`zipon {prefix}{name}" in text, f"zipon {prefix}{name} --help lacks an example"
            if hasattr(command, "commands"):
                walk(command, f"{prefix}{name} ")

    walk(typer.main.get_command(app), "")


@pytest.mark.parametrize("section, message", [
    ("ingest:\n  block_frames: -1\n", "ingest.block_frames: Input should be greater than 0"),
    ("reconstruct:\n  depth_stride: half\n",
     "reconstruct.depth_stride: expected 'auto' or a whole number from 1 to 8, got 'half'"),
])
def test_config_error_is_a_message_and_exit_1(tmp_path, capsys, section, message):
    (tmp_path / "params.yaml").write_text("scenes:\n  s0: {source: simulate}\n" + section)
    code = main(["--params", str(tmp_path / "params.yaml"), "status"])
    err = capsys.readouterr().err
    assert code == 1
    assert message in err
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
    from pipeline.engine.manifest import Manifest

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


def test_a_failed_stage_makes_run_and_stage_exit_1(tmp_path, capsys):
    (tmp_path / "bad.mcap").write_bytes(b"not an mcap log")
    (tmp_path / "params.yaml").write_text("scenes:\n  r0: {source: bad.mcap, format: mcap}\n")
    p = str(tmp_path / "params.yaml")
    assert main(["-q", "-p", p, "run"]) == 1
    err = capsys.readouterr().err
    assert "error r0/ingest:" in err and "bad.mcap" in err and "Traceback" not in err
    assert main(["-q", "-p", p, "stage", "ingest", "--scene", "r0"]) == 1
    assert not (tmp_path / "data" / "artifacts" / "r0" / "frames.zarr").exists()


def test_params_file_of_any_name_is_read(tmp_path, capsys):
    (tmp_path / "params.yaml").write_text("scenes:\n  other: {source: simulate}\n")
    (tmp_path / "mine.yaml").write_text("scenes:\n  mine: {source: simulate}\n")
    assert main(["-p", str(tmp_path / "mine.yaml"), "status"]) == 0
    out = capsys.readouterr().out
    assert "mine" in out and "other" not in out


def test_status_check_exits_1_when_stale_and_names_why(tmp_path, capsys):
    (tmp_path / "params.yaml").write_text("scenes:\n  a: {source: simulate}\n")
    p = str(tmp_path / "params.yaml")
    assert main(["-p", p, "status"]) == 0
    assert main(["-p", p, "status", "--check"]) == 1
    assert "never run" in capsys.readouterr().out


def test_dvc_check_exits_1_when_dvc_yaml_is_stale(tmp_path, capsys):
    (tmp_path / "params.yaml").write_text("scenes:\n  a: {source: simulate}\n")
    p = str(tmp_path / "params.yaml")
    assert main(["-p", p, "dvc", "--check"]) == 1
    assert "out of date" in capsys.readouterr().err
    assert main(["-p", p, "dvc"]) == 0 and main(["-p", p, "dvc", "--check"]) == 0
    (tmp_path / "params.yaml").write_text("scenes:\n  a: {source: simulate}\n  b: {source: simulate}\n")
    assert main(["-p", p, "dvc", "--check"]) == 1


def test_strict_params_types_name_the_key(tmp_path, capsys):
    p = tmp_path / "params.yaml"
    for body, message in (
        ("simulate: {frames: true}", "simulate.frames: expected a number, got true (a boolean)"),
        ("simulate: {frames: '12'}", "simulate.frames: expected a number, got the string '12'"),
        ("maps: {level_height_m: .nan}", "maps.level_height_m: Input should be a finite number"),
        ("run: {scheduler: fastest}", "run.scheduler: 'fastest' is not a scheduler"),
        ("maps: {min_candidate_score: 0.5}", "maps.min_candidate_score: moved to query.min_candidate_score"),
        ("encoders: {batch_size: 2}", "encoders.batch_size: moved to run.encoder_batch_size"),
    ):
        p.write_text("scenes:\n  a: {source: simulate}\n" + body + "\n")
        assert main(["-p", str(p), "status"]) == 1, body
        err = capsys.readouterr().err.replace("\n", " ")
        assert message in err, (body, err)


def test_python_dash_m_runs_the_same_cli():
    """`python -m zipon.cli` is the `zipon` command (the package's commands register without an import cycle)."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "zipon.cli", "--help"], capture_output=True, text=True,
                          env={"COLUMNS": "200", "PATH": ""}, timeout=60)
    assert done.returncode == 0, done.stderr
    assert all(f" {name} " in done.stdout for name in ("run", "demo", "query", "eval", "goals", "encoders"))


def test_version_comes_from_the_package_metadata(capsys):
    from importlib.metadata import version

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"zipon {version('zipon')}"


def test_shell_completion_script():
    """``--show-completion`` detects the shell it runs under (the parent process): run it from bash, whatever started
    the tests (a background job's orphaned process has no shell above it). ``; exit`` keeps bash from exec'ing."""
    import shlex
    import subprocess
    import sys

    done = subprocess.run(["bash", "-c", f"{shlex.quote(sys.executable)} -m zipon.cli --show-completion; exit $?"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "_zipon_completion()" in done.stdout and "_ZIPON_COMPLETE=complete_bash" in done.stdout


@pytest.mark.parametrize("flags, zipon_level, dvc_level", [
    (["-q"], logging.WARNING, logging.WARNING), ([], logging.INFO, logging.WARNING),
    (["-v"], logging.DEBUG, logging.WARNING), (["-vv"], logging.DEBUG, logging.INFO),
])
def test_quiet_and_verbose_set_the_logging_levels(tmp_path, capsys, flags, zipon_level, dvc_level):
    """The library logs (logger ``zipon``), the CLI picks the level; DVC's own info ("Updating lock file") only
    with -vv."""
    (tmp_path / "params.yaml").write_text("scenes: {a: {source: simulate}}\n")
    assert main([*flags, "-p", str(tmp_path / "params.yaml"), "params"]) == 0
    assert logging.getLogger("zipon").level == zipon_level
    assert logging.getLogger("dvc").level == logging.getLogger("distributed").level == dvc_level


def test_a_stage_message_is_logged_and_shown_unless_quiet(capsys):
    from pipeline import logs

    logs.configure(0)
    logs.get_logger("stages").info("%s/%s: %s", "a", "ingest", "read 3 frames")
    logs.get_logger("stages").debug("hidden at info")
    assert capsys.readouterr().err == "a/ingest: read 3 frames\n"
    logs.configure(-1)
    logs.get_logger("stages").info("not shown with -q")
    logs.get_logger("stages").warning("shown")
    assert capsys.readouterr().err == "warning: shown\n"


def test_data_and_manifests_roots_that_are_files(tmp_path, capsys, monkeypatch):
    """Given by environment or by default (a file named manifests beside params.yaml): named, exit 1."""
    (tmp_path / "params.yaml").write_text("scenes:\n  s0: {source: simulate}\n")
    (tmp_path / "manifests").write_text("not a folder\n")
    assert main(["--params", str(tmp_path / "params.yaml"), "status"]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert f"--manifests-dir (default) {tmp_path / 'manifests'}: is a file, not a folder" in err
    monkeypatch.setenv("ZIPON_DATA", str(tmp_path / "params.yaml"))
    assert main(["--params", str(tmp_path / "params.yaml"), "--manifests-dir", str(tmp_path), "status"]) == 1
    err = " ".join(capsys.readouterr().err.split())
    # typer reads ZIPON_DATA as the option's value
    assert f"--data-dir {tmp_path / 'params.yaml'}: is a file, not a folder; point --data-dir at a folder" in err
