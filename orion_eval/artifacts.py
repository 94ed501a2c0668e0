"""One scene's artifacts, opened lazily, with the lineage check the evaluator relies on.

:class:`Artifacts` gives the frames (ground truth), the reconstruction, the two semantic maps (as
:class:`~pipeline.maps.query.MapQuery` objects), the goals and the routes of one scene. Before
anything is evaluated, :meth:`Artifacts.check_lineage` compares the reconstruction's output digest
(``manifests/<scene>/reconstruct.json``) with the ``recon`` input digest recorded in each downstream
manifest (vlmap, cfmap, goals, routes) and the goals digest recorded by routes; any mismatch is a
:class:`~pipeline.errors.LineageError` naming both manifests.

The action space (``step_m``, ``turn_deg``) and the success radius are facts of ``routes.zarr``: the
episodes' reference paths and replays were made with them (and the goal regions of goals.zarr cut with
that radius), so the evaluator reads them from the artifact (:meth:`Artifacts.action_space`), never from
the params. :meth:`Artifacts.check_action_space` (run with the lineage check) refuses a ``task`` section
that disagrees with the artifact: ``task.step_m``, ``task.turn_deg``, ``task.success_m`` or
``task.hfov_deg`` differing from what routes.zarr was built with (rebuild: ``zipon run``) — so one
evaluation never mixes two action spaces, two success radii or two fields of view.
"""

from __future__ import annotations

import math
from functools import cached_property
from pathlib import Path

import numpy as np

from pipeline.config import Params
from pipeline.errors import LineageError, MissingInputError
from pipeline.geometry import GridSpec
from pipeline.manifest import Manifest
from pipeline.paths import Workspace

# downstream stage -> the artifacts it must share with the others (input name -> producing stage)
LINEAGE = {"vlmap": {"recon": "reconstruct"}, "cfmap": {"recon": "reconstruct"},
           "goals": {"recon": "reconstruct"}, "routes": {"recon": "reconstruct", "goals": "goals"}}


