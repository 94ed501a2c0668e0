"""Object templates, colours and materials of the procedural scenes.

A template builds an object's part boxes in a *local* frame: footprint centred on the origin,
``x`` across the object (width), ``y`` from its back (``-d/2``) to its front (``+d/2``), ``z`` up
from its base. :func:`place_parts` rotates them by a multiple of 90 degrees and moves them into
the world, so every part stays a world-axis-aligned box.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

# Named colours (name -> sRGB). Instances of one class in a scene never share a colour.
COLOURS: dict[str, tuple[int, int, int]] = {
    "white": (236, 236, 232),
    "black": (38, 38, 40),
    "grey": (128, 128, 130),
    "dark grey": (72, 72, 76),
    "beige": (216, 200, 168),
    "cream": (240, 228, 196),
    "brown": (120, 78, 46),
    "dark brown": (78, 50, 30),
    "light wood": (196, 160, 110),
    "red": (186, 40, 40),
    "maroon": (118, 30, 42),
    "orange": (226, 128, 40),
    "yellow": (226, 196, 60),
    "olive": (120, 120, 48),
    "green": (60, 140, 70),
    "dark green": (36, 86, 50),
    "teal": (40, 128, 128),
    "light blue": (140, 184, 220),
    "blue": (50, 90, 180),
    "navy blue": (34, 44, 96),
    "purple": (110, 60, 140),
    "pink": (228, 150, 170),
    "turquoise": (64, 200, 190),
    "mustard": (200, 160, 40),
}

# Per-class choices of material; the renderer's texture follows the material.
MATERIALS = ("wood", "fabric", "leather", "metal", "plastic", "ceramic", "glass", "paper")
MATERIAL_CODE = {name: i for i, name in enumerate(MATERIALS)}


@dataclass(frozen=True)
class Part:
    """A part box in the local frame (metres)."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]


@dataclass(frozen=True)
class Template:
    """How to build one object class."""

    cls: str
    size: str  # "big" | "small"
    materials: tuple[str, ...]
    colours: tuple[str, ...]
    build: Callable[[np.random.Generator], tuple[float, float, list[Part]]]  # -> (width, depth, parts)
    support: bool = False  # other (small) objects may stand on its top
    meta: dict = field(default_factory=dict)


def _box(x0, y0, z0, x1, y1, z1) -> Part:
    return Part((x0, y0, z0), (x1, y1, z1))


def _legs(w, d, h, t=0.05) -> list[Part]:
    hw, hd = w / 2, d / 2
    return [_box(sx * hw - (t if sx > 0 else 0), sy * hd - (t if sy > 0 else 0), 0.0,
                 sx * hw + (0 if sx > 0 else t), sy * hd + (0 if sy > 0 else t), h)
            for sx in (-1, 1) for sy in (-1, 1)]


def _u(rng, lo, hi, q=0.01) -> float:
    return float(np.round(rng.uniform(lo, hi) / q) * q)


def _bed(rng):
    w, d = _u(rng, 1.0, 1.8), _u(rng, 1.95, 2.1)
    hd = d / 2
    return w, d, [
        _box(-w / 2, -hd, 0.0, w / 2, hd, 0.30),
        _box(-w / 2 + 0.03, -hd + 0.08, 0.30, w / 2 - 0.03, hd - 0.02, 0.52),
        _box(-w / 2, -hd, 0.0, w / 2, -hd + 0.08, _u(rng, 0.9, 1.2)),
        _box(-w / 2 + 0.15, -hd + 0.12, 0.52, w / 2 - 0.15, -hd + 0.5, 0.62),  # pillow / duvet fold
    ]


def _nightstand(rng):
    w, d, h = _u(rng, 0.4, 0.55), _u(rng, 0.35, 0.45), _u(rng, 0.45, 0.6)
    return w, d, [_box(-w / 2, -d / 2, 0.0, w / 2, d / 2, h),
                  _box(-w / 2 + 0.04, d / 2 - 0.001, h * 0.55, w / 2 - 0.04, d / 2 + 0.01, h * 0.9)]


def _wardrobe(rng):
    w, d, h = _u(rng, 0.9, 1.6), _u(rng, 0.55, 0.62), _u(rng, 1.9, 2.2)
    return w, d, [_box(-w / 2, -d / 2, 0.0, w / 2, d / 2, h),
                  _box(-0.01, d / 2, 0.2, 0.01, d / 2 + 0.015, h - 0.2)]


