"""``goals.zarr``: personalized goals with feedback, and the reader the evaluator uses.

Format (version 2; version 2 added the goal regions, which the routes stage and the evaluator read)::

    goals.zarr/            attrs: artifact="goals", format_version=2, stage, params_digest, code_version,
    │                             scene, units="metres", frame="world, z up", grid {rows, cols, cell_size_m,
    │                             origin_xy, orientation}, source ("gt" | "file" | "navchat"),
    │                             edits {path, digest} | null, start_pose [x, y, yaw] | null,
    │                             document   the goals document (pipeline.goals.schema): rooms, objects
    │                                        (class, identity, room, position_xy), goals (id, name, type,
    │                                        room, room_id, objects = same_goal group, feedback
    │                                        {corrective, descriptive, landmark, procedural}),
    │                             objects    [{key, cls, instance_id, room, footprint [[x, y], ...],
    │                                        mass_center [x, y], z_range [z0, z1], size, color_name,
    │                                        material, description}] (world metres, heights above floor),
    │                             landmarks  {goal id: [{object, relation, distance_m}]},
    │                             region_goals [goal ids, in document order: region g belongs to region_goals[g]],
    │                             goal_region {definition, success_m},
    │                             sight {method, camera_height_m, levels (fractions of object height),
    │                                    tolerance_m, own_dilation_cells}
    ├── object_index   (rows, cols) int32  1 + index into attrs.objects (footprints on the grid), 0 = none
    ├── region_cells   (C,) int64          every goal's region (pipeline.nav.region.group_region) as flat
    │                                      row-major cell ids on ``grid``, concatenated
    └── region_offset  (G+1,) int64        goal g's region = region_cells[region_offset[g]:region_offset[g+1]]

A building (a ``recon.zarr`` of several floors) adds what keeps its floors apart; a single-floor store has none
of it and is written byte for byte as before floors existed::

    goals.zarr/            attrs (added): floors [{id, name, floor_z_m}], region_floors [floor of region g]
    │                             (objects' and rooms' records carry ``floor``, written when it is not 0)
    └── floors/            only in a building (``object_index`` at the root is floor 0's footprints)
        └── <id>/          only in a building, floor <id> >= 1
            └── object_index   (rows, cols) int32  only in a building: floor <id>'s footprints, 1 + index into
                                                   attrs.objects

A goal lies on the floor of its objects; its region (``region_cells``) is cells of that floor's grid.

Variable-length records live in attrs as JSON (a few hundred objects at most); the raster is
chunked in 256x256 tiles. A goal's region (where an episode to it can succeed: navigable cells within
``task.success_m`` of a member's footprint that see its mass centre on the reconstructed mesh) is
computed once, here, by the goals stage, whose procedural feedback is planned into it; the routes
stage and the evaluator read it (:meth:`Goals.goal_region`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import ArtifactError
from pipeline.geometry import GridSpec
from pipeline.goals.objects import ObjectRecord, ObjectSet
from pipeline.goals.schema import GoalsDocument
from pipeline.store import ArtifactAttrs, AttrsModel, GridAttrs, compressor, new_group, open_group

ARTIFACT = "goals"
FORMAT_VERSION = 2
FLOOR_GROUP = "floors"  # a building's floors/<id>/object_index (id >= 1; floor 0's is the root's)


class GoalRegionAttrs(AttrsModel):
    """``attrs.goal_region``: how the goal regions were cut."""

    success_m: float
    definition: str | None = None


class GoalsAttrs(ArtifactAttrs):
    """The attrs of ``goals.zarr`` (the tree above): the document and object records as their own models."""

    scene: str
    grid: GridAttrs
    source: str = "file"
    edits: dict[str, Any] | None = None
    start_pose: tuple[float, float, float] | None = None
    document: GoalsDocument
    objects: list[ObjectRecord]
    landmarks: dict[str, list[dict[str, Any]]] = {}
    region_goals: list[str] = []
    goal_region: GoalRegionAttrs | None = None
    sight: dict[str, Any] = {}
    floors: list[dict[str, Any]] | None = None  # a building only: [{id, name, floor_z_m}]
    region_floors: list[int] | None = None  # a building only: the floor of each region (region_goals' order)


def write_goals(path: Path, *, document: GoalsDocument, objset: ObjectSet, landmarks: dict,
                object_index: np.ndarray | list[np.ndarray], grid: GridSpec, attrs: dict, start_pose=None,
                edits: dict | None = None, regions: dict[str, np.ndarray], region_attrs: dict, sight: dict,
                floors: list[dict] | None = None, region_floors: list[int] | None = None) -> None:
    """Write a new goals store at ``path``; ``attrs`` carries artifact_attrs (stage, params digest...);
    ``regions`` maps every goal id -> its ``(rows, cols)`` bool goal region. A building passes one
    ``object_index`` per floor, its ``floors`` records and the floor of each region (``region_floors``)."""
    per_floor = object_index if isinstance(object_index, list) else [object_index]
    building = {"floors": floors, "region_floors": list(region_floors or [])} if len(per_floor) > 1 else {}
    if building and (floors is None or len(floors) != len(per_floor) or len(region_floors or []) != len(regions)):
        raise ValueError(f"{path}: a building needs a floor record per object index and a floor per region")
    group = new_group(Path(path), GoalsAttrs.checked({
        **attrs, "scene": objset.scene, "units": "metres", "frame": "world, z up", "grid": grid.to_attrs(),
        "source": objset.source, "edits": edits, "start_pose": list(start_pose) if start_pose is not None else None,
        "document": document.model_dump(mode="json", by_alias=True),
        "objects": [o.model_dump(mode="json") for o in objset.objects],
        "landmarks": landmarks, "region_goals": list(regions), "goal_region": dict(region_attrs),
        "sight": dict(sight), **building,
    }, path))
    for f, index in enumerate(per_floor):
        where = group if f == 0 else group.require_group(f"{FLOOR_GROUP}/{f}")
        tile = (min(256, index.shape[0]), min(256, index.shape[1]))
        arr = where.create_array("object_index", shape=index.shape, chunks=tile, dtype="int32",
                                 compressors=compressor(3))
        arr[:] = index.astype(np.int32)
        arr.attrs.update({"meaning": "1 + index into attrs.objects; 0 = no object"})
    cells = [np.flatnonzero(np.asarray(m, bool).reshape(-1)).astype(np.int64) for m in regions.values()]
    for name, a in (("region_cells", np.concatenate(cells) if cells else np.zeros(0, np.int64)),
                    ("region_offset", np.concatenate([[0], np.cumsum([len(c) for c in cells])]).astype(np.int64))):
        z = group.create_array(name, shape=a.shape, chunks=(max(len(a), 1),), dtype=a.dtype, compressors=compressor(3))
        if a.size:
            z[:] = a


@dataclass(frozen=True)
class GoalView:
    """One goal as the evaluator needs it (world metres)."""

    id: str
    name: str
    type: str
    room: str | None
    room_id: str | None
    object_keys: tuple[str, ...]  # the same_goal group
    instance_ids: tuple[int, ...]
    footprints: tuple[np.ndarray, ...]  # (N,2) polygons, one per object
    mass_centers: np.ndarray  # (K,2) one per object
    feedback: dict  # corrective (dict), descriptive, landmark, procedural (str | None)
    landmarks: tuple[dict, ...]
    floor: int = 0  # the floor its objects lie on

    @property
    def mass_center(self) -> np.ndarray:
        """Mass centre of the representative (first) object."""
        return self.mass_centers[0]


class Goals:
    """Read-only view of a ``goals.zarr``."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.group = open_group(self.path, artifact=ARTIFACT, format_version=FORMAT_VERSION)
        self.attrs = dict(self.group.attrs)
        self.meta = GoalsAttrs.read(self.attrs, self.path)
        self.grid = self.meta.grid.spec
        self.document = self.meta.document
        self.objects = {o.key: o for o in self.meta.objects}
        self.object_keys = [o.key for o in self.meta.objects]
        self.scene = self.meta.scene
        self.goals = [self._view(g) for g in self.document.goals]
        self.region_goals = list(self.meta.region_goals)
        self.floors = list(self.meta.floors or [{"id": 0, "name": "floor 0"}])

    def floor_of(self, goal_id: str) -> int:
        """The floor goal ``goal_id`` lies on (0 in a single-floor scene)."""
        return self.goal(goal_id).floor

    @property
    def success_m(self) -> float:
        """The success radius the goal regions were cut with, metres (``goal_region.success_m``)."""
        if self.meta.goal_region is None:
            raise ArtifactError(f"{self.path}: attrs.goal_region missing (rebuild it with: zipon run --force)")
        return self.meta.goal_region.success_m

    def goal_region(self, goal_id: str) -> np.ndarray:
        """``(rows, cols)`` bool goal region of ``goal_id`` on its floor's grid (all False when it has none)."""
        out = np.zeros(self.grid.rows * self.grid.cols, bool)
        if goal_id in self.region_goals:
            g = self.region_goals.index(goal_id)
            off = self.group["region_offset"][g: g + 2]
            out[self.group["region_cells"][int(off[0]): int(off[1])]] = True
        return out.reshape(self.grid.rows, self.grid.cols)

    def _view(self, g) -> GoalView:
        objs = [self.objects[k] for k in g.objects]
        return GoalView(
            id=g.id, name=g.name, type=g.type, room=g.room, room_id=g.room_id, object_keys=tuple(g.objects),
            instance_ids=tuple(o.instance_id for o in objs),
            footprints=tuple(np.asarray(o.footprint, dtype=np.float64) for o in objs),
            mass_centers=np.asarray([o.mass_center for o in objs], dtype=np.float64),
            feedback=g.feedback.model_dump(mode="json"),
            landmarks=tuple(self.meta.landmarks.get(g.id) or ()), floor=objs[0].floor,
        )

    def goal(self, goal_id: str) -> GoalView:
        for g in self.goals:
            if g.id == goal_id:
                return g
        raise KeyError(f"{self.path}: no goal {goal_id!r}")

    def object_index(self, floor: int = 0) -> np.ndarray:
        """``(rows, cols)`` int32 footprints of floor ``floor``'s objects: 1 + index into ``object_keys``."""
        if floor == 0:
            return self.group["object_index"][:]
        try:
            return self.group[f"{FLOOR_GROUP}/{floor}/object_index"][:]
        except KeyError:
            raise ArtifactError(f"{self.path}: no floor {floor} (floors {[f['id'] for f in self.floors]})") from None

    def footprint_mask(self, keys) -> np.ndarray:
        """``(rows, cols)`` bool: cells covered by the given objects (all on one floor: the first's)."""
        idx = [self.object_keys.index(k) + 1 for k in keys]
        return np.isin(self.object_index(self.objects[keys[0]].floor if keys else 0), idx)

    def object_set(self) -> ObjectSet:
        return ObjectSet(scene=self.scene, source=self.meta.source,
                         objects=list(self.objects.values()))
