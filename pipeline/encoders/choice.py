"""Which encoder a map stage uses, and loading implementations by name, without importing torch.

Stage configs (``zipon status``, ``zipon params``, staleness checks) need the encoder's NAME only;
:func:`encoder_choice` answers from the params alone for 'vlmap' / 'cfmap', and imports the
registry (:mod:`pipeline.encoders.base`, torch) only to check an explicit encoder name.
:func:`load` imports the one module implementing a name (``zipon query`` on an oracle map does not
import open_clip or torchvision); a name it does not know loads every implementation.
"""

from __future__ import annotations

import importlib
import importlib.util
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline import plugins
from pipeline.errors import ConfigError

if TYPE_CHECKING:
    from pipeline.config import EncodersParams

#: encoder name -> module of :mod:`pipeline.encoders` implementing it
MODULES: dict[str, str] = {
    "oracle": "oracle", "lseg": "lseg", "maskclip": "maskclip", "conceptfusion": "conceptfusion",
    "torchscript": "torchscript", "simulated_lseg": "perception", "simulated_cf": "perception",
}


#: entry-point group through which installed packages add encoders: ``name = "module:Class"``


def plugin_names() -> list[str]:
    """Encoder names installed packages register in the ``zipon.encoders`` entry-point group."""
    return plugins.names(plugins.ENCODERS_GROUP)


def _plugin_entry(name: str):
    return plugins.entry(plugins.ENCODERS_GROUP, name)


def plugin_source(name: str) -> str | None:
    """The source folder (a package) or file (a module) of plugin encoder ``name``, without importing it;
    None for a built-in encoder. Map stages hash it as an input: the plugin's code is outside zipon's."""
    if name in MODULES:
        return None
    ep = _plugin_entry(name)
    if ep is None:
        return None
    spec = importlib.util.find_spec(ep.value.split(":")[0].split(".")[0])
    if spec is None or spec.origin is None:
        raise ConfigError(f"encoder {name!r}: entry point {ep.value!r} ({plugins.ENCODERS_GROUP}) names a module that is "
                          "not installed")
    origin = Path(spec.origin)
    return str(origin.parent if origin.name == "__init__.py" else origin)


def _load_plugin(name: str) -> bool:
    """Register plugin encoder ``name`` from its entry point; False when no package provides it."""
    from pipeline.encoders.base import ENCODERS, Encoder

    cls = plugins.load_class(plugins.ENCODERS_GROUP, name, Encoder, "pipeline.encoders.base.Encoder", "encoder")
    if cls is None:
        return False
    ENCODERS[name] = cls
    return True


def load(name: str | None = None) -> None:
    """Register the implementation of encoder ``name`` (None or an unlisted name: every implementation);
    names no built-in module has are looked up in the ``zipon.encoders`` entry points."""
    from pipeline.encoders.base import ENCODERS

    if name in ENCODERS:
        return
    if name in MODULES:
        importlib.import_module(f"pipeline.encoders.{MODULES[name]}")
        if name in ENCODERS:
            return
    if name is not None and _load_plugin(name):
        return
    from pipeline.encoders import conceptfusion, lseg, maskclip, oracle, perception, torchscript  # noqa: F401


def encoder_choice(params: "EncodersParams", which: str | None = None, *, simulated: bool = False) -> str:
    """The encoder name a stage uses: ``which`` is 'vlmap', 'cfmap' or an encoder name (None = vlmap).

    For a simulated scene ``encoders.simulated`` (when set) overrides the stage's choice; the name
    'perception' means ``simulated_lseg`` for the vlmap and ``simulated_cf`` for the cfmap.
    """
    which = which or "vlmap"
    if simulated and params.simulated is not None:
        name = params.simulated
    elif which in ("vlmap", "cfmap"):
        name = getattr(params, which)
    else:
        from pipeline.encoders.base import ENCODERS

        load(which)
        if which not in ENCODERS:
            load()
            raise ConfigError(f"encoder {which!r}: unknown (choose one of {sorted(ENCODERS)} or 'vlmap'/'cfmap')")
        name = which
    if name == "perception":  # one setting, each map its model: LSeg-like for the vlmap, ConceptFusion-like for the cfmap
        name = "simulated_cf" if which == "cfmap" else "simulated_lseg"
    return name
