"""The floors of a scene: found from the upward-facing surface and from where the camera walked, or pinned.

Two witnesses, as in HOV-SG's floor segmentation but with surface normals and camera poses:

- **the cameras** (:func:`camera_levels`): a camera carried through a building stands at about the same
  height above each floor, so camera heights cluster per floor (peaks of their histogram at least
  :data:`~pipeline.config.MIN_STOREY_M` apart; frames on stairs lie between and form no peak). This holds
  where a height histogram of the surface is ambiguous (a floor seen only in parts, a building of terraces).
- **the surface** (:func:`estimate_floor`): a floor is horizontal, faces up and lies below the cameras
  standing on it; upward-facing surface can only be seen from above, so the upward points between two
  camera levels belong to the upper one (its floor, its furniture tops, the treads of the stairs up to it).
  Each level's floor is the lowest strong peak of the smoothed height histogram of those points (the
  single-floor rule of every earlier zipon, applied per level).

They are checked against each other (:func:`find_floors`); what disagrees is reported, as a warning
where the floors are still usable and as an error naming the key to set where they are not:
a camera level with no floor surface under it takes the other floors' camera height (warning); two
camera levels over one floor are one floor (warning); a floor-like upward surface (:data:`_FLOOR_LIKE_M2`
or more, :func:`surface_peaks`) that no camera stood on is a floor seen, not walked (warning; pin
``reconstruct.floors`` to map it). Ceilings are the lowest strong peak of the downward-facing surface above
a floor's cameras and below the next floor (None when not seen).

``reconstruct.floors`` pins the floors by hand (:func:`pinned_floors`); a pinned floor with no upward
surface at its height is a one-line :class:`ConfigError` naming the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.signal import find_peaks

from pipeline.config import MIN_STOREY_M, ReconstructParams
from pipeline.errors import ConfigError, StageError
from pipeline.recon import surface as surface_mod
from pipeline.recon.store import Floor
from pipeline.recon.surface import Surface

_UP_COS = 0.9  # normals within ~25 deg of +z count as horizontal, upward-facing surfaces
_FLOOR_BIN_M = 0.01
_FLOOR_MIN_POINTS = 50
_FLOOR_PEAK_FRACTION = 0.3  # the floor is the lowest bin holding >= 30% of the tallest bin
_CAMERA_BIN_M = 0.05  # camera height histogram
_CAMERA_SIGMA_M = 0.1  # its smoothing (Gaussian)
_LEVEL_MIN_FRAMES = 5  # a camera level holds at least this many frames ...
_LEVEL_MIN_FRACTION = 0.02  # ... and this fraction of them
_PEAK_SEPARATION_M = 0.2  # surface histogram peaks at least this far apart (HOV-SG)
_FLOOR_LIKE_M2 = 6.0  # an upward surface this big at one height looks like a floor
_AREA_CELL_M = 0.1  # area of a surface: distinct cells of this edge it covers


@dataclass
class FoundFloors:
    """The floors (lowest first), what disagreed (``warnings``: one line each) and each camera's floor."""

    floors: list[Floor]
    floor_points: list[int]  # upward-facing points each floor's height rests on (0: pinned, or from the cameras)
    warnings: list[str] = field(default_factory=list)
    camera_floor: np.ndarray | None = None  # (F,) int: floor index of each camera, -1 between floors (stairs)
    figures: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- the surface

