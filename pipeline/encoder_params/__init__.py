"""The ``encoders`` section of ``params.yaml``: which encoder each map stage uses, each built-in encoder's settings
(its ``params_model``, one torch-free module per encoder named after the encoder's module: ``lseg`` for
:mod:`pipeline.encoders.lseg`) and installed plug-ins' settings (``plugins``, checked against the ``params_model``
each declares). A package of leaves, apart from :mod:`pipeline.encoders` (whose package imports the encoders): the
params schema imports it on every command, and a stage's code is not every encoder's."""

from __future__ import annotations

from typing import Any

from pydantic import Field, field_validator

from pipeline.encoder_params.conceptfusion import ConceptFusionParams
from pipeline.encoder_params.lseg import LSegParams
from pipeline.encoder_params.maskclip import MaskClipParams
from pipeline.encoder_params.oracle import OracleParams
from pipeline.encoder_params.perception import SimulatedCFParams, SimulatedLSegParams
from pipeline.encoder_params.torchscript import TorchScriptParams
from pipeline.section import Section


class EncodersParams(Section):
    """Open-vocabulary pixel/text encoders used by the map stages and the evaluator.

    No weights are ever downloaded: a real encoder without a ``weights`` file is a ConfigError.
    The oracle is a diagnostic built from ground truth; it runs only where chosen explicitly.
    """

    vlmap: str = Field("lseg", description="encoder of the vlmap stage (VLMaps uses lseg); a built-in name or "
                       "one an installed package registers in the zipon.encoders entry points")
    cfmap: str = Field("conceptfusion", description="encoder of the cfmap stage (built-in or plugin, as vlmap)")
    simulated: str | None = Field(
        "perception",
        description="encoder used INSTEAD of vlmap/cfmap for simulated scenes: 'perception' = simulated perception "
        "models (simulated_lseg for the vlmap, simulated_cf for the cfmap), 'oracle' = the ground-truth DIAGNOSTIC "
        "(perfect features, an upper bound, labelled so in every result); None = simulated scenes use vlmap/cfmap "
        "like real ones",
    )
    lseg: LSegParams = LSegParams()
    maskclip: MaskClipParams = MaskClipParams()
    conceptfusion: ConceptFusionParams = ConceptFusionParams()
    torchscript: TorchScriptParams = TorchScriptParams()
    oracle: OracleParams = OracleParams()
    simulated_lseg: SimulatedLSegParams = SimulatedLSegParams()
    simulated_cf: SimulatedCFParams = SimulatedCFParams()
    plugins: dict[str, dict[str, Any]] = Field(
        default_factory=dict, description="plugin encoder name -> its settings, checked against the params class the "
        "plugin declares (its params_model); part of a map's digest when the map uses that plugin"
    )

    @field_validator("plugins")
    @classmethod
    def _plugin_settings(cls, plugins: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        """Each plugin's settings validated by the class its encoder declares (importing the plugin's module; whether
        it is an Encoder is checked when it is built)."""
        from pydantic import ValidationError

        from pipeline import plugins as registry

        for name, settings in plugins.items():
            encoder = registry.load_class(registry.ENCODERS_GROUP, name, object, "a class", "encoder")
            if encoder is None:
                raise ValueError(f"{name}: settings for an encoder no installed package registers (zipon.encoders "
                                 "entry points)")
            if getattr(encoder, "params_model", None) is None:
                raise ValueError(f"{name}: the encoder takes no settings (it declares no params_model)")
            try:
                encoder.params_model.model_validate(settings)
            except ValidationError as err:
                e = err.errors()[0]
                where = ".".join(map(str, (name, *e["loc"])))
                raise ValueError(f"{where}: {e['msg'].removeprefix('Value error, ')}") from None
        return plugins

    @field_validator("vlmap", "cfmap", "simulated")
    @classmethod
    def _known_encoder(cls, name: str | None) -> str | None:
        from pipeline import plugins

        # 'perception': simulated_lseg for the vlmap, simulated_cf for the cfmap
        built_in = [*plugins.BUILT_IN_ENCODERS, "perception"]
        if name is None or name in built_in:  # known without reading the installed packages
            return name
        installed = plugins.names(plugins.ENCODERS_GROUP)
        if name not in installed:
            raise ValueError(f"unknown encoder {name!r}: built-in {built_in}, installed plugins "
                             f"(zipon.encoders entry points) {installed}")
        return name

    def settings_key(self, name: str) -> str | None:
        """The params key of encoder ``name``'s settings, whoever declares it: ``encoders.<name>`` for zipon's own
        (the section of its ``params_model``), ``encoders.plugins.<name>`` for an installed one's when set, None when
        it has none."""
        if name in type(self).model_fields and name not in ("vlmap", "cfmap", "simulated", "plugins"):
            return f"encoders.{name}"
        return f"encoders.plugins.{name}" if name in self.plugins else None

    def only(self, name: str) -> "EncodersParams":
        """This section with encoder ``name``'s settings only, every other key at its default: what a map built with
        ``name`` depends on (``encoders.lseg.crop_size`` is not part of a ConceptFusion map)."""
        key = self.settings_key(name)
        if key is None:
            return type(self)()
        if key.startswith("encoders.plugins."):
            return type(self)(plugins={name: self.plugins[name]})
        return type(self)(**{name: getattr(self, name)})
