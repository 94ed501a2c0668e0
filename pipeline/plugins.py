"""Entry points of installed packages that extend zipon (a leaf module: it imports nothing of zipon).

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


def names(group: str) -> list[str]:
    """Names registered in entry-point ``group`` by the installed packages (sorted)."""
    from importlib.metadata import entry_points  # read on use: the CLI starts without it

    return sorted({ep.name for ep in entry_points(group=group)})


def reader_names() -> list[str]:
    """Every dataset format zipon can read: the built-in readers, then those installed packages register (sorted)."""
    return list(BUILT_IN_READERS) + [name for name in names(READERS_GROUP) if name not in BUILT_IN_READERS]


def entry(group: str, name: str) -> EntryPoint | None:
    """The entry point ``name`` of ``group`` (a built-in reader's declaration first), or None when no installed package
    registers it."""
    if group == READERS_GROUP and name in BUILT_IN_READERS:
        from importlib.metadata import EntryPoint

        return EntryPoint(name, BUILT_IN_READERS[name], group)
    from importlib.metadata import entry_points

    found = list(entry_points(group=group, name=name))
    return found[0] if found else None


def load_class(group: str, name: str, base: type, base_label: str, kind: str) -> type | None:
    """The class entry point ``name`` of ``group`` registers, checked to be a subclass of ``base`` whose ``name``
    attribute is ``name``; None when no installed package registers ``name``. Raises ConfigError naming the entry
    point when it does not load or does not fit."""
    from pipeline.errors import ConfigError

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
    return cls
