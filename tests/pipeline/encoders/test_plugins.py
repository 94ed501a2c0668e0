"""Third-party encoders through the ``zipon.encoders`` entry points: chosen by name in params, their settings
and code part of a map's digest, a map built with one answers queries; broken registrations are named."""

import numpy as np
import pytest

from pipeline.paramsfile import parse_params
from pipeline.encoders.choice import load, plugin_names
from pipeline.errors import ConfigError
from pipeline.maps.build import build_map
from pipeline.maps.config import MAP_CONFIGS
from pipeline.maps.store import SemanticMap
from pipeline.recon import Recon
from pipeline.recon.build import reconstruct
from pipeline.store import artifact_attrs
from tests.fixtures.recon_scenes import write_box_room_frames
from tests.fixtures.user_agents import plugin_distribution
from tests.fixtures.user_encoders import COLOURS, ColourWords


@pytest.fixture
def plugins(tmp_path, monkeypatch):
    plugin_distribution(tmp_path / "site", {
        "colour_words": "tests.fixtures.user_encoders:ColourWords",
        "broken": "tests.fixtures.no_such_module:Encoder",
        "not_an_encoder": "json:dumps",
        "misnamed": "tests.fixtures.user_agents:NearestOnly",
    }, group="zipon.encoders")
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    yield tmp_path
    from pipeline.encoders.base import ENCODERS

    ENCODERS.pop("colour_words", None)


def _params(**encoders):
    return parse_params({"scenes": {"box": {"source": "simulate"}}, "grid": {"rows": 100, "cols": 160},
                         "encoders": encoders})


def test_registrations_resolve_and_bad_ones_are_named(plugins):
    from pipeline.encoders.base import ENCODERS

    assert {"colour_words", "broken", "misnamed"} <= set(plugin_names())
    load("colour_words")
    assert ENCODERS["colour_words"] is ColourWords
    with pytest.raises(ConfigError, match=r"zipon.encoders entry point 'broken' \(tests.fixtures.no_such_module:Encoder\) of package "
                                          r"'zipon-example-encoders': import failed: ModuleNotFoundError"):
        load("broken")
    with pytest.raises(ConfigError, match="is not a subclass of pipeline.encoders.base.Encoder"):
        load("not_an_encoder")
    with pytest.raises(ConfigError, match="is not a subclass"):
        load("misnamed")


def test_params_name_plugins_and_their_settings_are_in_the_map_digest(plugins):
    with pytest.raises(ConfigError, match=r"encoders.vlmap: unknown encoder 'colour_wordz'.*installed plugins"):
        _params(vlmap="colour_wordz")
    p = _params(simulated="colour_words", plugins={"colour_words": {"sharpness": 10.0}})
    cls = MAP_CONFIGS["vlmap"]
    assert "encoders.plugins.colour_words" in cls.param_keys(p, "box")
    assert cls.from_params(p, "box").encoders.plugins == {"colour_words": {"sharpness": 10.0}}
    source = cls.extra_inputs(p, "box")["encoder_plugin"]
    assert source.endswith("tests")  # the plugin's package: its code is hashed as an input of the map
    assert cls.from_params(_params(simulated="oracle"), "box").encoders.plugins == {}


def test_a_map_built_with_a_plugin_encoder_reads_the_scene_colours(plugins, tmp_path):
    frames, _ = write_box_room_frames(tmp_path / "frames.zarr", n_frames=32)
    p = _params(simulated="colour_words", plugins={"colour_words": {"sharpness": 30.0}})
    reconstruct(frames, tmp_path / "recon.zarr", tmp_path / "recon_mesh.ply", tmp_path / "recon_points.ply",
                p.reconstruct, p.grid)
    build_map(MAP_CONFIGS["vlmap"].from_params(p, "box"), frames, tmp_path / "recon.zarr", tmp_path / "vlmap.zarr",
              artifact_attrs("vlmap", 1, "vlmap", "t"))
    m = SemanticMap(tmp_path / "vlmap.zarr")
    assert m.encoder["name"] == "colour_words" and m.dim == 8
    # each cell's strongest colour word is the colour word nearest to recon's colour of that cell
    recon = Recon(tmp_path / "recon.zarr")
    rows, cols = np.unravel_index(m.cell, (recon.grid.rows, recon.grid.cols))
    colour = recon.color[rows, cols].astype(np.float32) / 255.0
    protos = np.array(list(COLOURS.values()), np.float32) / 255.0
    nearest = ((colour[:, None, :] - protos[None]) ** 2).sum(-1).argmin(1)
    feats = np.asarray(m.features(), np.float32)
    agree = (feats[:, : len(COLOURS)].argmax(1) == nearest).mean()
    assert agree > 0.8, agree


def test_plugin_settings_are_read_through_the_class_the_plugin_declares(plugins):
    assert ColourWords.settings(_params(plugins={"colour_words": {}}).encoders).sharpness == 20.0
    assert ColourWords.settings(_params(plugins={"colour_words": {"sharpness": 5}}).encoders).sharpness == 5.0
    with pytest.raises(ConfigError, match=r"encoders.plugins: colour_words.sharpness: expected a number, got the string .sharp."):
        _params(plugins={"colour_words": {"sharpness": "sharp"}})
    with pytest.raises(ConfigError, match=r"encoders.plugins: colour_wordz: settings for an encoder no installed "):
        _params(plugins={"colour_wordz": {"sharpness": 1.0}})
    with pytest.raises(ConfigError, match=r"zipon.encoders entry point 'broken' \(tests.fixtures.no_such_module:Encoder\) of package "
                                          r"'zipon-example-encoders': import failed: ModuleNotFoundError"):
        _params(plugins={"broken": {}})
