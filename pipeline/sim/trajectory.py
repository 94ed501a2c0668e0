"""Exploration-like camera trajectories on a ground-truth scene, in navchat's action space.

The robot starts with a 360 degree spin in the living room, then visits every room (nearest
unvisited room next, geodesic shortest paths on the free grid) and spins in place inside each;
moves are 0.25 m forward steps and 15 degree turns. If the tour has fewer actions than the
requested frames, further viewpoints per room are added. The action sequence is then stretched
over the recording time so that exactly ``frames`` frames sample it.

In a building of several floors the robot tours floor 0, walks to the foot of the stairs, climbs
them (forward steps along the flight, as a Habitat agent does), tours the next floor, and so on to
the top; then it walks back down to floor 0. Each floor is toured as an apartment is, in rounds of
further viewpoints, until it has its share of the actions (the walk's minimum split by the floors'
navigable areas); the first round also walks the stair hall to its dead end beyond the flight. A state carries the height of the walking surface under the robot (a floor,
or the ramp over a flight's steps, :meth:`pipeline.scene_gt.GTStair.surface_z`), so the camera
stays at one height above it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from pipeline.errors import StageError
from pipeline.geometry import GridSpec, camera_pose_from_base, interpolate_poses
from pipeline.scene_gt import GTScene, GTStair
from pipeline.sim.topdown import scene_grid

STEP_M = 0.25
TURN_RAD = np.deg2rad(15.0)
CELL_M = 0.05
LARGE_CELL_M = 0.1  # planning cell of a floor above LARGE_FLOOR_M2 (an office): 4x fewer cells to search
LARGE_FLOOR_M2 = 600.0
BODY_Z = (0.05, 1.5)  # heights that block the robot's body, metres above the floor


@dataclass
class FreeSpace:
    """Navigable cells of a scene for a robot of ``radius_m``."""

    grid: GridSpec
    clearance_m: np.ndarray  # (rows, cols) float distance to the nearest obstacle / outside
    navigable: np.ndarray  # (rows, cols) bool
    room_of_cell: np.ndarray  # (rows, cols) int16 room index, -1 outside rooms

    def is_navigable(self, xy: np.ndarray) -> np.ndarray:
        rc = self.grid.world_to_cell(xy)
        ok = self.grid.inside(rc)
        rc = np.clip(rc, 0, [self.grid.rows - 1, self.grid.cols - 1])
        return ok & self.navigable[rc[..., 0], rc[..., 1]]


def planning_cell_m(gt: GTScene) -> float:
    """The cell of the planning grid: :data:`CELL_M`, or :data:`LARGE_CELL_M` on a floor of over
    :data:`LARGE_FLOOR_M2` (an apartment or a house floor is far smaller)."""
    x0, x1, y0, y1 = gt.bounds_xy()
    return LARGE_CELL_M if (x1 - x0) * (y1 - y0) > LARGE_FLOOR_M2 else CELL_M


def free_space(gt: GTScene, radius_m: float) -> FreeSpace:
    """Floor minus walls and object parts in the body height band, eroded by ``radius_m`` (a single floor: pass
    :meth:`GTScene.floor_view` of a building's floor), on a grid of :func:`planning_cell_m`."""
    cell = planning_cell_m(gt)
    grid = scene_grid(gt, cell)
    free = gt.floor_mask(grid) & ~gt.occupancy(grid, *BODY_Z)
    clearance = ndimage.distance_transform_edt(free) * cell
    room = np.full((grid.rows, grid.cols), -1, np.int16)
    centres = grid.cell_to_world(np.stack(np.mgrid[0:grid.rows, 0:grid.cols], axis=-1))
    for k, r in enumerate(gt.rooms):
        p = np.asarray(r.polygon)
        inside = ((centres[..., 0] > p[:, 0].min()) & (centres[..., 0] < p[:, 0].max())
                  & (centres[..., 1] > p[:, 1].min()) & (centres[..., 1] < p[:, 1].max()))
        room[inside] = k
    return FreeSpace(grid, clearance, clearance > radius_m, room)


def _graph(fs: FreeSpace) -> tuple[csr_matrix, np.ndarray]:
    """8-connected graph over navigable cells (edge weights in metres); returns it and cell -> node."""
    nav = fs.navigable
    node = np.full(nav.shape, -1, np.int64)
    node[nav] = np.arange(int(nav.sum()))
    rows, cols, weights = [], [], []
    R, C = nav.shape
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = node[0:R - dr, max(0, -dc):C - max(0, dc)]
        b = node[dr:R, max(0, dc):C - max(0, -dc)]
        ok = (a >= 0) & (b >= 0)
        rows.append(a[ok]), cols.append(b[ok])
        weights.append(np.full(int(ok.sum()), fs.grid.cell_size_m * np.hypot(dr, dc)))
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    n = int(nav.sum())
    g = csr_matrix((np.concatenate([w, w]), (np.concatenate([r, c]), np.concatenate([c, r]))), shape=(n, n))
    return g, node


def room_viewpoints(fs: FreeSpace, room: int, count: int) -> list[np.ndarray]:
    """Up to ``count`` spots of a room: the most open one first, then farthest-point picks."""
    cells = np.argwhere(fs.navigable & (fs.room_of_cell == room))
    if len(cells) == 0:
        return []
    clear = fs.clearance_m[cells[:, 0], cells[:, 1]]
    picks = [int(np.argmax(clear))]
    dist = np.full(len(cells), np.inf)
    for _ in range(count - 1):
        dist = np.minimum(dist, np.hypot(*(cells - cells[picks[-1]]).T) * fs.grid.cell_size_m)
        score = np.where(clear > 0.35, dist, -1.0)
        if score.max() < 1.0:
            break
        picks.append(int(np.argmax(score)))
    return [fs.grid.cell_to_world(cells[i]) for i in picks]


def _string_pull(fs: FreeSpace, pts: np.ndarray) -> list[np.ndarray]:
    """Keep only the waypoints needed for straight, navigable segments."""
    out = [pts[0]]
    i = 0
    while i < len(pts) - 1:
        j = len(pts) - 1
        while j > i + 1:
            seg = np.linspace(pts[i], pts[j], int(np.hypot(*(pts[j] - pts[i])) / 0.01) + 2)  # 1 cm: no clipped corner
            if fs.is_navigable(seg).all():
                break
            j -= 1
        out.append(pts[j])
        i = j
    return out


class _Walker:
    """Turns and steps toward waypoints; records (x, y, yaw) after every action."""

    def __init__(self, fs: FreeSpace, xy: np.ndarray, yaw_steps: int = 0, z: float = 0.0):
        self.fs, self.xy, self.k, self.z = fs, np.asarray(xy, float), yaw_steps, float(z)
        self.states = [(self.xy[0], self.xy[1], self.k * TURN_RAD, self.z)]

    def _clearance(self, xy: np.ndarray) -> float:
        rc = np.clip(self.fs.grid.world_to_cell(xy), 0, [self.fs.grid.rows - 1, self.fs.grid.cols - 1])
        return float(self.fs.clearance_m[rc[0], rc[1]])

    def _record(self):
        self.states.append((self.xy[0], self.xy[1], self.k * TURN_RAD, self.z))

    def spin(self):
        for _ in range(24):
            self.k += 1
            self._record()

    def face(self, yaw: float):
        """Turn (15 degree steps, the short way) to the quantised heading nearest ``yaw``."""
        diff = (int(np.round((yaw - self.k * TURN_RAD) / TURN_RAD)) + 12) % 24 - 12
        for _ in range(abs(diff)):
            self.k += int(np.sign(diff))
            self._record()

    def take_stairs(self, stair: GTStair, up: bool, arrive: FreeSpace, arrive_z: float, off_m: float):
        """Face along ``stair`` (up or down) and step forward to ``off_m`` beyond its other end, the height
        following its surface; ``arrive`` is the free space of the floor reached."""
        bottom, top = np.asarray(stair.bottom[:2]), np.asarray(stair.top[:2])
        way = (top - bottom) / np.hypot(*(top - bottom))
        if not up:
            way = -way
        goal = (top if up else bottom) + off_m * way
        self.face(float(np.arctan2(way[1], way[0])))
        heading = np.array([np.cos(self.k * TURN_RAD), np.sin(self.k * TURN_RAD)])
        left = float(np.dot(goal - self.xy, heading))
        while left > 1e-9:
            step = min(STEP_M, left)
            self.xy = self.xy + step * heading
            self.z = float(stair.surface_z(self.xy))
            left -= step
            self._record()
        self.fs, self.z = arrive, float(arrive_z)
        self.states[-1] = (self.xy[0], self.xy[1], self.k * TURN_RAD, self.z)

    def go(self, target: np.ndarray, start: np.ndarray | None = None):
        """Turn and step to ``target`` along the planned (navigable) segment from ``start`` (default: here)."""
        start = self.xy.copy() if start is None else np.asarray(start, float)
        seg = target - start
        for _ in range(4000):
            delta = target - self.xy
            dist = float(np.hypot(*delta))
            if dist < STEP_M / 2:
                return
            want = np.arctan2(delta[1], delta[0])
            diff = int(np.round((want - self.k * TURN_RAD) / TURN_RAD))
            diff = (diff + 12) % 24 - 12
            if diff != 0:
                self.k += int(np.sign(diff))
                self._record()
                continue
            yaw = self.k * TURN_RAD
            nxt = self.xy + min(STEP_M, dist) * np.array([np.cos(yaw), np.sin(yaw)])
            if not self.fs.is_navigable(nxt):
                # the quantised heading would graze an obstacle. Quantised steps drift off the planned (navigable)
                # segment, so a straight step from the drifted spot can cut a doorway's corner too: take the first
                # navigable of a step straight to the target, toward the segment one step ahead, or back onto it
                t = float(np.clip(np.dot(self.xy - start, seg) / max(float(np.dot(seg, seg)), 1e-12), 0.0, 1.0))
                foot = start + t * seg
                rest = target - foot
                left = float(np.hypot(*rest))
                aim = foot + (min(STEP_M, left) / left) * rest if left > 1e-9 else foot
                options = []
                for frac in (1.0, 0.5, 0.25):  # shorter steps back toward the segment when a whole one cuts in
                    for way in (target, aim, foot):
                        gap = float(np.hypot(*(way - self.xy)))
                        if gap > 1e-9:
                            options.append(self.xy + (min(STEP_M * frac, gap) / gap) * (way - self.xy))
                ok = [o for o in options if self.fs.is_navigable(o)]
                nxt = ok[0] if ok else max(options, key=self._clearance)
            self.xy = nxt
            self._record()
        raise StageError(f"trajectory: could not reach waypoint {target.round(2).tolist()}")


class _FloorTour:
    """One floor's free space, its shortest-path graph and its rooms' viewpoints."""

    def __init__(self, gt: GTScene, radius_m: float):
        self.gt = gt
        self.fs = free_space(gt, radius_m)
        self.graph, self.node = _graph(self.fs)
        self.views = [room_viewpoints(self.fs, k, 6) for k in range(len(gt.rooms))]
        missing = [gt.rooms[k].id for k in range(len(gt.rooms)) if not self.views[k]]
        if missing:
            raise StageError(f"scene {gt.name}: no navigable spot in rooms {missing}")

    def largest_room(self) -> int:
        return max(range(len(self.gt.rooms)), key=lambda k: np.ptp(np.asarray(self.gt.rooms[k].polygon), axis=0).prod())

    def _walk_path(self, walker: _Walker, here: np.ndarray, pred: np.ndarray, goal: int):
        fs, node = self.fs, self.node
        path = [goal]
        while path[-1] != node[here[0], here[1]]:
            path.append(int(pred[path[-1]]))
        cells = np.argwhere(node >= 0)[np.argsort(node[node >= 0])][path[::-1]]
        pts = fs.grid.cell_to_world(cells)
        pts[0] = walker.xy
        pulled = _string_pull(fs, pts)
        for a, b in zip(pulled[:-1], pulled[1:]):
            walker.go(b, a)

    def visit_next(self, walker: _Walker, queue: list[tuple[int, int]], visited: list[str]):
        """Walk to the geodesically nearest queued viewpoint ``(room, index)``, spin there, and take it off
        ``queue``; a viewpoint furniture cut off is first moved to the room's most open reachable spot."""
        fs, node, views = self.fs, self.node, self.views
        here = fs.grid.world_to_cell(walker.xy)
        dist, pred = dijkstra(self.graph, indices=int(node[here[0], here[1]]), return_predecessors=True)
        cands = [(dist[node[tuple(fs.grid.world_to_cell(views[k][v]))]], k, v) for k, v in queue]
        d, k, v = min(cands)
        if not np.isfinite(d):
            # Furniture can cut a pocket off a room; look from the room's most open reachable spot instead.
            reachable = np.isfinite(dist[np.maximum(node, 0)]) & (node >= 0) & (fs.room_of_cell == k)
            if not reachable.any():
                raise StageError(f"scene {self.gt.name}: room {self.gt.rooms[k].id} is not reachable from "
                                 f"{visited[0]}")
            cells = np.argwhere(reachable)
            views[k][v] = fs.grid.cell_to_world(cells[int(np.argmax(fs.clearance_m[reachable]))])
            return
        queue.remove((k, v))
        self._walk_path(walker, here, pred, int(node[tuple(fs.grid.world_to_cell(views[k][v]))]))
        walker.spin()
        visited.append(self.gt.rooms[k].id)

    def walk_to(self, walker: _Walker, xy: np.ndarray, what: str):
        """Walk the geodesic shortest path to ``xy`` (``what`` names it in the error when it is out of reach)."""
        here = self.fs.grid.world_to_cell(walker.xy)
        dist, pred = dijkstra(self.graph, indices=int(self.node[here[0], here[1]]), return_predecessors=True)
        goal = int(self.node[tuple(self.fs.grid.world_to_cell(xy))])
        if goal < 0 or not np.isfinite(dist[goal]):
            raise StageError(f"scene {self.gt.name}: {what} at {np.round(xy, 2).tolist()} is not reachable")
        self._walk_path(walker, here, pred, goal)


def plan_actions(gt: GTScene, radius_m: float, min_actions: int) -> tuple[np.ndarray, list[str]]:
    """``(A+1, 4)`` states (x, y, yaw, z of the walking surface) after each action, and the room ids in visiting
    order."""
    if gt.floors:
        return _plan_building(gt, radius_m, min_actions)
    tour = _FloorTour(gt, radius_m)
    n_rooms = len(gt.rooms)
    start_room = tour.largest_room()
    walker = _Walker(tour.fs, tour.views[start_room][0], z=gt.floor_z)
    walker.spin()
    visited = [gt.rooms[start_room].id]
    queue = [(k, 0) for k in range(n_rooms) if k != start_room]
    level = 0
    while queue:
        tour.visit_next(walker, queue, visited)
        if not queue and len(walker.states) - 1 < min_actions:
            level += 1  # another round through the rooms' next viewpoints
            queue = [(k2, level) for k2 in range(n_rooms) if len(tour.views[k2]) > level]
            if not queue:
                level = 0
                queue = [(k2, 0) for k2 in range(n_rooms)]
    return np.asarray(walker.states), visited


STAIR_SPOT_M = 0.5  # the robot stands this far before a flight's foot / beyond its top to take it


def _floor_shares(tours: list[_FloorTour], min_actions: int) -> list[int]:
    """Actions each floor's tour takes at least: ``min_actions`` split by the floors' navigable areas."""
    area = np.array([float(t.fs.navigable.sum()) * t.fs.grid.cell_size_m ** 2 for t in tours])
    return [int(np.ceil(min_actions * a / area.sum())) for a in area]


def _stair_halls(tour: _FloorTour, floor: int, stairs: list[GTStair]) -> list[int]:
    """Per room of ``tour``: 1 for a room a flight starts or ends in on ``floor`` (the stair hall), else 0. The
    first round walks such a room to its second viewpoint too, the farthest from its most open spot (the landing):
    the hall's dead end beyond the flight, which no room's doorway leads through."""
    fs = tour.fs
    out = [0] * len(tour.gt.rooms)
    for s in stairs:
        for end, on in ((s.bottom, s.lower), (s.top, s.upper)):
            if on == floor:
                rc = np.clip(fs.grid.world_to_cell(np.asarray(end[:2])), 0, [fs.grid.rows - 1, fs.grid.cols - 1])
                near = fs.room_of_cell[max(rc[0] - 2, 0):rc[0] + 3, max(rc[1] - 2, 0):rc[1] + 3]
                for k in np.unique(near[near >= 0]):
                    out[int(k)] = 1
    return out


def _plan_building(gt: GTScene, radius_m: float, min_actions: int) -> tuple[np.ndarray, list[str]]:
    """Up through every floor, touring each as an apartment is toured, in whole rounds of further viewpoints, until
    it has its share of ``min_actions`` (:func:`_floor_shares`), then back down to floor 0. A round is never cut
    short: a room left at one viewpoint while the others got two is what a floor's grid misses most."""
    floors = gt.all_floors
    tours = [_FloorTour(gt.floor_view(f.id), radius_m) for f in floors]
    by_lower = {s.lower: s for s in gt.stairs}
    missing = [f.id for f in floors[:-1] if f.id not in by_lower]
    if missing:
        raise StageError(f"scene {gt.name}: no stairs up from floors {missing}")
    shares = _floor_shares(tours, min_actions)
    start_room = tours[0].largest_room()
    walker = _Walker(tours[0].fs, tours[0].views[start_room][0], z=floors[0].floor_z)
    walker.spin()
    visited = [tours[0].gt.rooms[start_room].id]

    def climb(floor: int, up: bool) -> int:
        stair = by_lower[floor if up else floor - 1]
        spot = np.asarray(stair.bottom[:2] if up else stair.top[:2])
        way = np.subtract(stair.top[:2], stair.bottom[:2])
        spot = spot + (-1 if up else 1) * STAIR_SPOT_M * way / np.hypot(*way)
        tours[floor].walk_to(walker, spot, f"the {'foot' if up else 'top'} of {stair.id}")
        reached = stair.upper if up else stair.lower
        walker.take_stairs(stair, up, tours[reached].fs, floors[reached].floor_z, STAIR_SPOT_M)
        return reached

    for f, tour in enumerate(tours):
        if f > 0:
            climb(f - 1, True)
        arrived = len(walker.states) - (1 if f == 0 else 0)  # floor 0's share counts its first spin
        n_rooms = len(tour.gt.rooms)
        ahead = _stair_halls(tour, floors[f].id, gt.stairs)
        queue = [(k, v) for k in range(n_rooms) for v in range(1 + ahead[k])
                 if not (f == 0 and k == start_room and v == 0) and v < len(tour.views[k])]
        level = 0
        while queue:  # the apartment's rounds (plan_actions), each one whole
            tour.visit_next(walker, queue, visited)
            if not queue and len(walker.states) - arrived < shares[f]:
                level += 1
                queue = [(k, level + ahead[k]) for k in range(n_rooms) if len(tour.views[k]) > level + ahead[k]]
                if not queue:
                    level = 0
                    queue = [(k, 0) for k in range(n_rooms)]
    for f in range(len(floors) - 1, 0, -1):
        climb(f, False)
    return np.asarray(walker.states), visited


def sample_trajectory(states: np.ndarray, frames: int, fps: float, camera_height_m: float,
                      start_ns: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Stretch the action states ``(A+1, 3 or 4)`` (x, y, yaw[, z of the walking surface]) over ``frames`` frames
    at ``fps``; the camera is ``camera_height_m`` above the walking surface.

    Returns key stamps ``(A+1,)`` int64 ns and key poses ``(A+1,4,4)`` (one per action boundary,
    spanning the recording), and frame stamps ``(frames,)`` and frame poses ``(frames,4,4)``.
    """
    duration_ns = int(round((frames - 1) / fps * 1e9))
    n = len(states)
    key_ns = start_ns + np.round(np.linspace(0, duration_ns, n)).astype(np.int64)
    surface = states[:, 3] if states.shape[1] > 3 else np.zeros(n)
    key_poses = np.stack([camera_pose_from_base(x, y, yaw, camera_height_m + z)
                          for (x, y, yaw), z in zip(states[:, :3], surface)])
    frame_ns = start_ns + np.round(np.arange(frames) * 1e9 / fps).astype(np.int64)
    frame_ns[-1] = key_ns[-1]
    return key_ns, key_poses, frame_ns, interpolate_poses(key_ns, key_poses, frame_ns)
