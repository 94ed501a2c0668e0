"""North-up PNGs of a ``recon.zarr`` grid (``zipon render <scene> --what ...``), with a scale bar, and a colour
bar (height) or a legend (obstacles, navigable) saying what the colours mean.

The picture is painted tile by tile (the store's 128-cell chunks, :meth:`~pipeline.recon.store.FloorGrids.tile_windows`):
of a ``region`` (world metres, :mod:`pipeline.region`) only the tiles it meets are read, and memory is the picture
plus one tile, whatever the floor's area. Without a region the picture covers the observed cells (plus a margin),
found by one pass over the occupancy tiles."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from pipeline.errors import ConfigError
from pipeline.recon.store import FREE, OCCUPIED, FloorGrids, Recon, TopDown
from pipeline.region import Region, Window, region_window

What = Literal["obstacles", "navigable", "color", "height"]
WHATS: tuple[str, ...] = ("obstacles", "navigable", "color", "height")


def grid_image(recon: TopDown, what: str, robot_radius_m: float | None = None, *, top_m: float | None = None
               ) -> tuple[np.ndarray, str]:
    """An ``(rows, cols, 3)`` float image in [0, 1] and its title, of a store's floor 0, one floor's grids or a window
    of them. ``top_m``: the height drawn brightest (default: the highest in the grids drawn)."""
    if what in ("obstacles", "navigable"):
        occ = recon.occupancy
    if what == "obstacles":
        img = np.full(occ.shape + (3,), 0.55)  # unknown: grey
        img[occ == FREE] = 1.0
        img[occ == OCCUPIED] = 0.0
        return img, "occupancy (white free, black occupied, grey unknown)"
    if what == "navigable":
        img = np.full(occ.shape + (3,), 0.55)
        img[occ == FREE] = (0.85, 0.85, 0.85)
        img[recon.navigable] = (0.2, 0.7, 0.3)
        img[occ == OCCUPIED] = 0.0
        radius = recon.robot_radius_m if robot_radius_m is None else robot_radius_m
        return img, f"navigable (green) for robot radius {radius} m"
    if what == "color":
        return recon.color.astype(np.float64) / 255.0, "top-surface colour"
    if what == "height":
        import matplotlib

        h = recon.height
        top = _top(h) if top_m is None else top_m
        img = matplotlib.colormaps["viridis"](np.clip(np.nan_to_num(h, nan=0.0) / top, 0, 1))[..., :3]
        img[~np.isfinite(h)] = 1.0
        return img, "height of the top surface above the floor"
    raise ConfigError(f"render --what {what!r}: expected one of {', '.join(WHATS)}")


LEGENDS = {
    "obstacles": [((1.0, 1.0, 1.0), "free"), ((0.0, 0.0, 0.0), "occupied"), ((0.55, 0.55, 0.55), "unknown")],
    "navigable": [((0.2, 0.7, 0.3), "navigable"), ((0.85, 0.85, 0.85), "free, too close to obstacles"),
                  ((0.0, 0.0, 0.0), "occupied"), ((0.55, 0.55, 0.55), "unknown")],
}


def _top(height: np.ndarray) -> float:
    """The height drawn brightest: the highest known, at least 0.1 m (1 m when nothing is known)."""
    return max(float(np.nanmax(height)) if np.isfinite(height).any() else 1.0, 0.1)


def _key(fig, ax, top_m: float, what: str) -> None:
    """The colour bar of the height map (metres above the floor, up to ``top_m``) or the legend of a categorical
    grid."""
    if what == "height":
        import matplotlib
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import Normalize

        top = top_m
        bar = fig.colorbar(ScalarMappable(Normalize(0.0, top), matplotlib.colormaps["viridis"]), ax=ax,
                           fraction=0.035, pad=0.02)
        bar.set_label("m above the floor (white: unknown)")
    elif what in LEGENDS:
        from matplotlib.patches import Patch

        handles = [Patch(facecolor=c, edgecolor="0.3", label=t) for c, t in LEGENDS[what]]
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)


def _stair_ends(ax, recon: Recon, floor: int) -> None:
    """Triangles at the ends of the stairs on ``floor``: pointing up at a foot, down at a head."""
    for link in recon.stairs:
        for end, marker, word in ((link.bottom, "^", "up"), (link.top, "v", "down")):
            if end.floor == floor:
                ax.plot(*end.xy, marker=marker, color="orange", markersize=11, markeredgecolor="black")
                ax.annotate(f"{link.kind} {word}", end.xy, xytext=(6, 6), textcoords="offset points", fontsize=8,
                            color="orange")


def _nice_length(span_m: float) -> float:
    """A round scale-bar length near a fifth of the span (0.1, 0.2, 0.5, 1, 2, 5 ... m)."""
    target = span_m / 5.0
    base = 10 ** np.floor(np.log10(target))
    return float(max(m * base for m in (1, 2, 5) if m * base <= target) if target >= base else base)


def observed_window(view: FloorGrids, margin: int = 10) -> Window | None:
    """The cells of ``view`` with a known occupancy, plus ``margin`` cells each side (clipped to the grid), found
    tile by tile; None when nothing is known."""
    box = None
    for tile in view.tile_windows():
        rows, cols = np.nonzero(tile.occupancy)
        if len(rows):
            w = tile.cells
            r0, r1, c0, c1 = w.r0 + rows.min(), w.r0 + rows.max() + 1, w.c0 + cols.min(), w.c0 + cols.max() + 1
            box = (r0, r1, c0, c1) if box is None else (min(box[0], r0), max(box[1], r1), min(box[2], c0),
                                                        max(box[3], c1))
    if box is None:
        return None
    g = view.grid
    return Window(max(int(box[0]) - margin, 0), min(int(box[1]) + margin, g.rows), max(int(box[2]) - margin, 0),
                  min(int(box[3]) + margin, g.cols))


def paint(view: FloorGrids, window: Window, what: str, robot_radius_m: float) -> tuple[np.ndarray, str, float]:
    """The ``(rows, cols, 3)`` uint8 picture of ``window`` of ``view``, painted one stored tile at a time (a height
    picture reads the height tiles twice: first for its top), its title and the height drawn brightest."""
    top = 1.0
    if what == "height":
        tops = [float(np.nanmax(h)) for h in (t.height for t in view.tile_windows(window)) if np.isfinite(h).any()]
        top = max(max(tops), 0.1) if tops else 1.0
    img = np.zeros((*window.shape, 3), np.uint8)
    title = ""
    for tile in view.tile_windows(window):
        rgb, title = grid_image(tile, what, robot_radius_m, top_m=top)
        img[tile.cells.within(window).slices] = np.round(np.asarray(rgb) * 255.0).clip(0, 255).astype(np.uint8)
    return img, title, top


def render_recon(recon_path: str | Path, what: str, out_png: str | Path, *, crop: bool = True, floor: int = 0,
                 region: Region | None = None) -> Path:
    """Draw one grid of ``recon_path`` (of floor ``floor``) north-up (x east to the right, y north up) with a scale
    bar and metre axes; on a building, the stairs' ends on that floor are marked.

    ``region`` (world metres) draws only its cells, reading only the tiles it meets (an InputDataError naming
    ``--region`` when it misses the grid); without it, ``crop`` trims the view to the observed cells plus a margin.
    Returns the PNG path.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    recon = Recon(recon_path)
    n = len(recon.floors)
    if not 0 <= floor < n:
        raise ConfigError(f"--floor {floor}: {Path(recon_path).parent.name} has {n} floor{'s' if n != 1 else ''} "
                          f"(0..{n - 1})")
    view = recon.floor(floor)
    if region is not None:
        window = region_window(view.grid, region)
    else:
        window = (observed_window(view) if crop else None) or Window(0, view.grid.rows, 0, view.grid.cols)
    img, title, top = paint(view, window, what, recon.robot_radius_m)
    if n > 1:
        title = f"{view.floor.name} ({view.floor_z:.2f} m): {title}"
    x0, x1, y0, y1 = window.grid(view.grid).extent_xy
    fig, ax = plt.subplots(figsize=(7, 7), dpi=120)
    ax.imshow(img, extent=(x0, x1, y0, y1), origin="upper", interpolation="nearest")
    _stair_ends(ax, recon, floor)
    ax.set_xlim(x0, x1)  # the stairs' marks never widen the view
    ax.set_ylim(y0, y1)
    xa, xb, ya, yb = x0, x1, y0, y1
    bar = _nice_length(xb - xa)
    bx, by = xa + 0.05 * (xb - xa), ya + 0.05 * (yb - ya)
    ax.plot([bx, bx + bar], [by, by], color="red", linewidth=4, solid_capstyle="butt")
    ax.text(bx + bar / 2, by + 0.02 * (yb - ya), f"{bar:g} m", color="red", ha="center", va="bottom", fontsize=10)
    ax.annotate("N", xy=(xb - 0.05 * (xb - xa), yb - 0.04 * (yb - ya)),
                xytext=(xb - 0.05 * (xb - xa), yb - 0.14 * (yb - ya)), color="red", ha="center",
                arrowprops={"arrowstyle": "->", "color": "red"})
    _key(fig, ax, top, what)
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    where = "" if region is None else f" in {region}"
    ax.set_title(f"{Path(recon_path).parent.name}: {title}{where}", fontsize=10)
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, bbox_inches="tight")
    plt.close(fig)
    return out_png