def _chair(rng):
    w, d, seat = _u(rng, 0.42, 0.55), _u(rng, 0.42, 0.52), _u(rng, 0.42, 0.48)
    return w, d, _legs(w, d, seat - 0.04, 0.04) + [
        _box(-w / 2, -d / 2, seat - 0.04, w / 2, d / 2, seat),
        _box(-w / 2, -d / 2, seat, w / 2, -d / 2 + 0.05, seat + _u(rng, 0.4, 0.5)),
    ]


def _armchair(rng):
    w, d = _u(rng, 0.75, 0.95), _u(rng, 0.75, 0.9)
    return w, d, [
        _box(-w / 2, -d / 2, 0.0, w / 2, d / 2, 0.42),
        _box(-w / 2, -d / 2, 0.42, w / 2, -d / 2 + 0.18, 0.85),
        _box(-w / 2, -d / 2, 0.42, -w / 2 + 0.14, d / 2, 0.62),
        _box(w / 2 - 0.14, -d / 2, 0.42, w / 2, d / 2, 0.62),
    ]


def _table(rng, w_range=(1.2, 1.7), d_range=(0.8, 1.0), h_range=(0.72, 0.76)):
    w, d, h = _u(rng, *w_range), _u(rng, *d_range), _u(rng, *h_range)
    return w, d, _legs(w, d, h - 0.04, 0.06) + [_box(-w / 2, -d / 2, h - 0.04, w / 2, d / 2, h)]


def _coffee_table(rng):
    return _table(rng, (0.9, 1.2), (0.5, 0.65), (0.4, 0.46))


def _desk(rng):
    w, d, h = _u(rng, 1.1, 1.5), _u(rng, 0.6, 0.75), _u(rng, 0.72, 0.76)
    return w, d, [
        _box(-w / 2, -d / 2, h - 0.04, w / 2, d / 2, h),
        _box(-w / 2, -d / 2, 0.0, -w / 2 + 0.04, d / 2, h - 0.04),
        _box(w / 2 - 0.45, -d / 2, 0.0, w / 2, d / 2 - 0.05, h - 0.04),  # drawer block
    ]


def _couch(rng):
    w, d = _u(rng, 1.8, 2.4), _u(rng, 0.85, 0.95)
    return w, d, [
        _box(-w / 2, -d / 2, 0.0, w / 2, d / 2, 0.42),
        _box(-w / 2, -d / 2, 0.42, w / 2, -d / 2 + 0.22, 0.85),
        _box(-w / 2, -d / 2, 0.42, -w / 2 + 0.18, d / 2, 0.62),
        _box(w / 2 - 0.18, -d / 2, 0.42, w / 2, d / 2, 0.62),
    ]


def _cabinet(rng):
    w, d, h = _u(rng, 0.8, 1.4), _u(rng, 0.4, 0.5), _u(rng, 0.5, 0.9)
    return w, d, [_box(-w / 2, -d / 2, 0.0, w / 2, d / 2, h),
                  _box(-w / 2 + 0.03, d / 2, 0.08, -0.01, d / 2 + 0.01, h - 0.05),
                  _box(0.01, d / 2, 0.08, w / 2 - 0.03, d / 2 + 0.01, h - 0.05)]


def _counter(rng):
    w, d = _u(rng, 1.2, 2.0), 0.6
    return w, d, [_box(-w / 2, -d / 2, 0.0, w / 2, d / 2, 0.86),
                  _box(-w / 2, -d / 2, 0.86, w / 2, d / 2 + 0.02, 0.9)]


def _shelf(rng):
    w, d, h = _u(rng, 0.7, 1.2), _u(rng, 0.3, 0.4), _u(rng, 1.6, 2.0)
    n = 5
    boards = [_box(-w / 2, -d / 2, i * (h - 0.03) / (n - 1), w / 2, d / 2, i * (h - 0.03) / (n - 1) + 0.03)
              for i in range(n)]
    return w, d, boards + [_box(-w / 2, -d / 2, 0.0, -w / 2 + 0.03, d / 2, h),
                           _box(w / 2 - 0.03, -d / 2, 0.0, w / 2, d / 2, h),
                           _box(-w / 2, -d / 2, 0.0, w / 2, -d / 2 + 0.02, h)]


