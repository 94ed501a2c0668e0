"""Which encoder a map stage uses, and loading implementations by name, without importing torch.

Stage configs (``zipon status``, ``zipon params``, staleness checks) need the encoder's NAME only;
:func:`encoder_choice` answers from the params alone for 'vlmap' / 'cfmap', and imports the
registry (:mod:`pipeline.encoders.base`, torch) only to check an explicit encoder name.
:func:`load` imports the one module implementing a name (``zipon query`` on an oracle map does not
import open_clip or torchvision); a name it does not know loads every implementation.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from pipeline.errors import ConfigError

if TYPE_CHECKING:
    from pipeline.config import EncodersParams

#: encoder name -> module of :mod:`pipeline.encoders` implementing it
MODULES: dict[str, str] = {
    "oracle": "oracle", "lseg": "lseg", "maskclip": "maskclip", "conceptfusion": "conceptfusion",
    "torchscript": "torchscript", "simulated_lseg": "perception", "simulated_cf": "perception",
}


def load(name: str | None = None) -> None:
    """Register the implementation of encoder ``name`` (None or an unlisted name: every implementation)."""
    from pipeline.encoders.base import ENCODERS

    if name in ENCODERS:
        return
    if name in MODULES:
        importlib.import_module(f"pipeline.encoders.{MODULES[name]}")
        if name in ENCODERS:
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
