"""The one plug-in mechanism (:mod:`pipeline.plugins`) and its isolation, with real installed packages (their
metadata on ``sys.path``, as ``pip install`` leaves it): a plug-in that fails while imported, detecting or running is
one line naming its entry point and its package, exit 1; a reader failing in ``detect`` is skipped with a warning."""

from __future__ import annotations

import logging

import pytest

from pipeline import plugins
from pipeline.errors import ConfigError, PluginError
from tests.fixtures.raw_datasets import make_recording, write_mcap, write_tum
from tests.fixtures.user_agents import plugin_package
from zipon.cli import main

PACKAGE = "zipon-hostile"
EP = {
    plugins.READERS_GROUP: {"detect_raises": "tests.fixtures.hostile_plugins:DetectRaises",
                            "samples_raise": "tests.fixtures.hostile_plugins:SamplesRaise"},
    plugins.AGENTS_GROUP: {"argparse_agent": "tests.fixtures.argparse_agent:ArgparseAgent",
                           "exiting": "tests.fixtures.hostile_plugins:ExitingAgent",
                           "nearest_plugin": "tests.fixtures.user_agents:PluginNearest"},
    plugins.ENCODERS_GROUP: {"encode_raises": "tests.fixtures.hostile_plugins:EncodeRaises"},
}


def named(group: str, name: str) -> str:
    return f"{group} entry point {name!r} ({EP[group][name]}) of package {PACKAGE!r}"


@pytest.fixture
def hostile(tmp_path, monkeypatch):
    plugin_package(tmp_path / "site", PACKAGE, EP)
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    yield tmp_path
    from orion_eval.agents import AGENTS
    from pipeline.encoders.base import ENCODERS
    from pipeline.readers import READERS

    for registry in (AGENTS, ENCODERS, READERS):
        for name in [n for group in EP.values() for n in group]:
            registry.pop(name, None)


def _cli(ws, *args) -> list[str]:
    return ["-q", "-p", str(ws.params_path), "--data-dir", str(ws.data_dir), "--manifests-dir",
            str(ws.manifests_dir), *args]


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


def test_every_family_is_declared_the_same_way_and_resolved_by_one_function():
    from orion_eval.agents import AGENTS, agent_class
    from pipeline.encoders.choice import encoder_class
    from pipeline.readers import reader_class

    assert list(AGENTS) == list(plugins.BUILT_IN_AGENTS)  # the built-ins, loaded in their declared order
    for group, resolve in ((plugins.READERS_GROUP, reader_class), (plugins.AGENTS_GROUP, agent_class),
                           (plugins.ENCODERS_GROUP, encoder_class)):
        for name, value in plugins.BUILT_IN[group].items():
            cls = resolve(name)
            assert f"{cls.__module__}:{cls.__qualname__}" == value and cls.name == name
            assert cls not in plugins.INSTALLED  # zipon's own: their errors keep their tracebacks
        assert resolve("nobody_registers_this") is None


def test_a_reader_failing_in_detect_is_skipped_with_a_warning_and_the_built_in_readers_answer(hostile, tmp_path,
                                                                                              caplog):
    from pipeline.readers import detect_format

    folder = write_tum(tmp_path / "raw", make_recording())
    with caplog.at_level(logging.WARNING, logger="zipon.plugins"):
        assert detect_format(folder) == "tum"
    warned = [r.getMessage() for r in caplog.records if r.name == "zipon.plugins"]
    assert warned == [f"{named(plugins.READERS_GROUP, 'detect_raises')}: detect failed: PermissionError: cannot "
                      f"peek into {folder}; skipped"]


def test_an_agent_calling_argparse_at_import_is_one_line_and_exit_1(hostile, built_scene, tmp_path, capsys):
    ws, _ = built_scene
    code = main(_cli(ws, "eval", "-o", str(tmp_path / "out"), "-m", "argparse_agent", "-f", "yesno", "--seeds", "1"))
    err = one_line(capsys)
    assert code == 1 and not (tmp_path / "out" / "results.json").exists()
    assert f"agent 'argparse_agent': {named(plugins.AGENTS_GROUP, 'argparse_agent')}: import failed: SystemExit(2)" in err
    assert "(it printed: greedy-agent: error: unrecognized arguments: --required-flag-missing)" in err


