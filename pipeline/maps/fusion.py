"""Vectorized fusion of dense pixel features into the top-down grid and a sparse voxel map.

Geometry: pixels are back-projected at the ENCODER's resolution (``DenseFeatures.intrinsics`` and
``DenseFeatures.resample_depth``) with each frame's ``T_world_camera``; a point lands in the grid
cell :meth:`GridSpec.world_to_cell` gives and in height level
``floor((z - floor_z - min_height_m) / level_height_m)``. Points outside the grid, outside the
height band ``[floor + min_height_m, floor + max_height_m)``, outside the depth range, on depth
edges (flying pixels) or where the encoder marks the feature invalid are not fused.

Height rule (the same for both maps): a cell's top-down feature is the weighted mean of the
points in its HIGHEST observed level. This is navchat's "top occupied voxel per column"
projection; VLMaps' 2-D map instead averages every height, which mixes a table's top with the
floor seen under it and a cup with the table it stands on. The top rule matches what a top-down
view (and recon's colour map) shows and what ``GTScene.instance_footprints`` rasterises
(taller parts win), and it is order-independent: a level-``k`` point only survives if no point of
that column ever lands above level ``k``.

- :class:`TopDownAccumulator` (vlmap) applies the rule while streaming: per cell one fp32 feature
  sum, a weight, a count and the top level; when a higher level appears, the cell restarts.
  Memory: one int32 slot per grid cell + ``(observed cells, D)`` fp32.
- :class:`VoxelAccumulator` (cfmap) keeps every level: ``(observed voxels, D)`` fp32 sums behind
  an int32 slot lattice (rows x cols x levels) allocated by squares where keys are written
  (:class:`~pipeline.maps.segments.TilePagedIndex`: 4 bytes per voxel of the squares a chunk reaches,
  not of the floor). :meth:`VoxelAccumulator.top_down` projects it with the same rule, so the
  cfmap's top-down equals a TopDownAccumulator fed the same points.

Both grow their feature sums by segments, never copied (:mod:`pipeline.maps.segments`: memory bounded
by the observed cells/voxels, never by the number of frames) and add a whole block with one sparse one-hot x
dense product over the slots the block touches (pixels that are not fused are empty rows), so no Python loop runs over
pixels or points. Means are taken as ``sum / weight`` before normalising (ConceptFusion weights
reach 1e-15 at 5 m). Features whose cells take rows of a small table
(:class:`~pipeline.encoders.base.PaletteFeatures`: the oracle) are added in factored form: point
weights summed per (slot, table row), then one weighted table row per pair, so a block costs
``O(points + pairs x D)`` instead of ``O(points x D)``.

Chunks and folds: :meth:`_Accumulator.state` gives an accumulator's content as a :class:`FusionState`
(the partial of one chunk of frames) and :meth:`_Accumulator.merge` folds such a state into another
accumulator by the same rules (voxels: sums add; top-down: the higher top level wins, equal tops add).
Folding chunk states in a fixed order gives the same floats whatever ran the chunks (and the same as
folding a stored fold of a prefix of them, :mod:`pipeline.maps.incremental`): every key's rows are
added elementwise, in chunk order, starting from zero.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch

from pipeline.encoders.base import DenseFeatures, PaletteFeatures
from pipeline.geometry import GridSpec, Intrinsics, backproject
from pipeline.maps.segments import SegmentedRows, TilePagedIndex
from pipeline.maps.store import Lattice, MapCells, MapVoxels


@dataclass
class BlockPoints:
    """Where each feature pixel of a block goes.

    ``cell``: ``(B*h*w,)`` int64 flat cell ``row * cols + col``, -1 where the pixel is not fused.
    ``level``: ``(B*h*w,)`` int64 height level (undefined where ``cell`` is -1).
    ``dist_m``: ``(B*h*w,)`` float32 distance from the camera, metres.
    """

    cell: np.ndarray
    level: np.ndarray
    dist_m: np.ndarray

    @property
    def n_fused(self) -> int:
        return int((self.cell >= 0).sum())


def depth_edges(depth_m: np.ndarray, max_jump: float) -> np.ndarray:
    """``(B,h,w)`` bool: pixels whose depth differs from a 4-neighbour by more than ``max_jump * depth``."""
    d = np.asarray(depth_m, dtype=np.float32)
    edge = np.zeros(d.shape, dtype=bool)
    if max_jump <= 0:
        return edge
    tol = max_jump * d
    dv = np.abs(np.diff(d, axis=1))
    dh = np.abs(np.diff(d, axis=2))
    edge[:, 1:] |= dv > tol[:, 1:]
    edge[:, :-1] |= dv > tol[:, :-1]
    edge[:, :, 1:] |= dh > tol[:, :, 1:]
    edge[:, :, :-1] |= dh > tol[:, :, :-1]
    return edge


def locate_block(
    lattice: Lattice,
    depth_m: np.ndarray,
    valid: np.ndarray,
    T_world_camera: np.ndarray,
    intr: Intrinsics,
    *,
    depth_min_m: float,
    depth_max_m: float,
    max_depth_jump: float = 0.0,
    z_band: tuple[float, float] | None = None,
) -> BlockPoints:
    """Back-project a block of feature-resolution depth and assign cells and levels.

    ``depth_m`` ``(B,h,w)`` float32 metres at the feature resolution (0 = invalid), ``valid``
    ``(B,h,w)`` bool feature validity, ``T_world_camera`` ``(B,4,4)``, ``intr`` the feature grid's
    intrinsics (``DenseFeatures.intrinsics``). ``z_band`` ``(lo, hi)`` world z, metres: only points with
    ``lo <= z < hi`` are fused (one floor's band of a building, :func:`~pipeline.recon.store.floor_bands`).
    """
    depth_m = np.asarray(depth_m, dtype=np.float32)
    B, h, w = depth_m.shape
    keep = np.asarray(valid, dtype=bool) & (depth_m >= depth_min_m) & (depth_m <= depth_max_m)
    if max_depth_jump > 0:
        keep &= ~depth_edges(depth_m, max_depth_jump)
    pts_cam = np.stack([backproject(depth_m[b], intr) for b in range(B)])  # (B,h,w,3)
    T = np.asarray(T_world_camera, dtype=np.float32)
    pts = (np.matmul(pts_cam.reshape(B, h * w, 3), T[:, :3, :3].transpose(0, 2, 1)) + T[:, None, :3, 3]).reshape(-1, 3)
    rc = lattice.grid.world_to_cell(pts[:, :2])
    level = np.floor((pts[:, 2] - (lattice.floor_z + lattice.min_height_m)) / lattice.level_height_m).astype(np.int64)
    keep = keep.reshape(-1) & lattice.grid.inside(rc) & (level >= 0) & (level < lattice.levels)
    if z_band is not None:
        keep &= (pts[:, 2] >= z_band[0]) & (pts[:, 2] < z_band[1])
    cell = np.where(keep, rc[:, 0] * lattice.grid.cols + rc[:, 1], -1)
    dist = np.linalg.norm(pts_cam.reshape(-1, 3), axis=1).astype(np.float32)
    return BlockPoints(cell=cell, level=level, dist_m=dist)


def point_weights(dist_m: np.ndarray, sigma_m: float | None) -> np.ndarray | None:
    """ConceptFusion confidence ``exp(-d^2 / 2 sigma^2)``; None = count weights (every point 1)."""
    if sigma_m is None:
        return None
    return np.exp(-(dist_m.astype(np.float32) ** 2) / np.float32(2.0 * sigma_m**2))


class _SlotStore:
    """Growable ``(capacity, D)`` fp32 sums (in segments, :mod:`pipeline.maps.segments`) + weights + counts; slot 0
    is a scratch row."""

    def __init__(self, dim: int, n_keys: int, device: torch.device, capacity: int = 4096,
                 slot_of: TilePagedIndex | None = None):
        self.dim, self.device = dim, device
        # each key's slot (-1: none yet); a voxel lattice's is paged (TilePagedIndex), a grid's is one tensor
        self.slot_of = torch.full((n_keys,), -1, dtype=torch.int32, device=device) if slot_of is None else slot_of
        self.keys = torch.full((capacity,), -1, dtype=torch.int64, device=device)
        self.sum = SegmentedRows(dim, device, capacity)
        self.sum.zero_range_(0, 1)
        self.weight = torch.zeros(capacity, dtype=torch.float64, device=device)
        self.count = torch.zeros(capacity, dtype=torch.int64, device=device)
        self.used = 1  # slot 0 collects pixels that are not fused
        self._rows = torch.empty((0, dim), dtype=torch.float32, device=device)  # see _buffer

    def slots(self, keys: torch.Tensor) -> torch.Tensor:
        """Slots ``(P,)`` of ``keys`` ``(P,)`` int64 (repeats allowed); new keys get new slots in ascending order."""
        slot = self.slot_of[keys]
        missing = torch.nonzero(slot < 0).squeeze(1)
        if len(missing):
            new_keys = _distinct(keys[missing], self.slot_of)  # only keys never seen: few after the first blocks
            need = self.used + len(new_keys)
            if need > self.capacity:
                self._grow(need)
            fresh = torch.arange(self.used, need, device=self.device)
            self.slot_of[new_keys] = fresh.to(torch.int32)
            self.keys[fresh] = new_keys
            self.sum.zero_range_(self.used, need)  # grown rows are unwritten until given out (_grow)
            for rows in (self.weight, self.count):
                rows[self.used : need] = 0
            self.used = need
            slot = self.slot_of[keys]
        return slot.long()

    @property
    def capacity(self) -> int:
        return self.keys.shape[0]

    def _grow(self, need: int) -> None:
        """Double the capacity until ``need`` slots fit. The sums grow by segments, nothing copied; of the small
        columns only the slots in use are copied. Rows past the used ones are left unwritten (:meth:`slots` zeroes
        them as it gives them out), so the memory a store holds is its used rows, not its capacity."""
        cap = self.capacity
        while cap < need:
            cap *= 2
        self.sum.reserve(cap)
        for name in ("weight", "count", "keys"):
            old = getattr(self, name)
            new = torch.empty((cap,) + tuple(old.shape[1:]), dtype=old.dtype, device=self.device)
            new[: self.used] = old[: self.used]
            setattr(self, name, new)

    def add(self, target: torch.Tensor, features: torch.Tensor, weights: np.ndarray | None,
            index: torch.Tensor | None = None) -> None:
        """Add rows of ``features`` ``(P,D)`` (times ``weights`` ``(P,)``) into slots ``target`` ``(P,)`` (0 = skip).

        With ``index`` ``(P,)`` int64, ``features`` is a ``(T,D)`` palette and point ``p``'s feature is
        ``features[index[p]]`` (:class:`~pipeline.encoders.base.PaletteFeatures`).

        Dense rows: one sparse x dense product, a ``(P, K)`` one-hot matrix (one non-zero per fused
        point, its weight, in the column of its slot among the ``K`` slots the block touches)
        transposed times the features. It reads each feature row once and needs no ``features *
        weights`` copy; on CPU it is about 1.5x faster than ``index_add_`` (benchmarks/bench_maps.py).

        Palette rows: the weights are first summed per (slot, palette row) pair in float64; each pair
        then adds its palette row times that sum, so the cost grows with the slots touched, not with
        ``P x D``. Both write their ``(K or pairs, D)`` rows into a buffer kept across blocks (fresh
        pages of a new tensor cost more than the arithmetic) and ``index_add_`` them in a fixed order.
        """
        fused = target > 0
        keep = torch.nonzero(fused).squeeze(1)
        if not len(keep):
            return
        t = target[keep]
        touched = _distinct(t, self._scratch_index())
        self._pos[touched] = torch.arange(len(touched), device=self.device)
        local = self._pos[t]
        k = len(touched)
        if weights is None:
            w = torch.ones(len(keep), dtype=torch.float32, device=self.device)
        else:
            w = torch.from_numpy(np.asarray(weights, np.float32)).to(self.device)[keep]
        if index is None:
            crow = torch.zeros(len(target) + 1, dtype=torch.int64, device=self.device)
            torch.cumsum(fused, 0, out=crow[1:])  # rows of points that are not fused stay empty (never read)
            with warnings.catch_warnings():  # "sparse CSR support is in beta": the product used here is stable
                warnings.simplefilter("ignore", UserWarning)
                onehot = torch.sparse_csr_tensor(crow, local, w, size=(len(target), k))
                rows = torch.mm(onehot.t(), features, out=self._buffer(k))
            self.sum.index_add_(touched, rows)
        else:
            n_rows = features.shape[0]
            pair, inverse = torch.unique(local * n_rows + index[keep], sorted=True, return_inverse=True)
            pair_weight = torch.zeros(len(pair), dtype=torch.float64, device=self.device)
            pair_weight.index_add_(0, inverse, w.double())
            rows = torch.index_select(features, 0, pair % n_rows, out=self._buffer(len(pair)))
            rows.mul_(pair_weight.float()[:, None])
            self.sum.index_add_(touched[pair // n_rows], rows)
        counts = torch.bincount(local, minlength=k)
        self.weight[touched] += counts if weights is None else torch.bincount(local, weights=w.double(), minlength=k)
        self.count[touched] += counts

    def _buffer(self, n: int) -> torch.Tensor:
        """A ``(n, D)`` float32 scratch tensor reused across blocks (grown by doubling)."""
        if self._rows.shape[0] < n:
            self._rows = torch.empty((max(n, 2 * self._rows.shape[0]), self.dim), dtype=torch.float32, device=self.device)
        return self._rows[:n]

    def _scratch_index(self) -> torch.Tensor:
        """An int64 scratch array over the slots (grown with them)."""
        if getattr(self, "_pos", None) is None or self._pos.shape[0] < self.capacity:
            self._pos = torch.full((self.capacity,), -1, dtype=torch.int64, device=self.device)
        return self._pos

    def observed(self) -> tuple[np.ndarray, np.ndarray]:
        """Keys and slots of every allocated row, keys ascending."""
        keys = self.keys[1 : self.used].cpu().numpy()
        order = np.argsort(keys, kind="stable")
        return keys[order], order + 1


def _distinct(values: torch.Tensor, scratch: torch.Tensor) -> torch.Tensor:
    """Distinct ``values`` ``(P,)`` int64, ascending, in O(P) + a sort of the distinct ones only.

    ``scratch`` is any int tensor indexable by ``values``; its entries at ``values`` are overwritten.
    Each value's entry keeps the position of one of its occurrences (whichever write lands last), so
    exactly one occurrence per value sees its own position.
    """
    pos = torch.arange(len(values), device=values.device)
    scratch[values] = pos.to(scratch.dtype)
    return torch.sort(values[scratch[values].long() == pos]).values


def _unit_means(sums: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``(N,D)`` float32 unit-norm weighted means of ``sums`` ``(N,D)`` with total weights ``weight`` ``(N,)``.

    Dividing by the weight first matters: ConceptFusion weights ``exp(-d^2 / 2 sigma^2)`` reach 1e-15
    at 5 m, and ``normalize`` clamps norms below 1e-12, which would shrink such a cell's feature
    towards zero instead of giving it unit norm.
    """
    out = torch.empty(sums.shape, dtype=torch.float32, device=sums.device)
    for s in range(0, len(sums), 1 << 15):  # row chunks: float64 temporaries of 128 MB at most (D = 512)
        w = weight[s : s + (1 << 15)].to(torch.float64).clamp_min(1e-300)[:, None]
        out[s : s + len(w)] = torch.nn.functional.normalize((sums[s : s + len(w)].to(torch.float64) / w).float(), dim=1)
    return out


def _flat_features(features: torch.Tensor, device: torch.device) -> torch.Tensor:
    f = features.reshape(-1, features.shape[-1])
    return f.to(device=device, dtype=torch.float32)


class _Accumulator:
    """Shared streaming part of the accumulators: a slot store over ``n_keys`` keys and the block loop."""

    def __init__(self, lattice: Lattice, dim: int, n_keys: int, device: str | torch.device,
                 slot_of: TilePagedIndex | None = None):
        self.lattice, self.dim = lattice, dim
        self.device = torch.device(device)
        self.store = _SlotStore(dim, n_keys, self.device, slot_of=slot_of)
        self.points_fused = 0

    def add(self, points: BlockPoints, features: "torch.Tensor | DenseFeatures", weights: np.ndarray | None = None
            ) -> None:
        """Fuse one block: ``features`` ``(B,h,w,D)`` (or ``(P,D)``) rows matching ``points``, or the encoder's
        :class:`DenseFeatures` of the block (a :class:`PaletteFeatures` is added in its factored form)."""
        dev = self.device
        cell = torch.from_numpy(points.cell).to(dev)
        fused = cell >= 0
        target = torch.zeros_like(cell)
        if bool(fused.any()):
            target[fused] = self._slots(cell[fused], torch.from_numpy(points.level).to(dev)[fused])
        if isinstance(features, PaletteFeatures):
            self.store.add(target, features.palette.to(device=dev, dtype=torch.float32), weights,
                           index=features.index.reshape(-1).to(dev))
            return
        if isinstance(features, DenseFeatures):
            features = features.features
        self.store.add(target, _flat_features(features, dev), weights)

    def _slots(self, cell: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """Store slots of the in-grid points (0 = not fused); counts them in ``points_fused``."""
        raise NotImplementedError

    def state(self) -> "FusionState":
        """A copy of the content (keys ascending), e.g. one chunk's partial to fold elsewhere."""
        return self.rows(*self.store.observed())

    def observed(self) -> tuple[np.ndarray, np.ndarray]:
        """``(keys, slots)`` of every key holding rows, keys ascending (for :meth:`rows`)."""
        return self.store.observed()

    def rows(self, keys: np.ndarray, slots: np.ndarray) -> "FusionState":
        """A copy of the rows of ``slots`` (keys ``keys``, as :meth:`observed` pairs them): a part of :meth:`state`
        (e.g. one spatial tile's, :mod:`pipeline.maps.spill`) without a copy of the whole."""
        s = torch.from_numpy(np.asarray(slots, np.int64)).to(self.device)
        top = self._top()
        return FusionState(keys=np.asarray(keys, np.int64), sum=self.store.sum.gather(s).cpu(),
                           weight=self.store.weight[s].cpu(), count=self.store.count[s].cpu(),
                           top=None if top is None else top[s].cpu())

    def merge(self, part: "FusionState") -> None:
        """Fold ``part`` (another accumulator's :meth:`state` on the same lattice) into this one."""
        if (part.top is None) != (self._top() is None) or part.sum.shape[1:] != (self.dim,):
            raise ValueError(f"cannot fold a {part.sum.shape[1:]}-feature state with top={part.top is not None} "
                             f"into a {type(self).__name__} of {self.dim} features")
        if not len(part.keys):
            return
        dev = self.device
        slot = self.store.slots(torch.from_numpy(part.keys).to(dev))  # distinct keys: distinct slots
        rows = torch.arange(len(slot), device=dev)
        if part.top is not None:
            top = self._grown_top()
            ptop = part.top.to(dev)
            restart = ptop > top[slot]
            r = slot[restart]
            self.store.sum.zero_(r)
            self.store.weight[r] = 0
            self.store.count[r] = 0
            top[r] = ptop[restart]
            rows = torch.nonzero(ptop == top[slot]).squeeze(1)
            slot = slot[rows]
        self.store.sum.index_add_(slot, part.sum.to(dev)[rows])
        self.store.weight.index_add_(0, slot, part.weight.to(dev)[rows])
        self.store.count.index_add_(0, slot, part.count.to(dev)[rows])

    def _top(self) -> torch.Tensor | None:
        """Per-slot top level (top-down accumulators), else None."""
        return None

    @property
    def keeps_top(self) -> bool:
        """Whether the states hold each key's top level (a top-down accumulator's)."""
        return self._top() is not None


@dataclass
class FusionState:
    """What an accumulator holds, on the CPU: the partial of one chunk of frames, or a fold of several.

    ``keys`` ``(N,)`` int64 ascending (flat cells of a top-down accumulator; ``level * cells + cell`` of a voxel
    one), ``sum`` ``(N,D)`` float32 weighted feature sums, ``weight`` ``(N,)`` float64, ``count`` ``(N,)`` int64
    points, ``top`` ``(N,)`` int64 top level (top-down only, else None).
    """

    keys: np.ndarray
    sum: torch.Tensor
    weight: torch.Tensor
    count: torch.Tensor
    top: torch.Tensor | None = None

    @property
    def points(self) -> int:
        """Points in the sums (for a top-down state: in the top levels only)."""
        return int(self.count.sum())

    @property
    def nbytes(self) -> int:
        parts = [self.sum, self.weight, self.count] + ([] if self.top is None else [self.top])
        return int(self.keys.nbytes) + sum(t.numel() * t.element_size() for t in parts)


class TopDownAccumulator(_Accumulator):
    """Streaming top-down fusion with the top-level rule (see the module docstring)."""

    def __init__(self, lattice: Lattice, dim: int, *, device: str | torch.device = "cpu"):
        super().__init__(lattice, dim, lattice.cells, device)
        self.top = torch.full((self.store.capacity,), -1, dtype=torch.int64, device=self.device)

    def _top(self) -> torch.Tensor:
        return self.top

    def _grown_top(self) -> torch.Tensor:
        """``top`` grown to the store's capacity (new slots -1: no level yet)."""
        if self.top.shape[0] < self.store.capacity:
            grown = torch.full((self.store.capacity,), -1, dtype=torch.int64, device=self.device)
            grown[: self.top.shape[0]] = self.top
            self.top = grown
        return self.top

    def _slots(self, cell: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        dev = self.device
        slot = self.store.slots(cell)
        self._grown_top()
        n = self.store.used
        block_top = torch.full((n,), -1, dtype=torch.int64, device=dev).scatter_reduce_(0, slot, level, "amax")
        restart = torch.nonzero(block_top > self.top[:n]).squeeze(1)
        self.store.sum.zero_(restart)
        self.store.weight[restart] = 0
        self.store.count[restart] = 0
        self.top[restart] = block_top[restart]
        on_top = level == self.top[slot]
        self.points_fused += int(on_top.sum())
        return torch.where(on_top, slot, torch.zeros_like(slot))

    def result(self) -> "FusedCells":
        return FusedCells.from_state(self.state())


class VoxelAccumulator(_Accumulator):
    """Sparse 3-D voxel feature map on the lattice (every level kept; ConceptFusion-style)."""

    def __init__(self, lattice: Lattice, dim: int, *, device: str | torch.device = "cpu"):
        grid = lattice.grid
        super().__init__(lattice, dim, lattice.cells * lattice.levels, device,
                         slot_of=TilePagedIndex(grid.rows, grid.cols, lattice.levels, device))

    def _slots(self, cell: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        self.points_fused += len(cell)
        return self.store.slots(level * self.lattice.cells + cell)

    def result(self) -> "FusedVoxels":
        return FusedVoxels.from_state(self.state(), self.lattice)


@dataclass
class FusedCells:
    """A fused top-down map, cells ascending. ``features`` ``(N,D)`` float32 unit norm."""

    cell: np.ndarray  # (N,) int64 flat row * cols + col
    features: torch.Tensor  # (N,D) float32, L2-normalised weighted means
    weight: np.ndarray  # (N,) float32 sum of point weights
    count: np.ndarray  # (N,) int32 points fused
    level: np.ndarray  # (N,) int16 top level

    @classmethod
    def from_sums(cls, cell, sums, weight, count, level) -> "FusedCells":
        feats = _unit_means(sums, weight)
        return cls(np.asarray(cell, np.int64), feats.cpu(), weight.cpu().numpy().astype(np.float32),
                   count.cpu().numpy().astype(np.int32), level.cpu().numpy().astype(np.int16))

    @classmethod
    def from_state(cls, state: FusionState) -> "FusedCells":
        """The map of a top-down accumulator's state."""
        return cls.from_sums(state.keys, state.sum, state.weight, state.count, state.top)

    def to_store(self) -> MapCells:
        """As the map store writes it (:class:`~pipeline.maps.store.MapCells`, numpy)."""
        return MapCells(cell=self.cell, features=self.features.numpy(), weight=self.weight, count=self.count,
                        level=self.level)


@dataclass
class FusedVoxels:
    """The sparse voxel map: voxel ``i`` is (cell[i], level[i]); keys ascending (level-major)."""

    cell: np.ndarray  # (M,) int64
    level: np.ndarray  # (M,) int64
    sum: torch.Tensor  # (M,D) float32 weighted sums
    weight: torch.Tensor  # (M,) float64
    count: torch.Tensor  # (M,) int64

    @classmethod
    def from_state(cls, state: FusionState, lattice: Lattice) -> "FusedVoxels":
        """The voxel map of a voxel accumulator's state."""
        level, cell = np.divmod(state.keys, lattice.cells)
        return cls(cell=cell, level=level, sum=state.sum, weight=state.weight, count=state.count)

    def features(self) -> torch.Tensor:
        return _unit_means(self.sum, self.weight).cpu()

    def to_store(self, grid: GridSpec) -> MapVoxels:
        """As the map store writes it (:class:`~pipeline.maps.store.MapVoxels`: (row, col, level) keys, fp16)."""
        row, col = np.divmod(self.cell, grid.cols)
        return MapVoxels(key=np.stack([row, col, self.level], axis=1).astype(np.int16),
                         features=self.features().numpy().astype(np.float16),
                         weight=self.weight.cpu().numpy().astype(np.float32),
                         count=self.count.cpu().numpy().astype(np.int32))

    def top_down(self) -> FusedCells:
        """Project with the height rule: each cell takes its highest voxel."""
        # Keys are level-major, so for each cell the LAST occurrence in key order is its top voxel.
        order = np.lexsort((self.level, self.cell))
        last = np.r_[self.cell[order][1:] != self.cell[order][:-1], True]
        pick = torch.from_numpy(order[last])
        return FusedCells.from_sums(self.cell[order[last]], self.sum[pick], self.weight[pick], self.count[pick],
                                    torch.from_numpy(self.level[order[last]]))
