"""One installed third-party package extending zipon three ways (a dataset reader, an encoder, an agent through the
``zipon.readers``, ``zipon.encoders`` and ``zipon.agents`` entry points): a scene read by its reader, mapped with
its encoder and evaluated with its agent, by name from params and the CLI."""

import json

import pytest

from pipeline import plugins
from pipeline.errors import ConfigError
from pipeline.frames import FrameStore
from pipeline.maps.store import SemanticMap
from pipeline.paramsfile import parse_params
from pipeline.paths import Workspace
from pipeline.readers import detect_format
from tests.fixtures.user_agents import PluginNearest, plugin_package
from tests.fixtures.user_readers import UserLog
from zipon.cli import main

PARAMS = """\
scenes:
  tiny: {source: simulate, format: user_log}
simulate: {frames: 80, width: 160, height: 120, rooms_min: 2, rooms_max: 2}
reconstruct: {voxel_size_m: 0.05}
encoders: {simulated: colour_words, plugins: {colour_words: {sharpness: 20.0}}}
goals: {max_goals: 4}
routes: {episodes_per_goal: 1}
eval: {workers: 1, seeds: [0]}
"""


@pytest.fixture
def package(tmp_path, monkeypatch):
    plugin_package(tmp_path / "site", "zipon-example-extensions", {
        plugins.READERS_GROUP: {"user_log": "tests.fixtures.user_readers:UserLog"},
        plugins.ENCODERS_GROUP: {"colour_words": "tests.fixtures.user_encoders:ColourWords"},
        plugins.AGENTS_GROUP: {"nearest_plugin": "tests.fixtures.user_agents:PluginNearest"},
    })
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    yield tmp_path
    from pipeline.encoders.base import ENCODERS
    from pipeline.readers import READERS

    from orion_eval.agents import AGENTS

    ENCODERS.pop("colour_words", None)
    READERS.pop("user_log", None)
    AGENTS.pop("nearest_plugin", None)


def test_a_reader_name_no_package_registers_is_refused_at_load():
    with pytest.raises(ConfigError, match=r"scenes.tiny.format: .*unknown format 'user_log'.*\['mcap', 'rosbag'"):
        parse_params({"scenes": {"tiny": {"source": "simulate", "format": "user_log"}}})


def test_the_package_reader_is_in_the_registry_and_its_layout_in_the_detection_message(package, tmp_path):
    assert plugins.reader_names()[-1] == "user_log" and "user_log" not in plugins.BUILT_IN_READERS
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(Exception, match=r"a user's recorder log \(\*\.user\.mcap\) \(user_log\)"):
        detect_format(tmp_path)


def test_ingest_map_and_eval_with_the_package_reader_encoder_and_agent(package, tmp_path):
    root = tmp_path / "ws"
    root.mkdir()
    (root / "params.yaml").write_text(PARAMS)
    cli = ["-q", "-p", str(root / "params.yaml"), "--data-dir", str(root / "data"), "--manifests-dir",
           str(root / "manifests")]
    assert main([*cli, "run"]) == 0
    ws = Workspace.resolve(root / "params.yaml", data_dir=root / "data", manifests_dir=root / "manifests")
    provenance = FrameStore(ws.artifact("frames", "tiny")).attrs["provenance"]
    assert (provenance["format"], provenance["reader"]) == ("user_log", UserLog.__name__)
    assert SemanticMap(ws.artifact("vlmap", "tiny")).encoder["name"] == "colour_words"
    assert main([*cli, "eval", "-o", str(tmp_path / "eval"), "-m", "nearest_plugin", "-f", "yesno"]) == 0
    results = json.loads((tmp_path / "eval" / "results.json").read_text())
    assert list(results["overall"]) == [PluginNearest.name]
    assert results["overall"][PluginNearest.name]["yesno"]["episodes"] == len(results["episodes"]) > 0


@pytest.mark.parametrize("setting, message", [
    ("sharpness: -1.0", "encoders.plugins: colour_words.sharpness: Input should be greater than 0"),
    ("sharpnes: 20.0", "encoders.plugins: colour_words.sharpnes: Extra inputs are not permitted"),
])
def test_the_package_encoder_settings_are_checked_by_the_class_it_declares(package, tmp_path, capsys, setting,
                                                                           message):
    root = tmp_path / "ws"
    root.mkdir()
    (root / "params.yaml").write_text(PARAMS.replace("sharpness: 20.0", setting))
    assert main(["-p", str(root / "params.yaml"), "status"]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert err.endswith(message) and str(root / "params.yaml") in err
