"""PNG pictures shared by the stages and the CLI: colour maps, scale bars, frame contact sheets."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def write_png(path: Path, rgb: np.ndarray) -> Path:
    """Write an ``(H,W,3)`` uint8 RGB image as PNG (parents created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, png = cv2.imencode(".png", cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR))
    if not ok:
        raise ValueError(f"{path}: image of shape {np.shape(rgb)} cannot be encoded as PNG")
    path.write_bytes(png.tobytes())  # a full or read-only disk raises OSError naming the path (imwrite is silent)
    return path


def colorize(values: np.ndarray, vmin: float | None = None, vmax: float | None = None,
             invalid: np.ndarray | None = None, colormap: int = cv2.COLORMAP_TURBO) -> np.ndarray:
    """Scalar image ``(H,W)`` -> ``(H,W,3)`` uint8 RGB with an opencv colormap; invalid pixels black."""
    v = np.asarray(values, dtype=np.float32)
    bad = ~np.isfinite(v) if invalid is None else (invalid | ~np.isfinite(v))
    good = v[~bad]
    lo = float(vmin if vmin is not None else (good.min() if good.size else 0.0))
    hi = float(vmax if vmax is not None else (good.max() if good.size else 1.0))
    scaled = np.clip((np.nan_to_num(v) - lo) / max(hi - lo, 1e-9), 0, 1)
    rgb = cv2.cvtColor(cv2.applyColorMap((scaled * 255).astype(np.uint8), colormap), cv2.COLOR_BGR2RGB)
    rgb[bad] = 0
    return rgb


