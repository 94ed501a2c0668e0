"""Choosing and loading encoders by name: stage configs need no torch, one encoder loads one module."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.config import EncodersParams
from pipeline import plugins
from pipeline.encoders.choice import encoder_choice, load
from pipeline.errors import ConfigError

ROOT = Path(__file__).resolve().parents[3]


def _modules_after(code: str) -> dict:
    probe = (f"import sys, json\n{code}\n"
             "print(json.dumps({m: m in sys.modules for m in ('torch', 'torchvision', 'open_clip')}))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_stage_configs_name_their_encoder_without_importing_torch():
    got = _modules_after(
        "from pipeline.config import Params\n"
        "from pipeline.maps.config import VlmapConfig, CfmapConfig\n"
        "import stages.vlmap, stages.cfmap, pipeline.maps\n"
        "p = Params.model_validate({'scenes': {'s': {'source': 'simulate'}}, 'encoders': {'simulated': 'oracle'}})\n"
        "assert VlmapConfig.from_params(p, 's').encoder == 'oracle'\n"
        "assert 'encoders.oracle' in CfmapConfig.param_keys(p, 's')")
    assert got == {"torch": False, "torchvision": False, "open_clip": False}


def test_building_one_encoder_imports_only_its_module():
    got = _modules_after("from pipeline.config import EncodersParams\nfrom pipeline.encoders import build_encoder\n"
                         "build_encoder(EncodersParams(), 'oracle')")
    assert got == {"torch": True, "torchvision": False, "open_clip": False}


def test_every_declared_name_loads_its_class_and_unknown_names_are_config_errors():
    from pipeline.encoders import ENCODERS

    load()
    assert set(ENCODERS) == set(plugins.BUILT_IN_ENCODERS)
    for name, cls in ENCODERS.items():
        assert f"{cls.__module__}:{cls.__qualname__}" == plugins.BUILT_IN_ENCODERS[name] and cls.name == name
    with pytest.raises(ConfigError, match=r"'nope': unknown \(choose one of \['lseg', .*'simulated_cf'\]"):
        encoder_choice(EncodersParams(), "nope")


def test_the_params_accept_every_declared_encoder_and_refuse_others_naming_them():
    for name in [*plugins.BUILT_IN_ENCODERS, "perception"]:
        assert EncodersParams(vlmap=name).vlmap == name
    with pytest.raises(ValueError, match=r"unknown encoder 'lsegg': built-in \['lseg', 'maskclip', .*'perception'\]"):
        EncodersParams(cfmap="lsegg")


def test_each_built_in_encoder_declares_the_class_of_its_params_section():
    from pipeline.encoders import ENCODERS

    load()
    defaults = EncodersParams()
    for name, cls in ENCODERS.items():
        assert EncodersParams.model_fields[name].annotation is cls.params_model
        assert cls.settings(defaults) is getattr(defaults, name)
