"""Region generators for ConceptFusion: a frame -> a set of (possibly overlapping) region masks.

Family: :class:`RegionGenerator` (ABC) + :data:`REGION_GENERATORS` registry, chosen by
``encoders.conceptfusion.regions.generator``:

- ``rgbd`` (default): felzenszwalb graph segmentation (scikit-image) of CIELAB colour plus
  weighted metric depth, so both colour edges and depth discontinuities cut regions;
- ``gt``: ground-truth instance masks (simulated data; needs the ``instance`` images);
- ``sam``: segment-anything automatic masks (needs the ``segment_anything`` package and a local
  checkpoint; a clear error when chosen without them).

All return :class:`Regions`: ``masks`` ``(R,h,w)`` bool on a grid covering the whole image
(pixel-corner convention, like the encoders' feature grids); pixels may be in no region.
"""

from __future__ import annotations

import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import cv2
import numpy as np

from pipeline.encoder_params.conceptfusion import RegionParams
from pipeline.errors import ConfigError, InputDataError, MissingInputError


@dataclass
class Regions:
    """Regions of one frame: ``masks`` ``(R,h,w)`` bool covering the whole ``image_size`` (H, W)."""

    masks: np.ndarray
    image_size: tuple[int, int]

    def __len__(self) -> int:
        return int(self.masks.shape[0])

    def boxes_px(self) -> np.ndarray:
        """``(R,4)`` float32 ``x0, y0, x1, y1`` bounding boxes in image pixels (corner convention)."""
        R, h, w = self.masks.shape
        if R == 0:
            return np.zeros((0, 4), np.float32)
        cols, rows = self.masks.any(axis=1), self.masks.any(axis=2)
        c0, c1 = cols.argmax(axis=1), w - cols[:, ::-1].argmax(axis=1)
        r0, r1 = rows.argmax(axis=1), h - rows[:, ::-1].argmax(axis=1)
        H, W = self.image_size
        return np.stack([c0 * W / w, r0 * H / h, c1 * W / w, r1 * H / h], axis=1).astype(np.float32)

    def resampled(self, size: tuple[int, int]) -> np.ndarray:
        """``(R,*size)`` bool masks: nearest grid cell at each target cell centre."""
        _, h, w = self.masks.shape
        rows = np.minimum(((np.arange(size[0]) + 0.5) * h / size[0]).astype(np.int64), h - 1)
        cols = np.minimum(((np.arange(size[1]) + 0.5) * w / size[1]).astype(np.int64), w - 1)
        return self.masks[:, rows[:, None], cols[None, :]]