def _tv(rng):
    w, h = _u(rng, 0.8, 1.2), _u(rng, 0.5, 0.7)
    return w, 0.2, [_box(-0.15, -0.1, 0.0, 0.15, 0.1, 0.02),
                    _box(-0.03, -0.03, 0.02, 0.03, 0.03, 0.1),
                    _box(-w / 2, -0.03, 0.1, w / 2, 0.03, 0.1 + h),
                    _box(-w / 2 + 0.03, 0.03, 0.13, w / 2 - 0.03, 0.035, 0.07 + h)]


def _computer(rng):
    w, h = _u(rng, 0.45, 0.6), _u(rng, 0.3, 0.38)
    return w, 0.22, [_box(-0.12, -0.11, 0.0, 0.12, 0.07, 0.02),
                     _box(-0.03, -0.07, 0.02, 0.03, -0.03, 0.12),
                     _box(-w / 2, -0.07, 0.12, w / 2, -0.03, 0.12 + h),
                     _box(-w / 2 + 0.02, -0.03, 0.14, w / 2 - 0.02, -0.025, 0.10 + h),
                     _box(-0.22, 0.0, 0.0, 0.22, 0.11, 0.02)]  # keyboard


def _plant(rng):
    p, h, f = _u(rng, 0.22, 0.34), _u(rng, 0.5, 1.3), _u(rng, 0.35, 0.6)
    return f, f, [_box(-p / 2, -p / 2, 0.0, p / 2, p / 2, 0.3),
                  _box(-f / 2, -f / 2, 0.3, f / 2, f / 2, 0.3 + h)]


def _small_plant(rng):
    p, f = _u(rng, 0.12, 0.16), _u(rng, 0.2, 0.28)
    return f, f, [_box(-p / 2, -p / 2, 0.0, p / 2, p / 2, 0.14),
                  _box(-f / 2, -f / 2, 0.14, f / 2, f / 2, 0.14 + _u(rng, 0.15, 0.3))]


def _floor_lamp(rng):
    h = _u(rng, 1.4, 1.7)
    return 0.4, 0.4, [_box(-0.15, -0.15, 0.0, 0.15, 0.15, 0.03),
                      _box(-0.02, -0.02, 0.03, 0.02, 0.02, h - 0.3),
                      _box(-0.2, -0.2, h - 0.3, 0.2, 0.2, h)]


def _table_lamp(rng):
    return 0.26, 0.26, [_box(-0.08, -0.08, 0.0, 0.08, 0.08, 0.04),
                        _box(-0.015, -0.015, 0.04, 0.015, 0.015, 0.3),
                        _box(-0.13, -0.13, 0.28, 0.13, 0.13, 0.48)]


def _toilet(rng):
    return 0.42, 0.7, [_box(-0.19, -0.35, 0.0, 0.19, 0.3, 0.42),
                       _box(-0.21, -0.35, 0.42, 0.21, -0.15, 0.8),
                       _box(-0.19, -0.12, 0.42, 0.19, 0.33, 0.45)]


def _sink(rng):
    w = _u(rng, 0.6, 0.9)
    return w, 0.5, [_box(-w / 2, -0.25, 0.0, w / 2, 0.25, 0.8),
                    _box(-w / 2 + 0.08, -0.17, 0.8, w / 2 - 0.08, 0.2, 0.86),
                    _box(-0.02, -0.24, 0.86, 0.02, -0.12, 1.05)]  # faucet


def _fridge(rng):
    w, h = _u(rng, 0.6, 0.8), _u(rng, 1.7, 1.95)
    return w, 0.68, [_box(-w / 2, -0.34, 0.0, w / 2, 0.34, h),
                     _box(w / 2 - 0.08, 0.34, h * 0.45, w / 2 - 0.05, 0.38, h * 0.85)]


def _stove(rng):
    return 0.6, 0.6, [_box(-0.3, -0.3, 0.0, 0.3, 0.3, 0.88),
                      _box(-0.28, -0.28, 0.88, 0.28, 0.28, 0.9),
                      _box(-0.3, -0.3, 0.9, 0.3, -0.24, 1.05)]


def _bathtub(rng):
    w = _u(rng, 1.5, 1.7)
    return w, 0.75, [_box(-w / 2, -0.375, 0.0, w / 2, 0.375, 0.5)]


def _microwave(rng):
    return 0.48, 0.36, [_box(-0.24, -0.18, 0.0, 0.24, 0.18, 0.28),
                        _box(-0.2, 0.18, 0.04, 0.08, 0.185, 0.24)]


