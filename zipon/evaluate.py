"""``zipon.run_eval``: the one evaluation entry (the API, ``zipon eval`` and ``zipon demo`` call it): the evaluator
(:func:`orion_eval.run.evaluate`) on a dataset's built scenes, with user agent classes.

An agent is a subclass of :class:`orion_eval.agents.Agent` with a ``name`` and a
``run(m, instruction, goal_name)`` method acting through the ORION modules ``m``
(``retrieve_map``, ``goto_object``, ``talk``, ...); pass the class itself in ``agents`` beside the
built-in names ('human', 'cow', 'vlmap', 'cf', 'orion'), or install a package that registers it in the
``zipon.agents`` entry-point group and pass its name (or name it in ``eval.methods``: the evaluator resolves names
through :mod:`pipeline.plugins`, whichever entry calls it)::

    [project.entry-points."zipon.agents"]
    greedy = "my_package.agents:Greedy"
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from pipeline.errors import ConfigError


def run_eval(dataset, out_dir: str | Path = "eval_out", *, agents: Sequence | None = None,
             scenes: Sequence[str] | None = None, feedback: Sequence[str] | None = None,
             seeds: int | Sequence[int] | None = None, report: bool = True, progress: bool = False,
             strict: bool = False) -> dict:
    """Evaluate agents on built scenes; writes ``out_dir/results.json`` (+ report.html) and returns the results.

    ``dataset``: a :class:`~zipon.api.Dataset` or anything :func:`zipon.open` takes; on an object-store data root
    the evaluated scenes are mirrored first. ``agents``: built-in names and/or :class:`~orion_eval.agents.Agent`
    subclasses (default: params ``eval.methods``). ``seeds``: a count (``2`` = seeds 0 and 1) or explicit seeds
    (default: params ``eval.seeds``). ``strict``: stored human-answered episodes of goals a later goals edit removed
    are an error, not left out with a warning.
    """
    from orion_eval.run import evaluate
    from stages import STAGES
    from zipon.api import Dataset, open

    ds = dataset if isinstance(dataset, Dataset) else open(dataset)
    names, classes = agent_names(agents)
    if isinstance(seeds, bool) or (isinstance(seeds, int) and seeds < 1):
        raise ConfigError(f"seeds: expected a count >= 1 or a list of seeds, got {seeds!r}")
    seed_list = list(range(seeds)) if isinstance(seeds, int) else (None if seeds is None else [int(s) for s in seeds])
    ds.mirror(list(scenes or ds.params.eval.scenes or ds.params.scenes))  # what it evaluates
    return evaluate(ds.workspace, ds.params, STAGES, Path(out_dir), scenes=list(scenes) if scenes else None,
                    methods=names, feedback=list(feedback) if feedback else None, seeds=seed_list,
                    progress=progress, report=report, agent_classes=classes or None, strict=strict)


def agent_names(agents: Sequence | None) -> tuple[list[str] | None, dict[str, type]]:
    """Split ``agents`` into method names and ``{name: class}`` for the caller's own classes (names are resolved by
    the evaluator through the registry: built in or installed); errors name the culprit."""
    from orion_eval.agents import Agent, agent_class

    if agents is None:
        return None, {}
    if isinstance(agents, (str, type)):
        agents = [agents]
    names, classes = [], {}
    for a in agents:
        if isinstance(a, str):
            names.append(a)
            continue
        if not (isinstance(a, type) and issubclass(a, Agent)):
            raise ConfigError(f"agents: {a!r} is neither a method name nor a subclass of orion_eval.agents.Agent")
        name = getattr(a, "name", "") or ""
        if not name:
            raise ConfigError(f"agents: {a.__qualname__} has no `name` (set a class attribute, e.g. name = 'mine')")
        known = agent_class(name)
        if known is not None and known is not a:
            raise ConfigError(f"agents: {a.__qualname__}.name {name!r} is taken by the registered "
                              f"{known.__qualname__}; choose another name")
        if name in classes and classes[name] is not a:
            raise ConfigError(f"agents: two classes are named {name!r}")
        classes[name] = a
        names.append(name)
    return names, classes
