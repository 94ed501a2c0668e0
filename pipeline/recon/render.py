"""North-up PNGs of a ``recon.zarr`` grid (``zipon render <scene> --what ...``), with a scale bar, and a colour
bar (height) or a legend (obstacles, navigable) saying what the colours mean."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from pipeline.errors import ConfigError
from pipeline.recon.store import FREE, OCCUPIED, FloorGrids, Recon

What = Literal["obstacles", "navigable", "color", "height"]
WHATS: tuple[str, ...] = ("obstacles", "navigable", "color", "height")


def grid_image(recon: Recon | FloorGrids, what: str, robot_radius_m: float | None = None) -> tuple[np.ndarray, str]:
    """An ``(rows, cols, 3)`` float image in [0, 1] and its title, of a store's floor 0 or of one floor's grids."""
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
        top = max(float(np.nanmax(h)) if np.isfinite(h).any() else 1.0, 0.1)
        img = matplotlib.colormaps["viridis"](np.clip(np.nan_to_num(h, nan=0.0) / top, 0, 1))[..., :3]
        img[~np.isfinite(h)] = 1.0
        return img, "height of the top surface above the floor"
    raise ConfigError(f"render --what {what!r}: expected one of {', '.join(WHATS)}")


LEGENDS = {
    "obstacles": [((1.0, 1.0, 1.0), "free"), ((0.0, 0.0, 0.0), "occupied"), ((0.55, 0.55, 0.55), "unknown")],
    "navigable": [((0.2, 0.7, 0.3), "navigable"), ((0.85, 0.85, 0.85), "free, too close to obstacles"),
                  ((0.0, 0.0, 0.0), "occupied"), ((0.55, 0.55, 0.55), "unknown")],
}


def _key(fig, ax, recon: Recon | FloorGrids, what: str) -> None:
    """The colour bar of the height map (metres above the floor) or the legend of a categorical grid."""
    if what == "height":
        import matplotlib
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import Normalize

        h = recon.height
        top = max(float(np.nanmax(h)) if np.isfinite(h).any() else 1.0, 0.1)
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


def render_recon(recon_path: str | Path, what: str, out_png: str | Path, *, crop: bool = True, floor: int = 0) -> Path:
    """Draw one grid of ``recon_path`` (of floor ``floor``) north-up (x east to the right, y north up) with a scale
    bar; on a building, the stairs' ends on that floor are marked.

    ``crop`` trims the view to the observed cells plus a margin. Returns the PNG path.
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
    img, title = grid_image(view, what, recon.robot_radius_m)
    if n > 1:
        title = f"{view.floor.name} ({view.floor_z:.2f} m): {title}"
    g = view.grid
    x0, x1, y0, y1 = g.extent_xy
    fig, ax = plt.subplots(figsize=(7, 7), dpi=120)
    ax.imshow(img, extent=(x0, x1, y0, y1), origin="upper", interpolation="nearest")
    seen = np.argwhere(view.occupancy != 0)
    if crop and len(seen):
        (r0, c0), (r1, c1) = seen.min(axis=0) - 10, seen.max(axis=0) + 10
        (xa, yb), (xb, ya) = g.cell_to_world(np.array([[r1, c0], [r0, c1]]))
        ax.set_xlim(xa, xb)
        ax.set_ylim(yb, ya)
    xa, xb = ax.get_xlim()
    ya, yb = ax.get_ylim()
    bar = _nice_length(xb - xa)
    bx, by = xa + 0.05 * (xb - xa), ya + 0.05 * (yb - ya)
    ax.plot([bx, bx + bar], [by, by], color="red", linewidth=4, solid_capstyle="butt")
    ax.text(bx + bar / 2, by + 0.02 * (yb - ya), f"{bar:g} m", color="red", ha="center", va="bottom", fontsize=10)
    ax.annotate("N", xy=(xb - 0.05 * (xb - xa), yb - 0.04 * (yb - ya)),
                xytext=(xb - 0.05 * (xb - xa), yb - 0.14 * (yb - ya)), color="red", ha="center",
                arrowprops={"arrowstyle": "->", "color": "red"})
    _stair_ends(ax, recon, floor)
    _key(fig, ax, view, what)
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_title(f"{Path(recon_path).parent.name}: {title}", fontsize=10)
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, bbox_inches="tight")
    plt.close(fig)
    return out_png