def _z_of(surface: Surface, select: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> Callable[[], Iterator]:
    """The heights (float32) of the points ``select(xyz, normals)`` keeps, chunk by chunk, afresh at each call."""
    def values():
        for xyz, normals in surface.chunks(("xyz", "normals")):
            yield xyz[select(xyz, normals), 2]
    return values


def _extent(values: Callable[[], Iterator]) -> tuple[int, float, float]:
    """Count, least and greatest of the values (as float64; 0, nan, nan when none)."""
    n, lo, hi = 0, np.inf, -np.inf
    for v in values():
        if len(v):
            n, lo, hi = n + len(v), min(lo, float(v.min())), max(hi, float(v.max()))
    return n, (np.float64(lo) if n else np.nan), (np.float64(hi) if n else np.nan)


def _histogram(values: Callable[[], Iterator], base: float, length: int) -> np.ndarray:
    """Counts of the values in :data:`_FLOOR_BIN_M` bins from ``base`` (``length`` bins), float64."""
    hist = np.zeros(length, np.int64)
    for v in values():
        hist += np.bincount(((v.astype(np.float64) - base) / _FLOOR_BIN_M).astype(np.int64), minlength=length)
    return hist.astype(np.float64)


def _lowest_strong_peak(values: Callable[[], Iterator], n: int, z_min: float, z_max: float, *, fixed_bins: bool
                        ) -> tuple[float, int]:
    """The median height of the values near the lowest strong peak of their histogram, and how many those are.

    ``fixed_bins``: the histogram runs one bin past the top (the floor's rule), else to the top's bin (the
    ceiling's)."""
    base = np.floor(z_min / _FLOOR_BIN_M) * _FLOOR_BIN_M
    length = int(np.ceil((z_max - base) / _FLOOR_BIN_M)) + 1 if fixed_bins else \
        int(np.asarray((z_max - base) / _FLOOR_BIN_M).astype(np.int64)) + 1
    smooth = np.convolve(_histogram(values, base, length), np.ones(3), mode="same")
    first = int(np.flatnonzero(smooth >= _FLOOR_PEAK_FRACTION * smooth.max())[0])
    while first + 1 < length and smooth[first + 1] > smooth[first]:  # climb to the local peak
        first += 1
    centre = base + (first + 0.5) * _FLOOR_BIN_M

    def near():
        for v in values():
            yield v[np.abs(v.astype(np.float64) - centre) <= 2 * _FLOOR_BIN_M]
    n_near = surface_mod.count(near)
    return surface_mod.median(near, n_near), n_near


def estimate_floor(surface: Surface, camera_z: np.ndarray, above: float = -np.inf) -> tuple[float, int]:
    """Floor height (world z, metres) under the cameras and the number of floor points it rests on.

    ``surface``: the surface points (only those higher than ``above`` are read); ``camera_z`` ``(F,)`` camera
    heights. The lowest strong peak of the height histogram of upward-facing points below the cameras' median,
    refined by their median. Raises :class:`StageError` when no upward-facing surface lies below the cameras (e.g.
    a world that is not z-up: set ``reconstruct.floor_z_m`` or convert the poses at ingest).
    """
    top = np.median(camera_z)
    values = _z_of(surface, lambda xyz, normals: (xyz[:, 2] > above) & (normals[:, 2] > _UP_COS) & (xyz[:, 2] < top))
    n, z_min, z_max = _extent(values)
    if n < _FLOOR_MIN_POINTS:
        raise StageError(
            f"no floor found: {n} upward-facing surface points below the cameras "
            f"(expected at least {_FLOOR_MIN_POINTS} in a z-up world); set reconstruct.floor_z_m "
            "if the floor is not visible or the world frame is not z-up"
        )
    return _lowest_strong_peak(values, n, z_min, z_max, fixed_bins=True)


def surface_peaks(surface: Surface) -> list[tuple[float, float]]:
    """Peaks of the smoothed height histogram of upward-facing points (1 cm bins, Gaussian sigma 2 bins, peaks
    at least 0.2 m apart, as HOV-SG segments floors): ``[(height m, area m^2)]`` lowest first, ``area`` the
    horizontal area (10 cm cells) the points within 2 cm of the peak cover."""
    up = _z_of(surface, lambda xyz, normals: normals[:, 2] > _UP_COS)
    n, z_min, z_max = _extent(up)
    if n < _FLOOR_MIN_POINTS:
        return []
    lo = np.floor(z_min / _FLOOR_BIN_M) * _FLOOR_BIN_M
    hist = _histogram(up, lo, int(np.asarray((z_max - lo) / _FLOOR_BIN_M).astype(np.int64)) + 1)
    smooth = gaussian_filter1d(hist, sigma=2)
    peaks, _ = find_peaks(smooth, distance=round(_PEAK_SEPARATION_M / _FLOOR_BIN_M), height=_FLOOR_MIN_POINTS / 10)
    centres = [lo + (k + 0.5) * _FLOOR_BIN_M for k in peaks]
    cells = [np.zeros(0, np.int64) for _ in centres]  # each cell (i, j) as one int64: i * 2^32 + (j mod 2^32)
    for xyz, normals in surface.chunks(("xyz", "normals")):
        top = xyz[normals[:, 2] > _UP_COS]
        z = top[:, 2].astype(np.float64)
        for k, centre in enumerate(centres):
            near = np.abs(z - centre) <= 2 * _FLOOR_BIN_M
            if near.any():
                new = np.floor(top[near, :2].astype(np.float64) / _AREA_CELL_M).astype(np.int64)
                cells[k] = np.union1d(cells[k], (new[:, 0] << 32) | (new[:, 1] & 0xFFFFFFFF))
    return [(round(float(c), 3), round(len(seen) * _AREA_CELL_M**2, 2)) for c, seen in zip(centres, cells)]


def ceiling_above(surface: Surface, lo: float, hi: float) -> float | None:
    """The ceiling between world heights ``lo`` (a floor's cameras) and ``hi`` (the next floor): the lowest
    strong peak of downward-facing points there, or None when fewer than 50 were seen."""
    values = _z_of(surface, lambda xyz, normals: (normals[:, 2] < -_UP_COS) & (xyz[:, 2] > lo) & (xyz[:, 2] < hi))
    n, z_min, z_max = _extent(values)
    if n < _FLOOR_MIN_POINTS:
        return None
    return round(_lowest_strong_peak(values, n, z_min, z_max, fixed_bins=False)[0], 4)


# ----------------------------------------------------------------------------- the cameras

def camera_levels(camera_z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heights the cameras cluster at (one per floor walked, lowest first) and each camera's level.

    ``camera_z`` ``(F,)`` metres. Returns ``(levels (L,), label (F,))``; ``label`` is -1 for a camera
    farther than half a storey from every level (on the stairs). Cameras spread over less than
    :data:`MIN_STOREY_M` are one level, every camera on it (a single floor, as every earlier zipon read it).
    """
    z = np.asarray(camera_z, dtype=np.float64)
    if z.size == 0 or z.max() - z.min() < MIN_STOREY_M:
        return np.array([np.median(z)]) if z.size else np.zeros(0), np.zeros(z.size, np.int64)
    lo = z.min() - 5 * _CAMERA_SIGMA_M
    hist = np.bincount(((z - lo) / _CAMERA_BIN_M).astype(np.int64)).astype(np.float64)
    smooth = gaussian_filter1d(np.r_[hist, np.zeros(10)], sigma=_CAMERA_SIGMA_M / _CAMERA_BIN_M)
    peaks, _ = find_peaks(smooth, distance=round(MIN_STOREY_M / _CAMERA_BIN_M))
    centres = lo + (peaks + 0.5) * _CAMERA_BIN_M
    near = np.abs(z[:, None] - centres[None, :]) <= MIN_STOREY_M / 2
    counts = near.sum(axis=0)
    keep = counts >= max(_LEVEL_MIN_FRAMES, _LEVEL_MIN_FRACTION * z.size)
    if not keep.any():
        return np.array([np.median(z)]), np.zeros(z.size, np.int64)
    centres = centres[keep]
    levels = np.array([np.median(z[np.abs(z - c) <= MIN_STOREY_M / 2]) for c in centres])
    dist = np.abs(z[:, None] - levels[None, :])
    label = np.where(dist.min(axis=1) <= MIN_STOREY_M / 2, dist.argmin(axis=1), -1)
    return levels, label


# ----------------------------------------------------------------------------- floors

def find_floors(surface: Surface, camera_z: np.ndarray, p: ReconstructParams) -> FoundFloors:
    """The scene's floors (see the module doc): pinned (``reconstruct.floors`` / ``floor_z_m``) or found.

    ``surface``: the surface points (read a chunk at a time), ``camera_z`` ``(F,)`` heights of the fused cameras.
    One camera level gives exactly the floor every earlier zipon found (:func:`estimate_floor`).
    """
    if p.floors is not None:
        return pinned_floors(surface, camera_z, p)
    if p.floor_z_m is not None:
        return FoundFloors([Floor(id=0, name="floor 0", floor_z_m=float(p.floor_z_m), source="pinned",
                                  frames=int(camera_z.size))], [0], camera_floor=np.zeros(camera_z.size, np.int64))
    levels, label = camera_levels(camera_z)
    peaks = surface_peaks(surface)
    figures = {"camera_levels_m": [round(float(c), 3) for c in levels],
               "surface_peaks": [{"z_m": z, "area_m2": a} for z, a in peaks]}
    if len(levels) == 1:
        z, n = estimate_floor(surface, camera_z)
        floors = [(z, "surface", n)]
        warnings: list[str] = []
    else:
        floors, warnings = _per_level(surface, camera_z, levels, label)
    floors, label, merged = _merge_close(floors, label)
    warnings += merged
    warnings += _unwalked_surfaces(peaks, [z for z, _, _ in floors])
    records = []
    for i, (z, source, _) in enumerate(floors):
        cams = camera_z[label == i]
        top = floors[i + 1][0] - 0.05 if i + 1 < len(floors) else np.inf
        ceiling = ceiling_above(surface, float(np.median(cams)) if cams.size else z + 0.5, top)
        records.append(Floor(id=i, name=f"floor {i}", floor_z_m=float(z), ceiling_z_m=ceiling,
                             source=source, frames=int(cams.size)))
    return FoundFloors(records, [n for _, _, n in floors], warnings, label, figures)


def _per_level(surface, camera_z, levels, label) -> tuple[list[tuple[float, str, int]], list[str]]:
    """Each camera level's floor: :func:`estimate_floor` on the points above the level below; a level with no
    floor surface takes the camera height the other levels stand at."""
    found: list[tuple[float, str, int] | None] = []
    for k, level in enumerate(levels):
        try:
            z, n = estimate_floor(surface, camera_z[label == k], above=levels[k - 1] if k else -np.inf)
            found.append((z, "surface", n))
        except StageError:
            found.append(None)
    heights = [levels[k] - f[0] for k, f in enumerate(found) if f is not None]
    if not heights:
        raise StageError(
            f"no floor found under any of the {len(levels)} camera levels at "
            f"{', '.join(f'{c:.2f}' for c in levels)} m: too few upward-facing surface points below the cameras "
            f"(expected at least {_FLOOR_MIN_POINTS} each in a z-up world); pin them with reconstruct.floors")
    camera_height = float(np.median(heights))
    warnings = []
    for k, f in enumerate(found):
        if f is None:
            z = float(levels[k] - camera_height)
            found[k] = (z, "cameras", 0)
            warnings.append(
                f"floor at {z:.2f} m: no floor surface under the cameras at {levels[k]:.2f} m; its height comes from "
                f"the camera height on the other floors ({camera_height:.2f} m): pin it with reconstruct.floors")
    return found, warnings


def _merge_close(floors, label) -> tuple[list, np.ndarray, list[str]]:
    """Floors closer than :data:`MIN_STOREY_M` (two camera levels over one surface) become the lower one."""
    kept, index, warnings = [], [], []
    for z, source, n in floors:
        if kept and z - kept[-1][0] < MIN_STOREY_M:
            warnings.append(f"cameras at two heights stand on one floor ({kept[-1][0]:.2f} m and {z:.2f} m found, "
                            f"less than {MIN_STOREY_M} m apart): read as one floor at {kept[-1][0]:.2f} m")
            index.append(len(kept) - 1)
            continue
        index.append(len(kept))
        kept.append((z, source, n))
    relabel = np.array(index + [-1], dtype=np.int64)  # label -1 (stairs) stays -1
    return kept, relabel[label], warnings


def _unwalked_surfaces(peaks: list[tuple[float, float]], floor_z: list[float]) -> list[str]:
    """A floor-like upward surface no floor explains (not within a storey above one): seen, never walked."""
    out = []
    for z, area in peaks:
        below = [f for f in floor_z if f - 0.1 <= z]
        if area >= _FLOOR_LIKE_M2 and (not below or z - max(below) >= MIN_STOREY_M):
            out.append(f"an upward-facing surface of {area:.1f} m^2 at {z:.2f} m looks like a floor no camera stood on "
                       "(a floor seen from the stairs?); it is not mapped: pin it with reconstruct.floors")
    return out


def pinned_floors(surface: Surface, camera_z: np.ndarray, p: ReconstructParams) -> FoundFloors:
    """``reconstruct.floors`` as :class:`Floor` records, each checked against the surface: a pinned floor with
    fewer than 50 upward-facing points within ``floor_tolerance_m`` is a :class:`ConfigError` naming its key."""
    floors = [pin.floor_z_m for pin in p.floors]
    points = [0] * len(floors)
    for z_up in _z_of(surface, lambda xyz, normals: normals[:, 2] > _UP_COS)():
        z_up = z_up.astype(np.float64)
        for i, z in enumerate(floors):
            points[i] += int((np.abs(z_up - z) <= p.floor_tolerance_m).sum())
    records = []
    for i, (pin, n) in enumerate(zip(p.floors, points)):
        if n < _FLOOR_MIN_POINTS:
            peaks = surface_peaks(surface)
            big = sorted(peaks, key=lambda pa: -pa[1])[:3]
            seen = ", ".join(f"{z:.2f} m ({a:.1f} m^2)" for z, a in sorted(big)) or "none"
            raise ConfigError(f"reconstruct.floors[{i}].floor_z_m: no floor at {pin.floor_z_m:.2f} m: {n} "
                              f"upward-facing surface points within {p.floor_tolerance_m} m (expected at least "
                              f"{_FLOOR_MIN_POINTS}); the largest upward surfaces lie at {seen}")
    label = floor_of_cameras(floors, camera_z)
    for i, pin in enumerate(p.floors):
        records.append(Floor(id=i, name=pin.name or f"floor {i}", floor_z_m=float(pin.floor_z_m),
                             ceiling_z_m=pin.ceiling_z_m, source="pinned", frames=int((label == i).sum())))
    return FoundFloors(records, points, [], label, {"pinned": len(records)})


def floor_of_cameras(floor_z: list[float], camera_z: np.ndarray) -> np.ndarray:
    """Each camera's floor: the highest floor below it (a camera below every floor: -1)."""
    return np.searchsorted(np.asarray(floor_z), np.asarray(camera_z), side="right").astype(np.int64) - 1