class Artifacts:
    """Read-only, lazily opened view of one scene's artifacts (see the module docstring)."""

    def __init__(self, ws: Workspace, params: Params, scene: str, *, check: bool = True):
        self.ws, self.params, self.scene = ws, params, scene
        if check:
            self.check_lineage()
            self.check_action_space()

    # ------------------------------------------------------------------ lineage
    def manifest(self, stage: str) -> Manifest:
        man = Manifest.read(self.ws.manifest(self.scene, stage))
        if man is None:
            raise MissingInputError(f"{self.ws.manifest(self.scene, stage)}: no manifest of stage {stage} for scene "
                                    f"{self.scene!r} (run: zipon run -s {self.scene})")
        return man

    def check_lineage(self, stages: tuple[str, ...] = ("vlmap", "cfmap", "goals", "routes")) -> dict[str, str]:
        """Raise :class:`LineageError` unless every downstream artifact comes from the same recon (and goals).

        Returns ``{artifact: digest}`` of the shared upstream outputs.
        """
        shared: dict[str, str] = {}
        for stage in stages:
            man = self.manifest(stage)
            for name, producer in LINEAGE[stage].items():
                if name not in shared:
                    up = self.manifest(producer)
                    if name not in up.outputs:
                        raise LineageError(f"{self.ws.manifest(self.scene, producer)}: has no output {name!r}")
                    shared[name] = up.outputs[name].digest
                got = man.inputs.get(name)
                if got != shared[name]:
                    raise LineageError(
                        f"scene {self.scene}: {stage} was built from {name} {got}, but "
                        f"{self.ws.manifest(self.scene, LINEAGE[stage][name])} records {name} {shared[name]} "
                        f"(manifest {self.ws.manifest(self.scene, stage)}); rerun: zipon run -s {self.scene}")
        return shared

    def action_space(self) -> tuple[float, float, float]:
        """``(step_m, turn_deg, success_m)`` that routes.zarr was built with (what the evaluator uses)."""
        r = self.routes
        return r.step_m, r.turn_deg, r.success_m

    def check_action_space(self) -> None:
        """Raise :class:`LineageError` when the params in force disagree with routes.zarr's action space or
        success radius (see the module docstring)."""
        step_m, turn_deg, success_m = self.action_space()
        task, src = self.params.task, self.ws.params_path
        for key, built in (("step_m", step_m), ("turn_deg", turn_deg), ("success_m", success_m),
                           ("hfov_deg", self.routes.hfov_deg)):
            ours = getattr(task, key)
            if not math.isclose(ours, built, rel_tol=0.0, abs_tol=1e-9):
                raise LineageError(f"task.{key} {ours:g} in {src} but routes.zarr of {self.scene} was built with "
                                   f"{built:g}: rebuild with zipon run -s {self.scene}")

    # ------------------------------------------------------------------ artifacts
    def path(self, name: str) -> Path:
        p = self.ws.artifact(name, self.scene)
        if not p.exists():
            raise MissingInputError(f"{p}: artifact {name} of scene {self.scene!r} not found")
        return p

    @cached_property
    def frames(self):
        from pipeline.frames import FrameStore

        return FrameStore(self.path("frames"))

    @cached_property
    def gt(self):
        """The scene's :class:`~pipeline.scene_gt.GTScene` (simulated scenes), else ``None``."""
        return self.frames.ground_truth

    @cached_property
    def recon(self):
        from pipeline.recon import Recon

        return Recon(self.path("recon"))

    @cached_property
    def grid(self) -> GridSpec:
        return self.recon.grid

    @cached_property
    def navigable(self) -> np.ndarray:
        return self.recon.navigable

    @cached_property
    def height(self) -> np.ndarray:
        return self.recon.height

    @cached_property
    def goals(self):
        from pipeline.goals.store import Goals

        return Goals(self.path("goals"))

    @cached_property
    def routes(self):
        from pipeline.routes.store import Routes

        return Routes(self.path("routes"))

    def map_query(self, which: str):
        """The cached :class:`~pipeline.maps.query.MapQuery` of ``'vlmap'`` or ``'cfmap'``."""
        from pipeline.maps.query import open_query

        return open_query(self.path(which), self.params, recon_path=self.path("recon"),
                          frames_path=self.ws.artifact("frames", self.scene))

    @cached_property
    def camera_height_m(self) -> float:
        """Ego camera height above the floor: ``eval.camera_height_m`` or the recording's median."""
        if self.params.eval.camera_height_m is not None:
            return float(self.params.eval.camera_height_m)
        from pipeline.routes.region import recorded_camera_height

        return recorded_camera_height(self.recon.poses, self.recon.floor_z)  # what the routes stage sighted from

    @cached_property
    def room_of_cell(self) -> tuple[np.ndarray, list[str]]:
        """``(rows, cols)`` int16 room index (-1 none) and the room ids, from the goals' object rooms / GT rooms."""
        import cv2

        g = self.grid
        out = np.full((g.rows, g.cols), -1, np.int16)
        ids: list[str] = []
        rooms = self.gt.rooms if self.gt is not None else []
        for i, room in enumerate(rooms):
            rc = g.world_to_cell(np.asarray(room.polygon)).astype(np.int32)
            m = np.zeros((g.rows, g.cols), np.uint8)
            cv2.fillPoly(m, [rc[:, ::-1].reshape(-1, 1, 2)], 1)
            out[m.astype(bool)] = i
            ids.append(room.id)
        return out, ids

    def room_at(self, xy) -> str | None:
        """Room id at a world point (simulated scenes), else ``None``."""
        idx, ids = self.room_of_cell
        rc = self.grid.world_to_cell(np.asarray(xy, dtype=np.float64))
        if not self.grid.inside(rc) or idx[rc[0], rc[1]] < 0:
            return None
        return ids[int(idx[rc[0], rc[1]])]
