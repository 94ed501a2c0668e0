"""The one plug-in mechanism: entry points of installed packages that extend zipon, and zipon's own extensions
declared the same way (a leaf module: it imports nothing of zipon but its errors).

Groups: ``zipon.readers`` (name = "module:ReaderSubclass", see :mod:`pipeline.readers.base`), ``zipon.encoders``
(name = "module:EncoderSubclass", see :mod:`pipeline.encoders.choice`) and ``zipon.agents`` (name =
"module:AgentSubclass", see :mod:`orion_eval.agents.base`). Each family's registry is its built-in declarations
here plus what installed packages register; every caller (the CLI, ``zipon.run_eval``, ``orion_eval.run``, the
workbench, the stages) resolves a name through :func:`load_class`.

A plug-in is isolated: any exception or ``SystemExit`` while importing it (:func:`load_class`) or running it
(:func:`running`) becomes one :class:`~pipeline.errors.PluginError` naming the entry point and the package that
registers it (the CLI prints that line and exits 1); zipon's own errors a plug-in raises on purpose
(:class:`~pipeline.errors.ZiponError`: a malformed file it names) pass as they are. A reader whose ``detect`` fails
is skipped with a warning (:func:`detects`), so the other readers still answer.
"""

from __future__ import annotations

import contextlib
import io
import logging
import sys
from contextlib import contextmanager
from typing import TYPE_CHECKING, Iterator

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

#: zipon's own agents, declared like the readers above, in the paper's table order (then its ablations and the LLM's):
#: with the installed ``zipon.agents`` they are the agent registry
BUILT_IN_AGENTS = {
    "human": "orion_eval.agents.human:HumanAgent", "cow": "orion_eval.agents.cow:CowAgent",
    "vlmap": "orion_eval.agents.maps:VLMapAgent", "cf": "orion_eval.agents.maps:CFAgent",
    "orion": "orion_eval.agents.orion:OrionAgent", "orion_wo_mem": "orion_eval.agents.orion:OrionWithoutMemory",
    "orion_wo_exp": "orion_eval.agents.orion:OrionWithoutExploration",
    "orion_wo_det": "orion_eval.agents.orion:OrionWithoutDetection",
    "orion_wo_map": "orion_eval.agents.orion:OrionWithoutMap", "llm": "orion_eval.agents.llm:LLMAgent",
}

#: each group's built-in declarations
BUILT_IN = {READERS_GROUP: BUILT_IN_READERS, ENCODERS_GROUP: BUILT_IN_ENCODERS, AGENTS_GROUP: BUILT_IN_AGENTS}
#: the classes installed packages registered, loaded so far: the entry point each came from (zipon's own are not
#: here: their errors are zipon's, with their tracebacks)
INSTALLED: dict[type, EntryPoint] = {}
LOG = logging.getLogger("zipon.plugins")


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


def agent_names() -> list[str]:
    """Every agent zipon can evaluate: the built-in agents, then those installed packages register (sorted)."""
    return registered(AGENTS_GROUP)


def origin(ep: EntryPoint) -> str:
    """How messages name a plug-in: its entry point, what it names, and the package registering it."""
    dist = getattr(ep, "dist", None)
    package = dist.name if dist is not None else "zipon" if ep.name in BUILT_IN.get(ep.group, {}) \
        else "an unknown package"
    return f"{ep.group} entry point {ep.name!r} ({ep.value}) of package {package!r}"


def _failure(ep: EntryPoint, doing: str, err: BaseException):
    from pipeline.errors import PluginError

    what = f"SystemExit({err.code!r})" if isinstance(err, SystemExit) else f"{type(err).__name__}: {err}"
    return PluginError(f"{origin(ep)}: {doing} failed: {what}")


@contextmanager
def running(cls: type, doing: str, passes: tuple[type[BaseException], ...] = ()) -> Iterator[None]:
    """Run a plug-in's code: an exception or ``SystemExit`` out of an installed package's class ``cls`` becomes one
    PluginError naming its entry point (``doing``: what it was asked, "run", "detect"...); zipon's own errors and
    ``passes`` (the evaluator's end-of-episode signal) go through, and zipon's own classes run unguarded."""
    from pipeline.errors import ZiponError

    ep = INSTALLED.get(cls)
    if ep is None:
        yield
        return
    try:
        yield
    except (ZiponError, *passes):
        raise
    except (Exception, SystemExit) as err:  # noqa: BLE001 - anything a third party's code raises is reported alike
        raise _failure(ep, doing, err) from err


def iterate(cls: type, doing: str, items) -> Iterator:
    """The items of a plug-in's iterable (a reader's samples), each drawn under :func:`running`."""
    with running(cls, doing):
        it = iter(items)
    while True:
        with running(cls, doing):
            try:
                item = next(it)
            except StopIteration:
                return
        yield item


def detects(cls: type, path) -> bool:
    """``cls.detect(path)``; a reader plug-in whose detect fails is skipped (False) with a warning naming it."""
    from pipeline.errors import PluginError

    try:
        with running(cls, "detect"):
            return bool(cls.detect(path))
    except PluginError as err:
        LOG.warning("%s; skipped", err)
        return False


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
    printed = io.StringIO()  # what a package prints while imported (a script's usage text): shown once, after
    try:
        with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(printed):
            cls = ep.load()
    except (Exception, SystemExit) as err:  # noqa: BLE001 - any failure of a third party's import is reported alike
        said = [line for line in printed.getvalue().splitlines() if line.strip()]
        raise ConfigError(f"{kind} {name!r}: {_failure(ep, 'import', err)}"
                          + (f" (it printed: {said[-1].strip()})" if said else "")) from None
    sys.stderr.write(printed.getvalue())
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise ConfigError(f"{kind} {name!r}: {origin(ep)} is not a subclass of {base_label}")
    if getattr(cls, "name", None) != name:
        raise ConfigError(f"{kind} {name!r}: {origin(ep)} names a class whose `name` is "
                          f"{getattr(cls, 'name', None)!r}; they must agree")
    if name not in BUILT_IN.get(group, {}):
        INSTALLED[cls] = ep
    if loaded is not None:
        loaded[name] = cls
    return cls
