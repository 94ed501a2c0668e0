"""The config of a map stage (``vlmap`` / ``cfmap``): which ``maps`` settings and which encoder settings a map's
params digest covers. Kept apart from :mod:`pipeline.maps.build` so that reading a stage's config (``zipon status``)
imports neither numpy nor the frame store."""

from __future__ import annotations

from enum import Enum
from typing import ClassVar

from pipeline.config import EncodersParams, MapsParams, Params
from pipeline.stageconfig import StageConfig, section_keys


class MapKind(str, Enum):
    """The two kinds of semantic map, one stage each; the value is the stage's (and params section's) name."""

    VLMAP = "vlmap"  # pixel features fused straight into the top-down cells (VLMaps)
    CFMAP = "cfmap"  # fused into sparse 3-D voxels, then projected top-down (ConceptFusion)

    def __str__(self) -> str:
        return self.value

    @property
    def fuses_voxels(self) -> bool:
        """Whether the map is fused in 3-D voxels (then projected by the height rule) rather than in cells."""
        return self is MapKind.CFMAP

    @property
    def own_fields(self) -> tuple[str, ...]:
        """The ``maps.*`` fields only this kind of map reads."""
        return KIND_FIELDS[self]

    def weight_sigma_m(self, p: MapsParams) -> float:
        """This kind's confidence-weight sigma (``maps.<kind>_weight_sigma_m``)."""
        return p.cfmap_weight_sigma_m if self is MapKind.CFMAP else p.vlmap_weight_sigma_m


# maps.* fields that only one kind of map reads
KIND_FIELDS: dict[MapKind, tuple[str, ...]] = {MapKind.VLMAP: ("vlmap_weight_sigma_m",),
                                               MapKind.CFMAP: ("cfmap_weight_sigma_m", "cfmap_voxels")}


class MapConfig(StageConfig):
    """Config of a map stage (``vlmap`` / ``cfmap``: set ``kind``): the ``maps`` fusion settings this kind reads,
    and the encoder it uses with that encoder's own settings only (``encoders.lseg.crop_size`` is not part of a
    ConceptFusion map). Query settings (``query``) and devices, batch sizes, threads (``run``) are in no digest."""

    kind: ClassVar[MapKind]
    maps: MapsParams
    encoder: str
    encoders: EncodersParams

    @classmethod
    def _other_fields(cls) -> tuple[str, ...]:
        return tuple(f for k in MapKind if k is not cls.kind for f in k.own_fields)

    @classmethod
    def _encoder(cls, params: Params, scene: str) -> tuple[str, list[str]]:
        """(encoder name, the params keys that choose it and configure it)."""
        from pipeline.encoders.choice import encoder_choice

        enc = params.encoders
        simulated = params.scenes[scene].simulated
        name = encoder_choice(enc, cls.kind.value, simulated=simulated)
        keys = ["encoders.simulated"] if simulated else []
        if not (simulated and enc.simulated is not None):
            keys.append(f"encoders.{cls.kind.value}")
        if (key := enc.settings_key(name)) is not None:  # a built-in's section or a plug-in's entry alike
            keys.append(key)
        return name, keys

    @classmethod
    def param_keys(cls, params: Params, scene: str) -> list[str]:
        return section_keys("maps", MapsParams, exclude=cls._other_fields()) + cls._encoder(params, scene)[1]

    @classmethod
    def from_params(cls, params: Params, scene: str) -> "MapConfig":
        name, _ = cls._encoder(params, scene)
        defaults = MapsParams()
        maps = params.maps.model_copy(update={f: getattr(defaults, f) for f in cls._other_fields()})
        return cls(maps=maps, encoder=name, encoders=params.encoders.only(name))

    @classmethod
    def extra_inputs(cls, params: Params, scene: str) -> dict[str, str]:
        """A plugin encoder's source (package folder or module file): its code is outside zipon's import
        closure, so its content is hashed as an input of the map."""
        from pipeline.encoders.choice import plugin_source

        source = plugin_source(cls._encoder(params, scene)[0])
        return {"encoder_plugin": source} if source else {}


class VlmapConfig(MapConfig):
    kind = MapKind.VLMAP


class CfmapConfig(MapConfig):
    kind = MapKind.CFMAP


MAP_CONFIGS: dict[str, type[MapConfig]] = {cfg.kind.value: cfg for cfg in (VlmapConfig, CfmapConfig)}
