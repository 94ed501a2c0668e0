"""Episode records read back from disk, validated as user input.

The workbench appends each episode a person answered to ``DATA/eval/human/<scene>.episodes.jsonl`` (one JSON
record a line). That file is read back by ``zipon eval -f human`` long after it was written, maybe edited by hand or
cut by a crash, and the goals it refers to may have been edited since. So every line is checked against
:class:`EpisodeRecord` (types strict: a string is not a number; numbers finite; metrics in range); a bad line is an
:class:`~pipeline.errors.InputDataError` naming the file, the line and the field. A record of a goal that is no
longer in the scene's goals store is left out with a warning naming it, or refused under ``strict``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from pipeline.errors import InputDataError

MAX_LINE_BYTES = 4 << 20  # one episode's log (poses, dialogue) is tens of kB


class EpisodeOutcome(BaseModel):
    """What every evaluated episode record holds and a reader of results relies on (the scene, goal, method, setting
    and seed it was played in, and its metrics); types strict, numbers finite, SPL and SIT in [0, 1]. A results.json's
    episodes are read back with it (``benchmarks/check_findings.py --results``)."""

    model_config = ConfigDict(strict=True, allow_inf_nan=False, extra="allow")
    scene: str
    goal: str
    method: str
    feedback: str
    seed: int
    success: bool
    spl: float = Field(ge=0, le=1)
    sit: float = Field(ge=0, le=1)


class EpisodeRecord(EpisodeOutcome):
    """One stored human-answered episode: what :meth:`orion_eval.episode.EpisodeRun.result` returns."""

    feedback: Literal["human"]
    seed: int = Field(ge=0)
    goal_type: str
    episode: str
    talk_turns: int = Field(ge=0)
    steps: int = Field(ge=0)
    travelled_m: float = Field(ge=0)
    geodesic_m: float = Field(ge=0)
    collisions: int = Field(ge=0)
    end: str
    final_distance_m: float | None = Field(default=None, ge=0)
    log: dict[str, Any] = Field(default_factory=dict)


@dataclass
class HumanEpisodes:
    """What one file held: the records kept, and the goals whose records were left out (goal -> count)."""

    records: list[dict] = field(default_factory=list)
    dropped: dict[str, int] = field(default_factory=dict)


def read_human_episodes(path: Path, scene: str, goal_ids: set[str], methods: list[str], *,
                        strict: bool = False) -> HumanEpisodes:
    """The records of ``path`` for ``scene`` played with ``methods``, each validated; records of goals not in
    ``goal_ids`` (removed by a later goals edit) are left out and counted, or refused when ``strict``."""
    out = HumanEpisodes()
    with open(path, "rb") as lines:  # streamed: the file grows with every play
        for number, raw in enumerate(lines, 1):
            if len(raw) > MAX_LINE_BYTES:
                raise InputDataError(f"line {number} is over {MAX_LINE_BYTES:,} bytes", path=path,
                                     expected="one JSON episode record a line")
            if not raw.strip():
                continue
            record = _record(path, number, raw)
            if record.scene != scene or record.method not in methods:
                continue
            if record.goal not in goal_ids:
                if strict:
                    raise InputDataError(f"line {number}: goal {record.goal!r} is not in scene {scene}'s goals store "
                                         f"(a goals edit removed it)", path=path, field="goal",
                                         expected="episodes of the goals as built (drop --strict to leave it out)")
                out.dropped[record.goal] = out.dropped.get(record.goal, 0) + 1
                continue
            out.records.append(record.model_dump(mode="json"))
    return out


def _record(path: Path, number: int, raw: bytes) -> EpisodeRecord:
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as err:
        raise InputDataError(f"line {number}: not a JSON episode record ({str(err)[:120]})", path=path) from None
    if not isinstance(data, dict):
        raise InputDataError(f"line {number}: not a JSON object", path=path, expected="one episode record a line")
    try:
        return EpisodeRecord.model_validate(data)
    except ValidationError as err:
        first = err.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "record"
        given = first.get("input")
        shown = repr(given)[:60] if not isinstance(given, dict) else "an object"
        raise InputDataError(f"line {number}: {first['msg']} (given {shown})", path=path, field=where,
                             expected="a human-answered episode record as zipon annotate stores it") from None
