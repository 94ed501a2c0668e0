"""The ``encoders`` section: each built-in encoder's settings are its ``params_model``, declared in a torch-free module
named after it (as an installed encoder declares its own), and one rule says where any encoder's settings are."""

import subprocess
import sys

import pytest

from pipeline import plugins
from pipeline.encoders.choice import encoder_class
from pipeline.encoder_params import EncodersParams
from pipeline.errors import ConfigError
from tests.fixtures.fresh_process import ROOT


@pytest.mark.parametrize("name", list(plugins.BUILT_IN_ENCODERS))
def test_a_built_in_encoder_s_section_is_its_params_model_declared_beside_it(name):
    cls = encoder_class(name)
    assert EncodersParams.model_fields[name].annotation is cls.params_model
    # pipeline/encoders/lseg.py -> pipeline/encoder_params/lseg.py
    assert cls.params_model.__module__ == f"pipeline.encoder_params.{cls.__module__.rsplit('.', 1)[1]}"
    assert EncodersParams().settings_key(name) == f"encoders.{name}"


def test_the_settings_modules_and_the_schema_import_no_torch():
    modules = sorted({encoder_class(n).params_model.__module__ for n in plugins.BUILT_IN_ENCODERS})
    probe = ("import sys\n" + "".join(f"import {m}\n" for m in modules) + "import pipeline.config\n"
             "print(sorted(m for m in ('torch', 'open_clip', 'numpy') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_where_an_encoder_s_settings_are_and_what_a_map_keeps_of_them():
    from pipeline.paramsfile import parse_params

    enc = parse_params({"scenes": {}, "encoders": {"lseg": {"crop_size": 320},
                                                   "conceptfusion": {"softmax_temperature": 0.5}}}).encoders
    assert enc.only("lseg") == EncodersParams(lseg=enc.lseg) and enc.only("lseg").lseg.crop_size == 320
    assert enc.only("lseg").conceptfusion == EncodersParams().conceptfusion  # another encoder's settings: defaults
    assert enc.settings_key("nobody") is None and enc.only("nobody") == EncodersParams()
    for field in ("vlmap", "cfmap", "simulated", "plugins"):  # choices, not an encoder's settings
        assert enc.settings_key(field) is None
    with pytest.raises(ConfigError, match="encoders.plugins: ghost: settings for an encoder no installed package"):
        parse_params({"scenes": {}, "encoders": {"plugins": {"ghost": {}}}})