def test_an_agent_exiting_while_it_runs_is_one_line_and_exit_1(hostile, built_scene, tmp_path, capsys):
    ws, _ = built_scene
    code = main(_cli(ws, "eval", "-o", str(tmp_path / "out"), "-m", "exiting", "-f", "yesno", "--seeds", "1"))
    err = one_line(capsys)
    assert code == 1 and not (tmp_path / "out" / "results.json").exists()
    assert err.endswith(f"{named(plugins.AGENTS_GROUP, 'exiting')}: run failed: SystemExit('agent: done')")


def test_the_library_entry_evaluates_an_installed_agent_named_in_eval_methods(hostile, built_scene, tmp_path):
    """``orion_eval.run.evaluate`` (no zipon.evaluate in between) resolves ``eval.methods`` through the registry."""
    from orion_eval.run import evaluate
    from stages import STAGES

    ws, params = built_scene
    params = params.model_copy(update={"eval": params.eval.model_copy(update={"methods": ["nearest_plugin"],
                                                                              "feedback": ["yesno"]})})
    res = evaluate(ws, params, STAGES, tmp_path / "lib", seeds=[0], progress=False, report=False)
    assert list(res["overall"]) == ["nearest_plugin"] and res["overall"]["nearest_plugin"]["yesno"]["episodes"] > 0
    with pytest.raises(ConfigError, match=r"eval.methods: unknown method\(s\) \['nobody'\]; choose from \[.*'human'.*\] "
                                          r"or the installed \['argparse_agent', 'exiting', 'nearest_plugin'\]"):
        evaluate(ws, params.model_copy(update={"eval": params.eval.model_copy(update={"methods": ["nobody"]})}),
                 STAGES, tmp_path / "lib2", seeds=[0], progress=False, report=False)


def test_a_reader_failing_mid_stream_fails_the_ingest_naming_it(hostile, tmp_path, capsys):
    root = tmp_path / "ws"
    root.mkdir()
    (root / "params.yaml").write_text("scenes: {}\n")
    log = write_mcap(tmp_path / "rec.user.mcap", make_recording())
    code = main(["-q", "-p", str(root / "params.yaml"), "--data-dir", str(root / "data"), "--manifests-dir",
                 str(root / "manifests"), "ingest", str(log), "-s", "rec", "--format", "samples_raise"])
    out = capsys.readouterr()
    assert code == 1 and "Traceback" not in out.out + out.err
    assert (f"{named(plugins.READERS_GROUP, 'samples_raise')}: samples failed: KeyError: \"topic '/cam/depth' "
            "vanished\"") in " ".join((out.out + out.err).split())
    assert not (root / "data" / "artifacts" / "rec" / "frames.zarr").exists()


def test_an_encoder_failing_in_its_forward_pass_is_named(hostile):
    import numpy as np

    from pipeline.config import EncodersParams
    from pipeline.encoders import build_encoder

    encoder = build_encoder(EncodersParams(plugins={"encode_raises": {}}), "encode_raises")
    with pytest.raises(PluginError) as err:
        encoder.encode_images(np.zeros((1, 16, 16, 3), np.uint8))
    assert str(err.value) == (f"{named(plugins.ENCODERS_GROUP, 'encode_raises')}: encode_images failed: "
                              "RuntimeError: CUDA error: out of memory")


def test_zipon_s_own_errors_raised_by_a_plug_in_pass_as_they_are():
    """A plug-in raising zipon's InputDataError on purpose (a file it names) keeps that message and class."""
    from importlib.metadata import EntryPoint

    from pipeline.errors import InputDataError

    class Mine:
        pass

    plugins.INSTALLED[Mine] = EntryPoint("mine", "pkg.mod:Mine", plugins.READERS_GROUP)
    try:
        with pytest.raises(InputDataError, match="file x.log: bad header"):
            with plugins.running(Mine, "open"):
                raise InputDataError("bad header", path="x.log")
        with pytest.raises(PluginError, match=r"zipon.readers entry point 'mine' \(pkg.mod:Mine\) of package 'an "
                                              r"unknown package': open failed: ValueError: nope"):
            with plugins.running(Mine, "open"):
                raise ValueError("nope")
    finally:
        plugins.INSTALLED.pop(Mine)
