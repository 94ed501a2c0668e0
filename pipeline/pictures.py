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
    return write_png(out_png, np.concatenate(rows, axis=0))