def _picture(rng):
    w, h = _u(rng, 0.5, 1.0), _u(rng, 0.4, 0.7)
    return w, 0.03, [_box(-w / 2, -0.015, 0.0, w / 2, 0.015, h)]


_WOODY = ("brown", "dark brown", "light wood", "white", "black", "grey", "beige")
_BRIGHT = tuple(COLOURS)

TEMPLATES: dict[str, Template] = {
    t.meta.get("key", t.cls): t
    for t in (
        Template("bed", "big", ("wood", "fabric", "metal"), _BRIGHT, _bed),
        Template("nightstand", "big", ("wood", "plastic"), _WOODY, _nightstand, support=True),
        Template("wardrobe", "big", ("wood",), _WOODY, _wardrobe),
        Template("chair", "big", ("wood", "plastic", "metal"), _BRIGHT, _chair),
        Template("chair", "big", ("fabric", "leather"), _BRIGHT, _armchair, meta={"key": "armchair"}),
        Template("table", "big", ("wood", "glass", "metal"), _WOODY, _table, support=True),
        Template("table", "big", ("wood", "glass"), _WOODY, _coffee_table, support=True,
                 meta={"key": "coffee table"}),
        Template("desk", "big", ("wood", "metal"), _WOODY, _desk, support=True),
        Template("couch", "big", ("fabric", "leather"), _BRIGHT, _couch),
        Template("cabinet", "big", ("wood", "metal", "plastic"), _WOODY, _cabinet, support=True),
        Template("cabinet", "big", ("wood", "plastic"), _WOODY, _counter, support=True,
                 meta={"key": "counter"}),
        Template("shelf", "big", ("wood", "metal"), _WOODY, _shelf),
        Template("tv", "small", ("plastic",), ("black", "dark grey", "grey", "white"), _tv),
        Template("computer", "small", ("plastic", "metal"), ("black", "dark grey", "grey", "white"), _computer),
        Template("plant", "big", ("ceramic", "plastic"), _BRIGHT, _plant),
        Template("plant", "small", ("ceramic", "plastic"), _BRIGHT, _small_plant, meta={"key": "small plant"}),
        Template("lamp", "big", ("metal", "fabric"), _BRIGHT, _floor_lamp),
        Template("lamp", "small", ("metal", "ceramic", "fabric"), _BRIGHT, _table_lamp,
                 meta={"key": "table lamp"}),
        Template("toilet", "big", ("ceramic",), ("white", "cream", "beige", "black", "light blue"), _toilet),
        Template("sink", "big", ("ceramic", "metal"), ("white", "cream", "grey", "beige", "dark grey"), _sink),
        Template("fridge", "big", ("metal",), ("white", "grey", "black", "red", "cream"), _fridge),
        Template("stove", "big", ("metal",), ("white", "black", "grey", "dark grey"), _stove),
        Template("bathtub", "big", ("ceramic",), ("white", "cream", "light blue", "beige"), _bathtub),
        Template("microwave", "small", ("metal", "plastic"), ("white", "black", "grey", "red"), _microwave),
        Template("picture", "small", ("paper", "wood"), _BRIGHT, _picture),
    )
}


def rotate_box(bmin, bmax, quarter_turns: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotate a local box about z by ``quarter_turns * 90`` degrees (CCW); still axis-aligned."""
    c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][quarter_turns % 4]
    xs = np.array([bmin[0], bmax[0]])
    ys = np.array([bmin[1], bmax[1]])
    X, Y = np.meshgrid(xs, ys)
    rx, ry = c * X - s * Y, s * X + c * Y
    return (np.array([rx.min(), ry.min(), bmin[2]]), np.array([rx.max(), ry.max(), bmax[2]]))


def place_parts(parts: list[Part], xy: tuple[float, float], z0: float, quarter_turns: int):
    """World boxes ``[(min (3,), max (3,))]`` of local parts rotated by quarter turns, moved to ``xy``, base at ``z0``."""
    out = []
    off = np.array([xy[0], xy[1], z0])
    for p in parts:
        lo, hi = rotate_box(p.min, p.max, quarter_turns)
        out.append((np.round(lo + off, 4), np.round(hi + off, 4)))
    return out


def front_quarter_turns(inward_normal: tuple[int, int]) -> int:
    """Quarter turns that make a template's front (local +y) face ``inward_normal`` (a unit axis)."""
    return {(0, 1): 0, (-1, 0): 1, (0, -1): 2, (1, 0): 3}[tuple(int(v) for v in inward_normal)]
