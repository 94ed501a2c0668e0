"""Two runs on one data root: the second fails fast naming the first's pid and host; nothing is corrupted."""

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from zipon.cli import main
from pipeline.paramsfile import load_params
from pipeline.errors import LockedError
from pipeline.engine.locks import lock_holder, output_lock
from pipeline.engine.runner import run_stage
from pipeline.store import content_digest
from pipeline.engine.verify import verify_all
from tests.fixtures.toy_stages import TOY_STAGES

REPO = Path(__file__).resolve().parents[3]
HOST = socket.gethostname()


def _spawn(code: str, ready: Path, **env) -> subprocess.Popen:
    """A real second process running ``code``; returns once it has created ``ready``."""
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, env={**os.environ, **env})
    deadline = time.time() + 60
    while not ready.exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    assert ready.exists(), f"the helper process did not get ready (exit code {proc.poll()})"
    return proc


def _hold(lock: Path, ready: Path) -> subprocess.Popen:
    return _spawn("import time; from pipeline.engine.locks import output_lock\n"
                  f"with output_lock({str(lock)!r}, 'x'):\n"
                  f"    open({str(ready)!r}, 'w').close(); time.sleep(60)\n", ready)


def _kill(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGKILL)
    proc.wait()


def test_second_run_of_a_stage_fails_fast_and_the_data_root_stays_consistent(workspace, tmp_path):
    params = load_params(workspace.params_path, ["simulate.frames=8"])
    for stage in ("simulate", "ingest"):
        run_stage(workspace, params, TOY_STAGES, "s0", stage, show_progress=False)
    frames = workspace.artifact("frames", "s0")
    before = content_digest(frames)
    pause = tmp_path / "paused"
    first = _spawn(  # a forced rebuild that stops mid-write, holding the (s0, ingest) lock
        "from pipeline.paramsfile import load_params; from pipeline.paths import Workspace;"
        "from pipeline.engine.runner import run_stage; from tests.fixtures.toy_stages import TOY_STAGES;"
        f"ws = Workspace.resolve({str(workspace.params_path)!r});"
        "run_stage(ws, load_params(ws.params_path, ['simulate.frames=8']), TOY_STAGES, 's0', 'ingest',"
        " force=True, show_progress=False)", pause, TOY_PAUSE_FILE=str(pause))
    try:
        t0 = time.perf_counter()
        with pytest.raises(LockedError) as err:
            run_stage(workspace, params, TOY_STAGES, "s0", "ingest", force=True, show_progress=False)
        assert time.perf_counter() - t0 < 5  # fails fast, does not wait
        assert f"scene s0 stage ingest is being built by another zipon run: pid {first.pid} on host {HOST}" \
            in str(err.value)
        assert str(workspace.lock("s0", "ingest")) in str(err.value)
        # other scenes and stages are not locked
        assert run_stage(workspace, params, TOY_STAGES, "s1", "simulate", show_progress=False).status == "ran"
        assert content_digest(frames) == before
        tmp = list(workspace.tmp_dir("s0").iterdir())
        assert [lock_holder(workspace.lock("s0", "ingest"))[0]] == [first.pid]
        assert len(tmp) == 1 and f"-{first.pid}-" in tmp[0].name  # the refused run wrote nothing
    finally:
        _kill(first)
    # the dead holder's lock is broken automatically; its leftovers are swept; everything verifies
    assert run_stage(workspace, params, TOY_STAGES, "s0", "ingest", force=True, show_progress=False).status == "ran"
    assert content_digest(frames) == before
    assert list(workspace.tmp_dir("s0").iterdir()) == []
    assert not workspace.lock("s0", "ingest").exists()
    assert all(r.ok for r in verify_all(workspace, params, TOY_STAGES))


def test_zipon_run_exits_1_naming_the_holder(tmp_path, capsys):
    (tmp_path / "params.yaml").write_text("scenes:\n  s0: {source: simulate}\n")
    argv = ["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", str(tmp_path / "data"),
            "--manifests-dir", str(tmp_path / "manifests"), "run", "--stage", "simulate", "--scheduler", "sync"]
    lock = tmp_path / "data" / "artifacts" / "s0" / ".simulate.lock"
    holder = _hold(lock, tmp_path / "ready")
    try:
        assert main(argv) == 1
        err = " ".join(capsys.readouterr().err.split())
        assert f"scene s0 stage simulate is being built by another zipon run: pid {holder.pid} on host {HOST}" in err
        assert "Traceback" not in err
        assert not (tmp_path / "manifests" / "s0" / "simulate.json").exists()
    finally:
        _kill(holder)


def test_a_dead_holder_on_this_host_is_reclaimed(tmp_path):
    lock = tmp_path / "x.lock"
    _kill(_hold(lock, tmp_path / "ready"))
    assert lock.exists()  # SIGKILL left the marker behind
    with output_lock(lock, "x"):
        assert lock_holder(lock) == (os.getpid(), HOST)
    assert not lock.exists()


def test_a_lock_of_another_host_is_never_broken(tmp_path):
    lock = tmp_path / "x.lock"
    lock.write_text("4242\nnode-17.cluster\n")  # filelock's marker: pid, host
    with pytest.raises(LockedError, match=r"x is being built by another zipon run: pid 4242 on host node-17.cluster"):
        with output_lock(lock, "x"):
            pass
    assert lock.read_text() == "4242\nnode-17.cluster\n"
