"""Entry points of installed packages that extend zipon (a leaf module: it imports nothing of zipon).

Groups: ``zipon.encoders`` (name = "module:EncoderSubclass", see :mod:`pipeline.encoders.choice`) and
``zipon.agents`` (name = "module:AgentSubclass", see :mod:`zipon.evaluate`).
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points

#: the entry-point groups installed packages register their extensions in (their one home)
ENCODERS_GROUP = "zipon.encoders"
AGENTS_GROUP = "zipon.agents"


def names(group: str) -> list[str]:
    """Names registered in entry-point ``group`` by the installed packages (sorted)."""
    return sorted({ep.name for ep in entry_points(group=group)})


def entry(group: str, name: str) -> EntryPoint | None:
    """The entry point ``name`` of ``group``, or None when no installed package registers it."""
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
