"""Entry points of installed packages that extend zipon (a leaf module: it imports nothing of zipon).

Groups: ``zipon.encoders`` (name = "module:EncoderSubclass", see :mod:`pipeline.encoders.choice`) and
``zipon.agents`` (name = "module:AgentSubclass", see :mod:`zipon.evaluate`).
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points

ENCODERS_GROUP = "zipon.encoders"


def names(group: str) -> list[str]:
    """Names registered in entry-point ``group`` by the installed packages (sorted)."""
    return sorted({ep.name for ep in entry_points(group=group)})


def entry(group: str, name: str) -> EntryPoint | None:
    """The entry point ``name`` of ``group``, or None when no installed package registers it."""
    found = list(entry_points(group=group, name=name))
    return found[0] if found else None