def masks_from_labels(labels: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``(h,w)`` int labels and the label values to keep -> ``(R,h,w)`` bool masks."""
    return labels[None] == np.asarray(keep).reshape(-1, 1, 1)


def _work_size(H: int, W: int, work_height: int) -> tuple[int, int]:
    h = min(work_height, H)
    return h, max(1, int(round(W * h / H)))


def _select(labels: np.ndarray, min_area: int, max_regions: int, exclude: int | None = None) -> np.ndarray:
    """Label values with at least ``min_area`` pixels, the largest ``max_regions`` first."""
    values, counts = np.unique(labels, return_counts=True)
    ok = counts >= max(min_area, 1)
    if exclude is not None:
        ok &= values != exclude
    values, counts = values[ok], counts[ok]
    order = np.argsort(-counts, kind="stable")[:max_regions]
    return values[order]


class RegionGenerator(ABC):
    """Cuts one frame into regions."""

    name: ClassVar[str]

    def __init__(self, params: RegionParams):
        self.params = params

    @abstractmethod
    def __call__(self, rgb: np.ndarray, depth_m: np.ndarray | None, instance: np.ndarray | None) -> Regions:
        """``rgb`` ``(H,W,3)`` uint8, ``depth_m`` ``(H,W)`` metres or None, ``instance`` ``(H,W)`` ids or None."""


class RGBDRegions(RegionGenerator):
    """Felzenszwalb segmentation of colour (CIELAB / 100) and depth (metres x ``depth_weight``)."""

    name = "rgbd"

    def __call__(self, rgb, depth_m, instance) -> Regions:
        from skimage.segmentation import felzenszwalb

        p = self.params
        H, W = rgb.shape[:2]
        h, w = _work_size(H, W, p.work_height)
        small = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)
        lab = cv2.cvtColor(small.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB) / 100.0
        channels = [lab]
        if depth_m is not None and p.depth_weight > 0:
            d = cv2.resize(depth_m.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
            channels.append((d * p.depth_weight)[..., None])
        image = np.concatenate(channels, axis=-1).astype(np.float64)
        min_area = int(p.min_area_frac * h * w)
        with warnings.catch_warnings():  # 4 channels (colour + depth) are meant: silence skimage's RGB hint
            warnings.simplefilter("ignore", RuntimeWarning)
            labels = felzenszwalb(image, scale=p.felzenszwalb_scale, sigma=p.felzenszwalb_sigma,
                                  min_size=max(min_area, 1), channel_axis=-1)
        keep = _select(labels, min_area, p.max_regions)
        return Regions(masks_from_labels(labels, keep), (H, W))


class GTRegions(RegionGenerator):
    """One region per ground-truth instance id (id 0 = walls/floor: one region when ``gt_background``)."""

    name = "gt"

    def __call__(self, rgb, depth_m, instance) -> Regions:
        if instance is None:
            raise InputDataError(
                "region generator 'gt' needs instance images (simulated scenes; frames.zarr 'instance')",
                field="encoders.conceptfusion.regions.generator",
            )
        p = self.params
        H, W = instance.shape
        h, w = _work_size(H, W, p.work_height)
        rows = np.minimum(((np.arange(h) + 0.5) * H / h).astype(np.int64), H - 1)
        cols = np.minimum(((np.arange(w) + 0.5) * W / w).astype(np.int64), W - 1)
        labels = np.asarray(instance)[rows[:, None], cols[None, :]].astype(np.int64)
        keep = _select(labels, int(p.min_area_frac * h * w), p.max_regions, None if p.gt_background else 0)
        return Regions(masks_from_labels(labels, keep), (H, W))


class SAMRegions(RegionGenerator):
    """segment-anything automatic masks from a local checkpoint (import guarded)."""

    name = "sam"

    def __init__(self, params: RegionParams):
        super().__init__(params)
        try:
            from segment_anything import SamAutomaticMaskGenerator, sam_model_registry
        except ImportError:
            raise ConfigError(
                "encoders.conceptfusion.regions.generator is 'sam' but the segment_anything package is not "
                "installed (pip install segment-anything), or choose 'rgbd'"
            ) from None
        if params.sam_checkpoint is None:
            raise ConfigError("encoders.conceptfusion.regions.sam_checkpoint is not set (a local SAM checkpoint)")
        path = Path(params.sam_checkpoint).expanduser()
        if not path.is_file():
            raise MissingInputError(f"encoders.conceptfusion.regions.sam_checkpoint: {path} not found")
        if params.sam_model_type not in sam_model_registry:
            raise ConfigError(f"encoders.conceptfusion.regions.sam_model_type: unknown {params.sam_model_type!r}")
        self._generator = SamAutomaticMaskGenerator(sam_model_registry[params.sam_model_type](checkpoint=str(path)))

    def __call__(self, rgb, depth_m, instance) -> Regions:
        p = self.params
        H, W = rgb.shape[:2]
        found = self._generator.generate(np.ascontiguousarray(rgb))
        found = sorted(found, key=lambda m: -m["area"])[: p.max_regions]
        found = [m for m in found if m["area"] >= p.min_area_frac * H * W]
        masks = np.stack([m["segmentation"] for m in found]) if found else np.zeros((0, H, W), bool)
        h, w = _work_size(H, W, p.work_height)
        return Regions(Regions(masks, (H, W)).resampled((h, w)), (H, W))


REGION_GENERATORS: dict[str, type[RegionGenerator]] = {c.name: c for c in (RGBDRegions, GTRegions, SAMRegions)}


def build_region_generator(params: RegionParams) -> RegionGenerator:
    """The generator named by ``params.generator``."""
    return REGION_GENERATORS[params.generator](params)
