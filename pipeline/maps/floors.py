"""Queries over every floor of a building: each floor's map is queried on its own (:class:`MapQuery`) and the
candidates of all floors are answered together, each with its floor.

Order: with a pose, the pose stands on one floor (``pose_floor``); that floor's candidates come first, nearest
first (as on a single floor), then the other floors' candidates, which carry no ``distance_m`` / ``angle_rad``
(a straight line to another floor means nothing to a robot; a route across floors is :mod:`pipeline.nav`'s).
Without a pose, every candidate is ranked by mass (score x area), largest first, whatever its floor. Candidates
are numbered ``obj_id`` 1.. in that order, in the combined list and in each floor's result alike, and at most
``query.max_candidates`` are kept.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

from pipeline.errors import InputDataError
from pipeline.maps.query import Candidate, MapQuery, QueryResult


@dataclass
class FloorsResult:
    """A query of every floor: ``floors`` one :class:`QueryResult` per floor (lowest first; its heatmap on that
    floor's grid), ``candidates`` those of every floor in the order of the module doc, each with its ``floor``."""

    text: str
    artifact: str
    floors: list[QueryResult]
    candidates: list[Candidate]
    pose: tuple[float, float, float] | None
    pose_floor: int | None
    seconds: float

    def to_json(self) -> dict:
        """JSON-able summary: the query, each floor's figures (as :meth:`QueryResult.to_json`, without its
        candidates) and the candidates of every floor."""
        floors = []
        for r in self.floors:
            doc = r.to_json()
            doc.pop("candidates")
            doc.pop("text")
            doc.pop("map")
            doc.pop("pose")
            floors.append(doc)
        return {"text": self.text, "map": self.artifact, "pose": None if self.pose is None else list(self.pose),
                "pose_floor": self.pose_floor, "seconds": round(self.seconds, 5), "floors": floors,
                "candidates": [asdict(c) for c in self.candidates]}


def query_floors(queries: list[MapQuery], text: str, pose: tuple[float, float, float] | None = None, *,
                 pose_floor: int = 0, max_candidates: int | None = None, region=None) -> FloorsResult:
    """Query ``text`` on every floor (``queries[k]``: floor k's :class:`MapQuery`); ``pose`` (x, y, yaw: world
    metres, radians) stands on floor ``pose_floor``; ``region`` (a :class:`~pipeline.region.Region`, world metres)
    limits every floor's query to it. See the module doc for the order of the candidates."""
    if pose is not None and not 0 <= pose_floor < len(queries):
        raise InputDataError(f"got {pose_floor}", field="pose floor", expected=f"a floor 0..{len(queries) - 1}")
    t0 = time.perf_counter()
    results = [q.query(text, pose if pose is not None and k == pose_floor else None, region=region)
               for k, q in enumerate(queries)]
    if pose is not None:
        others = sorted((c for r in results if r.floor != pose_floor for c in r.candidates),
                        key=lambda c: (-c.score * c.area_m2, c.floor, c.obj_id))
        candidates = list(results[pose_floor].candidates) + others
    else:
        candidates = sorted((c for r in results for c in r.candidates),
                            key=lambda c: (-c.score * c.area_m2, c.floor, c.obj_id))
    limit = max_candidates if max_candidates is not None else queries[0].params.max_candidates
    candidates = candidates[:limit]
    for i, c in enumerate(candidates, 1):
        c.obj_id = i
    kept = {id(c) for c in candidates}
    for r in results:
        r.candidates = sorted((c for c in r.candidates if id(c) in kept), key=lambda c: c.obj_id)
    return FloorsResult(text=text, artifact=results[0].artifact, floors=results, candidates=candidates,
                        pose=None if pose is None else tuple(float(v) for v in pose),
                        pose_floor=None if pose is None else pose_floor, seconds=time.perf_counter() - t0)