def label_colors(ids: np.ndarray) -> np.ndarray:
    """Stable distinct colours for integer ids ``(H,W)`` -> ``(H,W,3)`` uint8; id 0 black."""
    ids = np.asarray(ids).astype(np.uint64)
    h = (ids * np.uint64(2654435761)) & np.uint64(0xFFFFFF)
    rgb = np.stack([(h >> np.uint64(s)) & np.uint64(255) for s in (16, 8, 0)], axis=-1).astype(np.uint8)
    rgb = (rgb // 2 + 96).astype(np.uint8)
    rgb[ids == 0] = 0
    return rgb


def add_scale_bar(img: np.ndarray, cell_size_m: float, *, meters: float | None = None) -> np.ndarray:
    """Draw a labelled scale bar (bottom-left) and a north arrow (top-right) on a north-up grid image."""
    img = np.ascontiguousarray(img.copy())
    h, w = img.shape[:2]
    if meters is None:
        span = w * cell_size_m
        meters = next(m for m in (0.5, 1, 2, 5, 10, 20, 50, 100) if m >= span / 6)
    px = int(round(meters / cell_size_m))
    x0, y0 = 10, h - 12
    cv2.rectangle(img, (x0 - 4, y0 - 22), (x0 + px + 60, y0 + 6), (255, 255, 255), -1)
    cv2.line(img, (x0, y0), (x0 + px, y0), (0, 0, 0), 3)
    for x in (x0, x0 + px):
        cv2.line(img, (x, y0 - 6), (x, y0 + 4), (0, 0, 0), 2)
    cv2.putText(img, f"{meters:g} m", (x0 + px + 6, y0 + 2), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    ax, ay = w - 20, 12
    cv2.arrowedLine(img, (ax, ay + 26), (ax, ay), (0, 0, 0), 2, tipLength=0.35)
    cv2.putText(img, "N", (ax - 5, ay + 42), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return img


AXIS_LEFT, AXIS_BOTTOM = 46, 34  # pixels of the margins that hold the metre ticks (add_metre_axes)


def add_metre_axes(img: np.ndarray, left_x_m: float, top_y_m: float, px_per_m: float) -> np.ndarray:
    """``img``, a north-up picture whose top-left corner is world (``left_x_m``, ``top_y_m``) at ``px_per_m`` pixels
    per metre, with margins holding world x (bottom) and y (left) ticks in metres at a round step at least 60 pixels
    apart."""
    h, w = img.shape[:2]
    out = np.full((h + AXIS_BOTTOM, w + AXIS_LEFT, 3), 255, np.uint8)
    out[:h, AXIS_LEFT:] = img
    step = next((m for m in (0.5, 1, 2, 5, 10, 20, 50) if m * px_per_m >= 60), 100)
    xa, xb = left_x_m, left_x_m + w / px_per_m
    ya, yb = top_y_m - h / px_per_m, top_y_m
    ink, font = (40, 40, 40), cv2.FONT_HERSHEY_SIMPLEX
    cv2.line(out, (AXIS_LEFT - 1, 0), (AXIS_LEFT - 1, h), ink, 1)  # the axes in the margins, beside the picture
    cv2.line(out, (AXIS_LEFT - 1, h), (AXIS_LEFT + w, h), ink, 1)
    for x in np.arange(np.ceil(xa / step) * step, xb, step):
        u = AXIS_LEFT + int(round((x - xa) * px_per_m))
        cv2.line(out, (u, h), (u, h + 5), ink, 1)
        text = f"{x + 0.0:g}"  # + 0.0: no "-0"
        cv2.putText(out, text, (u - 4 * len(text), h + 18), font, 0.4, ink, 1, cv2.LINE_AA)
    for y in np.arange(np.ceil(ya / step) * step, yb, step):
        v = int(round((yb - y) * px_per_m))
        cv2.line(out, (AXIS_LEFT - 6, v), (AXIS_LEFT - 1, v), ink, 1)
        cv2.putText(out, f"{y + 0.0:g}", (4, v + 4), font, 0.4, ink, 1, cv2.LINE_AA)
    cv2.putText(out, "x (m, east)", (AXIS_LEFT + w - 90, h + 31), font, 0.4, ink, 1, cv2.LINE_AA)
    cv2.putText(out, "y (m)", (2, h + 31), font, 0.4, ink, 1, cv2.LINE_AA)
    return out


def frames_contact_sheet(frames_path: Path, out_png: Path, *, count: int = 6, width: int = 320) -> Path:
    """A picture of a frame store: ``count`` evenly spaced frames, colour / depth / instance side by side."""
    from pipeline.frames import FrameStore

    fs = FrameStore(frames_path)
    idx = np.unique(np.linspace(0, fs.n_frames - 1, min(count, fs.n_frames)).round().astype(int))
    rows = []
    for i in idx:
        b = fs.read(int(i), int(i) + 1, instance=True)
        depth = b.depth_m()[0]
        tiles = [b.rgb[0], colorize(depth, 0.0, 10.0, invalid=depth <= 0)]
        if b.instance is not None:
            tiles.append(label_colors(b.instance[0]))
        scale = width / tiles[0].shape[1]
        tiles = [cv2.resize(t, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST) for t in tiles]
        row = np.concatenate(tiles, axis=1)
        cv2.putText(row, f"frame {i}", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        rows.append(row)
    sheet = add_colorbar(np.concatenate(rows, axis=0), 0.0, 10.0, "depth (m; black = invalid)")
    legend = [(None, "columns: colour | depth")] + ([(None, "| instance ids (one colour each)")] if fs.has_instance else [])
    return write_png(out_png, add_legend(sheet, legend))


def _text_width(text: str, scale: float = 0.45) -> int:
    return cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]


def add_colorbar(img: np.ndarray, lo: float, hi: float, label: str, *, colormap: int = cv2.COLORMAP_TURBO,
                 ticks: int = 5) -> np.ndarray:
    """``img`` with a labelled horizontal colour bar band below it (the scale of a :func:`colorize` layer)."""
    w = img.shape[1]
    band = np.full((46, w, 3), 255, np.uint8)
    x0, x1 = 10 + _text_width(label) + 10, max(w - 30, 10 + _text_width(label) + 60)
    cv2.putText(band, label, (10, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    ramp = colorize(np.tile(np.linspace(0.0, 1.0, max(x1 - x0, 2), dtype=np.float32), (14, 1)), 0.0, 1.0,
                    colormap=colormap)
    band[8:22, x0:x0 + ramp.shape[1]] = ramp[:, : max(0, min(ramp.shape[1], w - x0))]
    cv2.rectangle(band, (x0, 8), (x0 + ramp.shape[1] - 1, 21), (0, 0, 0), 1)
    for k in range(ticks):
        f = k / (ticks - 1)
        x = int(x0 + f * (ramp.shape[1] - 1))
        cv2.line(band, (x, 22), (x, 26), (0, 0, 0), 1)
        t = f"{lo + f * (hi - lo):.2g}"
        cv2.putText(band, t, (int(np.clip(x - _text_width(t, 0.4) // 2, 0, w - _text_width(t, 0.4))), 40),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([img, band], axis=0)


def add_legend(img: np.ndarray, entries: list[tuple[tuple[int, int, int] | None, str]], *,
               title: str | None = None) -> np.ndarray:
    """``img`` with a legend band below it: each entry a colour swatch (or none) and its text, wrapped to the width."""
    w = img.shape[1]
    rows, line, x = [], [], 10
    for colour, text in entries:
        need = (18 if colour is not None else 0) + _text_width(text) + 18
        if line and x + need > w:
            rows.append(line)
            line, x = [], 10
        line.append((colour, text))
        x += need
    if line:
        rows.append(line)
    top = 22 if title else 4
    band = np.full((top + 20 * len(rows) + 6, w, 3), 255, np.uint8)
    if title:
        cv2.putText(band, title, (10, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for r, line in enumerate(rows):
        x, y = 10, top + 20 * r + 14
        for colour, text in line:
            if colour is not None:
                cv2.rectangle(band, (x, y - 10), (x + 12, y + 2), tuple(int(c) for c in colour), -1)
                cv2.rectangle(band, (x, y - 10), (x + 12, y + 2), (60, 60, 60), 1)
                x += 18
            cv2.putText(band, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
            x += _text_width(text) + 18
    return np.concatenate([img, band], axis=0)
