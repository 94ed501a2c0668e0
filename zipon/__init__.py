"""zipon's Python API: a thin facade over the packages the CLI also uses.

    import zipon

    ds = zipon.open("params.yaml")            # or the project folder, or a data root (folder with artifacts/)
    scene = ds["sim_00"]
    result = scene.vlmap.query("chair", pose=(1.0, 2.0, 0.0))   # x, y metres, yaw radians
    grid = scene.vlmap.to_xarray()             # dense (y, x, feature) grid, coordinates in metres
    feats, seen = scene.cfmap.features_at([[1.0, 2.0]])
    scene.frames, scene.recon, scene.goals, scene.routes, scene.episodes
    results = zipon.run_eval(ds, "eval_out", agents=["orion", MyAgent], seeds=1)

Everything heavy is imported on first use, so ``import zipon`` is cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

__all__ = ["Agent", "Dataset", "MapView", "Scene", "open", "run_eval"]

if TYPE_CHECKING:  # pragma: no cover
    from orion_eval.agents import Agent
    from zipon.api import Dataset, MapView, Scene, open
    from zipon.evaluate import run_eval

_LAZY = {"Dataset": "zipon.api", "MapView": "zipon.api", "Scene": "zipon.api", "open": "zipon.api",
         "run_eval": "zipon.evaluate", "Agent": "orion_eval.agents"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'zipon' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
