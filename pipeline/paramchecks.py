"""Cross-field checks of params at load: values each valid alone that together cannot work.

The schema (:mod:`pipeline.config`) checks each key; these check what follows from several, so that a stage never
starts on values that must fail later in a traceback, an allocation the machine cannot make, or a loop that does
not end. Each error names the keys and says what would work.

- every integer within what numpy and zarr store (a signed 64-bit integer);
- the TSDF voxel: at least :data:`MIN_VOXEL_M` (a smaller one rounds the lattice to nothing) and
  ``grid.cell_size_m`` a whole multiple of it, at most :data:`MAX_VOXELS_PER_CELL` voxels per cell edge;
- the grid: its extent (rows and columns times the cell) within :data:`MAX_EXTENT_M`, and the memory of its
  layers and of one fused feature map within the machine's physical memory;
- simulated scenes: images within :data:`MAX_IMAGE_SIDE` pixels a side, and a block of rendered frames within
  the machine's memory.
"""

from __future__ import annotations

import os

from pipeline.errors import ConfigError

INT_BOUND = 2**63 - 1  # what an int64 array or attribute holds
MIN_VOXEL_M = 0.001  # a 1 mm TSDF voxel is finer than any depth camera resolves
MAX_VOXELS_PER_CELL = 64  # voxels per grid-cell edge (the defaults: 2)
MAX_EXTENT_M = 10_000.0  # a grid side of 10 km holds any building or campus
MAX_IMAGE_SIDE = 16_384  # pixels a side of a simulated image
GRID_BYTES_PER_CELL = 64  # the grid layers of recon.zarr (heights, occupancy, counts, colours), bytes per cell
FEATURE_BYTES = 4  # float32 accumulators of a fused feature map
FEATURE_DIM = 512  # the smallest feature size of the built-in encoders (LSeg, CLIP ViT-B)
RENDER_BYTES_PER_PIXEL = 200  # the simulator's ray casting: ~60 MB per 640x480 frame


def physical_memory() -> int:
    """Bytes of physical memory of this machine (0 when the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):
        return 0


def check_params(params, origin: str, *, memory: int | None = None) -> None:
    """Raise :class:`ConfigError` (one line per problem, each naming ``origin`` and the keys) when ``params`` cannot
    work together; ``memory``: bytes available (default: this machine's physical memory)."""
    memory = physical_memory() if memory is None else memory
    problems = [*_integers(params.model_dump(), ()), *_voxel(params), *_grid(params, memory),
                *_simulated(params, memory)]
    if problems:
        raise ConfigError("\n".join(f"{origin}: {p}" for p in problems))


def _integers(node, where: tuple) -> list[str]:
    """Every integer of ``node`` (the dumped params) outside ±:data:`INT_BOUND`, by key path."""
    if isinstance(node, bool):
        return []
    if isinstance(node, int):
        if abs(node) > INT_BOUND:
            digits = len(str(abs(node)))
            return [f"{'.'.join(map(str, where))}: an integer of {digits} digits is out of range (expected at most "
                    f"{INT_BOUND:,} in magnitude)"]
        return []
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, (list, tuple)) else ()
    return [p for key, value in items for p in _integers(value, (*where, key))]


def _voxel(params) -> list[str]:
    voxel, cell = params.reconstruct.voxel_size_m, params.grid.cell_size_m
    if voxel < MIN_VOXEL_M:
        return [f"reconstruct.voxel_size_m: {voxel:g} m is below {MIN_VOXEL_M:g} m (the TSDF lattice would round to "
                f"nothing; grid.cell_size_m is {cell:g} m)"]
    ratio = cell / voxel
    if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
        return [f"grid.cell_size_m ({cell:g}) must be a whole multiple of reconstruct.voxel_size_m ({voxel:g}) so "
                f"cell centres fall on the TSDF lattice (e.g. voxel_size_m: {cell / max(1, round(ratio)):g})"]
    if round(ratio) > MAX_VOXELS_PER_CELL:
        return [f"reconstruct.voxel_size_m ({voxel:g}) gives {round(ratio)} voxels per edge of a "
                f"grid.cell_size_m ({cell:g}) cell (expected at most {MAX_VOXELS_PER_CELL})"]
    return []


def _grid(params, memory: int) -> list[str]:
    g = params.grid
    out = []
    for key, count in (("grid.rows", g.rows), ("grid.cols", g.cols)):
        if count * g.cell_size_m > MAX_EXTENT_M:
            out.append(f"{key}: {count:,} cells of {g.cell_size_m:g} m span {count * g.cell_size_m:,.0f} m (expected "
                       f"at most {MAX_EXTENT_M:,.0f} m a side)")
    if out:
        return out
    dim = FEATURE_DIM
    need = g.rows * g.cols * (GRID_BYTES_PER_CELL + FEATURE_BYTES * dim)
    if memory and need > memory:
        out.append(f"grid.rows x grid.cols: {g.rows:,} x {g.cols:,} cells need about {_size(need)} for the grid "
                   f"layers and one {dim}-dim feature map, more than this machine's {_size(memory)} of memory "
                   f"(lower grid.rows / grid.cols or raise grid.cell_size_m)")
    return out


def _simulated(params, memory: int) -> list[str]:
    if not any(s.simulated for s in params.scenes.values()):
        return []
    s = params.simulate
    out = [f"simulate.{key}: {value:,} pixels (expected at most {MAX_IMAGE_SIDE:,})"
           for key, value in (("width", s.width), ("height", s.height)) if value > MAX_IMAGE_SIDE]
    if out:
        return out
    need = s.render_block_frames * s.width * s.height * RENDER_BYTES_PER_PIXEL
    if memory and need > memory:
        out.append(f"simulate.render_block_frames x simulate.width x simulate.height: {s.render_block_frames:,} "
                   f"frames of {s.width:,} x {s.height:,} need about {_size(need)} to render, more than this "
                   f"machine's {_size(memory)} of memory")
    return out


def _size(n: int) -> str:
    for unit, scale in (("TB", 1 << 40), ("GB", 1 << 30), ("MB", 1 << 20)):
        if n >= scale:
            return f"{n / scale:,.1f} {unit}"
    return f"{n:,} bytes"
