"""Which encoder a map stage uses, and loading implementations by name, without importing torch.

Stage configs (``zipon status``, ``zipon params``, staleness checks) need the encoder's NAME only;
:func:`encoder_choice` answers from the params alone for 'vlmap' / 'cfmap', and imports the
registry (:mod:`pipeline.encoders.base`, torch) only to check an explicit encoder name.
:func:`load` imports the one module implementing a name (``zipon query`` on an oracle map does not
import open_clip or torchvision). Names come from one registry: zipon's own encoders declared in
:data:`pipeline.plugins.BUILT_IN_ENCODERS`, and those installed packages register (``zipon.encoders``).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline import plugins
from pipeline.errors import ConfigError

if TYPE_CHECKING:
    from pipeline.config import EncodersParams
    from pipeline.encoders.base import Encoder


def plugin_names() -> list[str]:
    """Encoder names installed packages register in the ``zipon.encoders`` entry-point group."""
    return plugins.names(plugins.ENCODERS_GROUP)


def plugin_source(name: str) -> str | None:
    """The source folder (a package) or file (a module) of plugin encoder ``name``, without importing it;
    None for a built-in encoder. Map stages hash it as an input: the plugin's code is outside zipon's."""
    if name in plugins.BUILT_IN_ENCODERS:
        return None
    ep = plugins.entry(plugins.ENCODERS_GROUP, name)
    if ep is None:
        return None
    spec = importlib.util.find_spec(ep.value.split(":")[0].split(".")[0])
    if spec is None or spec.origin is None:
        raise ConfigError(f"encoder {name!r}: entry point {ep.value!r} ({plugins.ENCODERS_GROUP}) names a module that is "
                          "not installed")
    origin = Path(spec.origin)
    return str(origin.parent if origin.name == "__init__.py" else origin)


def encoder_class(name: str) -> type[Encoder] | None:
    """The encoder registered as ``name``, built in (:data:`pipeline.plugins.BUILT_IN_ENCODERS`) or by an installed
    package, imported on first use and kept in :data:`pipeline.encoders.base.ENCODERS`; None for a name neither
    declares. Raises ConfigError naming the entry point when a registration does not load or does not fit."""
    from pipeline.encoders.base import ENCODERS, Encoder

    return plugins.load_class(plugins.ENCODERS_GROUP, name, Encoder, "pipeline.encoders.base.Encoder", "encoder",
                              loaded=ENCODERS)


def load(name: str | None = None) -> None:
    """Register the implementation of encoder ``name`` (None: every built-in encoder; an installed package's is
    loaded by its name)."""
    for each in plugins.BUILT_IN_ENCODERS if name is None else (name,):
        encoder_class(each)


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
        if encoder_class(which) is None:
            raise ConfigError(f"encoder {which!r}: unknown (choose one of {plugins.encoder_names()} or 'vlmap'/'cfmap')")
        name = which
    if name == "perception":  # one setting, each map its model: LSeg-like for the vlmap, ConceptFusion-like for the cfmap
        name = "simulated_cf" if which == "cfmap" else "simulated_lseg"
    return name
