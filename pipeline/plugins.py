"""Entry points of installed packages that extend zipon, and zipon's own extensions declared the same way (a leaf
module: it imports nothing of zipon).

Groups: ``zipon.encoders`` (name = "module:EncoderSubclass", see :mod:`pipeline.encoders.choice`),
``zipon.agents`` (name = "module:AgentSubclass", see :mod:`zipon.evaluate`) and ``zipon.readers``
(name = "module:ReaderSubclass", see :mod:`pipeline.readers.base`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

#: the entry-point groups installed packages register their extensions in (their one home)
ENCODERS_GROUP = "zipon.encoders"
AGENTS_GROUP = "zipon.agents"
READERS_GROUP = "zipon.readers"

#: zipon's own dataset readers, declared the way a package declares its ``zipon.readers`` entry points: with the
#: installed ones they are the reader registry, and their names are known without importing any reader
BUILT_IN_READERS = {
    "mcap": "pipeline.readers.mcap:McapReader", "rosbag": "pipeline.readers.rosbag:RosbagReader",
    "tum": "pipeline.readers.tum:TumReader", "7scenes": "pipeline.readers.sevenscenes:SevenScenesReader",
    "navchat": "pipeline.readers.navchat:NavchatReader", "replica": "pipeline.readers.replica:ReplicaReader",
    "scannet": "pipeline.readers.scannet:ScanNetReader",
}

#: zipon's own encoders, declared like the readers above: with the installed ``zipon.encoders`` they are the encoder
#: registry, and their names (for the params' validation, ``zipon params``) are known without importing torch
BUILT_IN_ENCODERS = {
    "lseg": "pipeline.encoders.lseg:LSegEncoder", "maskclip": "pipeline.encoders.maskclip:MaskClipEncoder",
    "conceptfusion": "pipeline.encoders.conceptfusion:ConceptFusionEncoder",
    "torchscript": "pipeline.encoders.torchscript:TorchScriptEncoder", "oracle": "pipeline.encoders.oracle:OracleEncoder",
    "simulated_lseg": "pipeline.encoders.perception:SimulatedLSeg",
    "simulated_cf": "pipeline.encoders.perception:SimulatedCF",
}

#: each group's built-in declarations
BUILT_IN = {READERS_GROUP: BUILT_IN_READERS, ENCODERS_GROUP: BUILT_IN_ENCODERS}


def names(group: str) -> list[str]:
    """Names registered in entry-point ``group`` by the installed packages (sorted)."""
    from importlib.metadata import entry_points  # read on use: the CLI starts without it

    return sorted({ep.name for ep in entry_points(group=group)})


def registered(group: str) -> list[str]:
    """Every name of ``group``: zipon's own (in their declared order), then those installed packages register (sorted)."""
    own = BUILT_IN.get(group, {})
    return list(own) + [name for name in names(group) if name not in own]


def reader_names() -> list[str]:
    """Every dataset format zipon can read: the built-in readers, then those installed packages register (sorted)."""
    return registered(READERS_GROUP)


def encoder_names() -> list[str]:
    """Every encoder zipon can build: the built-in encoders, then those installed packages register (sorted)."""
    return registered(ENCODERS_GROUP)


def entry(group: str, name: str) -> EntryPoint | None:
    """The entry point ``name`` of ``group`` (a built-in declaration first), or None when neither zipon nor an installed
    package registers it."""
    if name in BUILT_IN.get(group, {}):
        from importlib.metadata import EntryPoint

        return EntryPoint(name, BUILT_IN[group][name], group)
    from importlib.metadata import entry_points

    found = list(entry_points(group=group, name=name))
    return found[0] if found else None


def load_class(group: str, name: str, base: type, base_label: str, kind: str, loaded: dict | None = None
               ) -> type | None:
    """The class entry point ``name`` of ``group`` registers, checked to be a subclass of ``base`` whose ``name``
    attribute is ``name``; None when neither zipon nor an installed package registers ``name``. Raises ConfigError
    naming the entry point when it does not load or does not fit. ``loaded``: the classes loaded so far by name, where
    a class is looked up first and kept once loaded."""
    from pipeline.errors import ConfigError

    if loaded is not None and name in loaded:
        return loaded[name]
    ep = entry(group, name)
    if ep is None:
        return None
    try:
        cls = ep.load()
    except Exception as err:  # noqa: BLE001 - any import failure of a third-party package is reported the same way
        raise ConfigError(f"{kind} {name!r}: entry point {ep.value!r} ({group}) failed to load: "
                          f"{type(err).__name__}: {err}") from None
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise ConfigError(f"{kind} {name!r}: entry point {ep.value!r} ({group}) is not a subclass of {base_label}")
    if getattr(cls, "name", None) != name:
        raise ConfigError(f"{kind} {name!r}: entry point {ep.value!r} names a class whose `name` is "
                          f"{getattr(cls, 'name', None)!r}; they must agree")
    if loaded is not None:
        loaded[name] = cls
    return cls
