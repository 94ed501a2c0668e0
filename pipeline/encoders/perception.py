"""Simulated open-vocabulary perception for simulated scenes: ``simulated_lseg`` and ``simulated_cf``.

No trained LSeg / CLIP / SAM weights exist on these machines, so the embedded scenes' maps come from
perception MODELS with the error structure of the real ones, in the real CLIP ViT-B/32 text space
(:mod:`pipeline.encoders.perception_text`). They are not trained networks, and every map records
``kind: simulated ... perception`` in its encoder identity; the exact ``oracle`` stays the
ground-truth diagnostic. Settings and the figure each was set from: :mod:`pipeline.encoder_params.perception`;
``benchmarks/quality_maps.py`` prints the maps' mAcc / F-mIoU next to the published ones.

Both read the frame's instance image and the scene's ground truth (``bind_scene``). Per object,
once per scene: its class feature (the class's CLIP row), plus its colour / material directions with
``attribute_weight`` (each misread as another catalogue colour / material with probability
``attribute_confusion``); with probability ``object_confusion`` it is persistently mixed toward a class c'
drawn from ``exp(cos(c, c') / confusion_temperature)`` over the scene's other classes and the
background (so desks turn into tables, cabinets into nightstands, far more often than chairs into
toilets). Per frame and object, with probability ``frame_confusion`` it takes a freshly drawn c' in
that view.

``simulated_lseg`` (dense, the vlmap's): every cell mixes the features of the classes around it with
gaussian weights of ``blur_cells`` (boundary bleeding; thin and small objects washed out by the
background), plus smooth false class responses on a coarse grid of ``noise_cells`` (amplitude
``background_noise`` on walls / floor: low-confidence background; ``object_noise`` on objects).

``simulated_cf`` (regions, the cfmap's): regions are the objects' masks (sharp edges), small ones
(< ``min_region_frac``) dropped into the background region, touching ones merged with
``merge_probability``; each region's local feature is its objects' area-weighted mean (whole-object
errors) with the colour / material of everything in the region's bounding box (ConceptFusion crops the
box, and CLIP does not bind attributes to the object), the global feature the area-weighted mean of all
regions, fused with ConceptFusion's own rule (:func:`pipeline.encoders.conceptfusion.fuse_region_features`).
SAM's automatic masks are nested (each prompt returns a whole, a part and a sub-part mask), and
ConceptFusion adds the fused feature of every mask to its pixels and renormalises: each object region that
touches others also lies in the coarser mask of it with its touching neighbours (their area-weighted
classes, the attributes of the union's bounding box), fused in the same softmax, so an object's pixels
carry its neighbours' classes and colours too (version 3).

All draws are seeded by ``seed``, the scene and the frame's instance image (never by the batch), and
every step works on whole frames (a handful of per-object table rows, one matrix product per frame).
"""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING, Any, ClassVar

import cv2
import numpy as np
import torch

from pipeline.encoders.base import DenseFeatures, Encoder, PaletteFeatures, l2_normalize
from pipeline.encoders.perception_text import (TEMPERATURE, VERSIONS, ClipTextSpace, load_text_space,
                                               resolve_embeddings)
from pipeline.errors import ConfigError, InputDataError
from pipeline.encoder_params.perception import SimulatedCFParams, SimulatedLSegParams
from pipeline.sim.catalog import COLOURS, MATERIALS

if TYPE_CHECKING:
    from pipeline.config import EncodersParams
    from pipeline.scene_gt import GTScene



def _frame_rng(seed: int, salt: str, scene: str, instance: np.ndarray) -> np.random.Generator:
    key = hashlib.blake2b(np.ascontiguousarray(instance).tobytes(), digest_size=8)
    key.update(f"{salt}\0{scene}".encode())
    return np.random.default_rng([seed, int.from_bytes(key.digest(), "little")])


def _cell_ids(instance: np.ndarray, out_size: tuple[int, int]) -> np.ndarray:
    """``(h,w)`` int64 instance ids at the feature cells' centres (nearest pixel)."""
    H, W = instance.shape
    h, w = out_size
    rows = np.minimum(((np.arange(h) + 0.5) * H / h).astype(np.int64), H - 1)
    cols = np.minimum(((np.arange(w) + 0.5) * W / w).astype(np.int64), W - 1)
    return instance[rows[:, None], cols[None, :]].astype(np.int64)


class SimulatedPerception(Encoder):
    """Shared part of the two simulated perception models (see the module docstring)."""

    profile: ClassVar[str]
    kind: ClassVar[str]
    reads_rgb = False  # features come from the instance image and the scene's ground truth
    needs_ground_truth = True

    def __init__(self, params: SimulatedLSegParams | SimulatedCFParams, *, batch_size: int = 4):
        super().__init__(device="cpu", batch_size=batch_size)  # table look-ups and small products
        self.p = params
        param = f"encoders.{self.name}.embeddings"
        self.space: ClipTextSpace = load_text_space(resolve_embeddings(params.embeddings, param), param)
        self.weights = self.space.path  # the embeddings file is this model's 'weights' (digest in identity)
        self.out_size = tuple(params.out_size)
        self._gt: GTScene | None = None
        self._cum_cache: dict[bytes, np.ndarray] = {}  # confusion distribution (cumulative) per class vector

    @classmethod
    def from_params(cls, params: "EncodersParams", *, device: str, batch_size: int = 4) -> "SimulatedPerception":
        return cls(cls.settings(params), batch_size=batch_size)

    @property
    def dim(self) -> int:
        return self.space.dim

    @property
    def temperature(self) -> float:
        return TEMPERATURE

    def config_identity(self) -> dict[str, Any]:
        return {"kind": self.kind, "profile": self.profile, **self.p.model_dump(mode="json", exclude={"embeddings"}),
                "scene": self._gt.name if self._gt is not None else None}

    def encode_text(self, texts: list[str]) -> torch.Tensor:
        return torch.from_numpy(np.stack([self.space.encode(t) for t in texts])).float()

    # ------------------------------------------------------------------ per-object tables
    def _confused(self, base: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Rows of the scene's vocabulary (its classes and the background) drawn for each of ``base`` (N,D)
        class vectors at uniforms ``u`` (N,), itself excluded."""
        out = np.empty((len(base), self.dim))
        for i, b in enumerate(base):  # one draw per object (not per pixel)
            k = b.tobytes()
            if k not in self._cum_cache:
                s = self._vocab @ b
                logits = np.where(s > 0.999, -np.inf, s / self.p.confusion_temperature)
                pr = np.exp(logits - logits[np.isfinite(logits)].max()) if np.isfinite(logits).any() else s * 0 + 1
                self._cum_cache[k] = np.cumsum(pr / pr.sum())
            cum = self._cum_cache[k]
            out[i] = self._vocab[min(int(np.searchsorted(cum, u[i])), len(cum) - 1)]
        return out

    def bind_scene(self, gt: "GTScene | None") -> None:
        """Per object: class row, attributes, persistent confusion (seeded by ``seed``, scene, object id)."""
        self._gt = gt
        if gt is None:
            return
        objs = gt.objects
        self._ids = np.array([o.id for o in objs], np.int64)
        self._class = np.stack([self.space.class_vector(o.cls) for o in objs]) if objs else np.zeros((0, self.dim))
        self._background = self.space.background_vector
        self._scene_classes = np.unique(self._class, axis=0) if objs else np.zeros((0, self.dim))
        self._vocab = np.concatenate([self._scene_classes, self._background[None]])
        self._cum_cache = {}
        rng = np.random.default_rng([self.p.seed, int.from_bytes(
            hashlib.blake2b(f"{self.name}\0{gt.name}".encode(), digest_size=8).digest(), "little")])
        n = len(objs)
        hit = rng.random(n) < self.p.object_confusion
        lo, hi = self.p.object_confusion_strength
        strength = np.where(hit, rng.uniform(lo, hi, n), 0.0)
        other = self._confused(self._class, rng.random(n)) if n else self._class
        self._identity = (1 - strength)[:, None] * self._class + strength[:, None] * other
        # colour / material as perceived: misread (another catalogue colour / material) with attribute_confusion
        colours, materials = sorted(COLOURS), sorted(MATERIALS)
        attrs = []
        for o in objs:
            colour, material = " ".join(o.color_name.lower().split()), o.material
            if rng.random() < self.p.attribute_confusion:
                colour = rng.choice([c for c in colours if c != colour])
            if rng.random() < self.p.attribute_confusion:
                material = rng.choice([m for m in materials if m != material])
            attrs.append(self.space.compose([], [str(colour)], [str(material)], self.p.attribute_weight,
                                            self.p.attribute_weight * 0.6))
        self._attr = np.stack(attrs) if attrs else np.zeros((0, self.dim))

    def _object_identities(self, ids: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``(K,D)`` class part of the objects ``ids`` (row index into the scene's objects) in this frame."""
        ident = self._identity[ids].copy()
        swap = rng.random(len(ids)) < self.p.frame_confusion
        if swap.any():
            ident[swap] = self._confused(self._class[ids[swap]], rng.random(int(swap.sum())))
        return ident

    def _object_rows(self, ids: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``(K,D)`` features of the objects ``ids``: class part plus each object's own attributes."""
        return self._object_identities(ids, rng) + self._attr[ids]

    def _labels(self, instance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(labels (h,w) in 0..K, objs (K,) row indices)``: compact per-frame labels, 0 = background."""
        cells = _cell_ids(instance, self.out_size)
        lut = np.zeros(max(int(cells.max()), int(self._ids.max(initial=0))) + 1, np.int64)
        lut[self._ids] = np.arange(1, len(self._ids) + 1)  # ids not in the scene are background
        rows = lut[cells]
        present, labels = np.unique(rows, return_inverse=True)
        labels = labels.reshape(rows.shape)
        if present[0] != 0:  # keep label 0 = background even when the frame has none
            present = np.concatenate([[0], present])
            labels = labels + 1
        return labels, present[1:] - 1

    def _noise(self, rng: np.random.Generator, amp_cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Smooth false class responses: ``(weights (C,h,w), rows (C,D))`` of the scene's classes, on a coarse
        grid of ``noise_cells`` upsampled bilinearly, scaled per cell by ``amp_cells`` (h,w)."""
        h, w = self.out_size
        C = len(self._scene_classes)
        if C == 0 or not amp_cells.any():
            return np.zeros((0, h, w), np.float32), np.zeros((0, self.dim))
        n = self.p.noise_cells
        gh, gw = -(-h // n) + 1, -(-w // n) + 1
        pick = rng.integers(C, size=(gh, gw))
        amp = rng.random((gh, gw)).astype(np.float32)
        coarse = (pick[None] == np.arange(C)[:, None, None]) * amp[None]  # (C,gh,gw)
        fine = cv2.resize(np.ascontiguousarray(coarse.transpose(1, 2, 0)), (w, h), interpolation=cv2.INTER_LINEAR)
        fine = fine.reshape(h, w, C).transpose(2, 0, 1)
        return fine * amp_cells[None], self._scene_classes

    def _check(self, instance) -> None:
        if self._gt is None:
            raise ConfigError(f"the {self.name} encoder simulates perception on SIMULATED scenes: it needs the scene's "
                              "ground truth (bind_scene); choose a real encoder for real data")
        if instance is None:
            raise InputDataError(f"the {self.name} encoder needs instance images", field="instance",
                                 expected="(B,H,W) uint16 ids (simulated scenes)")

    def _encode_batch(self, rgb: np.ndarray, depth_m, instance) -> DenseFeatures:
        """Cell features ``weights^T rows`` of each frame (:meth:`_frame`), renormalised."""
        self._check(instance)
        B, H, W = instance.shape
        h, w = self.out_size
        out = torch.empty((B, h * w, self.dim), dtype=torch.float32)
        for b in range(B):
            rng = _frame_rng(self.p.seed, self.name, self._gt.name, instance[b])
            weights, table = self._frame(instance[b], rng)  # (N,h,w), (N,D)
            wt = torch.from_numpy(np.ascontiguousarray(weights.reshape(len(weights), -1).T, dtype=np.float32))
            tt = torch.from_numpy(table.astype(np.float32))
            # unit norm from the small Gram matrix (|W T|^2 = rows of W (T T^T) W^T), then one product into place
            norm2 = ((wt @ (tt @ tt.T)) * wt).sum(dim=1, keepdim=True)
            torch.mm(wt / norm2.clamp_min(1e-24).sqrt(), tt, out=out[b])
        feats = out.reshape(B, h, w, self.dim)
        return DenseFeatures(feats, torch.ones((B, h, w), dtype=torch.bool), (H, W))

    def _frame(self, instance: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One frame's features in factored form (see the implementations)."""
        raise NotImplementedError


class SimulatedLSeg(SimulatedPerception):
    """Dense LSeg-like perception (see the module docstring)."""

    name = "simulated_lseg"
    params_model = SimulatedLSegParams
    version = VERSIONS[name]
    profile = "lseg"
    kind = ("simulated LSeg-like dense perception (CLIP ViT-B/32 text space; calibrated to ConceptGraphs "
            "Table I, Replica) - not a trained model")

    def _frame(self, instance, rng):
        labels, objs = self._labels(instance)
        K = len(objs) + 1
        onehot = (labels[..., None] == np.arange(K)).astype(np.float32)  # (h,w,K)
        if self.p.blur_cells > 0:
            s = float(self.p.blur_cells)
            onehot = cv2.GaussianBlur(onehot, (0, 0), sigmaX=s, sigmaY=s, borderType=cv2.BORDER_REFLECT)
            onehot = onehot.reshape(labels.shape + (K,))
        mix = onehot.transpose(2, 0, 1)  # (K,h,w), sums to 1 per cell
        rows = np.concatenate([self._background[None], self._object_rows(objs, rng)])
        amp = self.p.background_noise * mix[0] + self.p.object_noise * (1.0 - mix[0])
        nw, nrows = self._noise(rng, amp)
        return np.concatenate([mix, nw]), np.concatenate([rows, nrows])


class SimulatedCF(SimulatedPerception):
    """Region ConceptFusion-like perception (see the module docstring)."""

    name = "simulated_cf"
    params_model = SimulatedCFParams
    version = VERSIONS[name]
    profile = "conceptfusion"
    kind = ("simulated ConceptFusion-like region perception (CLIP ViT-B/32 text space; calibrated to ConceptFusion + "
            "SAM in ConceptGraphs Table I, Replica) - not a trained model")

    def _regions(self, labels: np.ndarray, K: int, rng: np.random.Generator) -> np.ndarray:
        """``(K,)`` region of each label: small ones join the background (0), touching ones merge at random."""
        h, w = labels.shape
        area = np.bincount(labels.ravel(), minlength=K)
        region = np.arange(K)
        region[(area < self.p.min_region_frac * h * w) & (region > 0)] = 0
        lab = region[labels]
        pairs = self._touching(lab)
        merge = pairs[rng.random(len(pairs)) < self.p.merge_probability]
        parent = np.arange(K)
        for a, b in merge:  # union-find over the frame's few objects
            ra, rb = a, b
            while parent[ra] != ra:
                ra = parent[ra]
            while parent[rb] != rb:
                rb = parent[rb]
            parent[max(ra, rb)] = min(ra, rb)
        for k in range(K):
            r = k
            while parent[r] != r:
                r = parent[r]
            parent[k] = r
        return parent[region]

    @staticmethod
    def _touching(lab: np.ndarray) -> np.ndarray:
        """``(P,2)`` sorted pairs of distinct object regions (> 0) that touch in the region image ``lab``."""
        pairs = np.concatenate([np.stack([lab[:, :-1].ravel(), lab[:, 1:].ravel()], 1),
                                np.stack([lab[:-1].ravel(), lab[1:].ravel()], 1)])
        pairs = pairs[(pairs[:, 0] != pairs[:, 1]) & (pairs.min(axis=1) > 0)]
        return np.unique(np.sort(pairs, axis=1), axis=0)

    def _box_share(self, labels: np.ndarray, cells: np.ndarray, K: int) -> np.ndarray:
        """``(K,)`` share of each label in the bounding box of the ``cells`` mask."""
        rr, cc = np.nonzero(cells)
        box = labels[rr.min() : rr.max() + 1, cc.min() : cc.max() + 1]
        return np.bincount(box.ravel(), minlength=K) / box.size

    def _groups(self, labels: np.ndarray, objs: np.ndarray, region: np.ndarray, ident: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """SAM's coarser masks: ``(regions (G,), local features (G,D))``, for each object region that touches
        others, the mask of it with its touching neighbours (SAM's automatic generator returns each prompt's
        whole / part / sub-part masks, so an object's pixels lie in larger masks too), its local feature the
        neighbours' area-weighted mean (class parts ``ident`` (K,D) as in this frame) with the attributes of the
        union's bounding box."""
        K = len(objs) + 1
        lab = region[labels]
        pairs = self._touching(lab)
        if not len(pairs):
            return np.zeros(0, np.int64), np.zeros((0, self.dim))
        attr = np.concatenate([np.zeros((1, self.dim)), self._attr[objs]])
        area = np.bincount(labels.ravel(), minlength=K).astype(np.float64)
        owners, feats = [], []
        for r in np.unique(pairs):
            members = np.unique(np.concatenate([[r], pairs[pairs[:, 0] == r, 1], pairs[pairs[:, 1] == r, 0]]))
            inside = np.isin(region, members)  # (K,) labels in the group
            rows = ident[inside] + self._box_share(labels, np.isin(lab, members), K) @ attr
            feats.append((area[inside, None] * rows / np.linalg.norm(rows, axis=1, keepdims=True)).sum(0))
            owners.append(r)
        return np.asarray(owners, np.int64), np.stack(feats)

    def _box_attributes(self, labels: np.ndarray, objs: np.ndarray, region: np.ndarray) -> np.ndarray:
        """``(K,D)`` attribute part of each label: the mean attributes of every cell in its region's bounding
        box (background cells carry none). ConceptFusion's local feature is CLIP of the region's box crop, and
        CLIP does not bind colour / material to the object (ARO): the crop reports the box's attributes."""
        K = len(objs) + 1
        attr = np.concatenate([np.zeros((1, self.dim)), self._attr[objs]])
        lab = region[labels]
        out = np.zeros((K, self.dim))
        for r in np.unique(lab):
            if r == 0:
                continue
            out[region == r] = self._box_share(labels, lab == r, K) @ attr
        return out

    def _frame(self, instance, rng):
        labels, objs = self._labels(instance)
        K = len(objs) + 1
        region = self._regions(labels, K, rng)
        ident = np.concatenate([self._background[None], self._object_identities(objs, rng)])
        rows = ident + self._box_attributes(labels, objs, region)
        area = np.bincount(labels.ravel(), minlength=K).astype(np.float64)
        R = int(region.max()) + 1
        local = np.zeros((R, self.dim))
        np.add.at(local, region, area[:, None] * (rows / np.linalg.norm(rows, axis=1, keepdims=True)))
        used = np.bincount(region, weights=area, minlength=R) > 0
        # false responses: the background region leans toward a random scene class (low-confidence background)
        if len(self._scene_classes):
            pick = self._scene_classes[rng.integers(len(self._scene_classes), size=R)]
            amp = np.where(np.arange(R) == 0, self.p.background_noise, self.p.object_noise) * rng.random(R)
            local = l2_normalize(torch.from_numpy(local)).numpy() + amp[:, None] * pick
        local_t = l2_normalize(torch.from_numpy(local[used]))
        g = l2_normalize((torch.from_numpy(np.bincount(region, weights=area, minlength=R)[used])[:, None]
                          * local_t).sum(0, keepdim=True))
        owners, group_local = self._groups(labels, objs, region, ident)
        masks = torch.cat([local_t, l2_normalize(torch.from_numpy(group_local))]) if len(owners) else local_t
        from pipeline.encoders.conceptfusion import fuse_region_features  # imports open_clip: only when fusing

        # one softmax over all the frame's masks, as ConceptFusion fuses every mask SAM returned
        fused = fuse_region_features(g, masks, torch.zeros(len(masks), dtype=torch.long), 1,
                                     self.p.global_temperature).numpy()
        table = np.zeros((R, self.dim))
        table[used] = fused[: len(local_t)]
        if len(owners):
            # a pixel's feature is the sum of the fused features of every mask holding it, renormalised
            table[owners] += fused[len(local_t):]
            table[owners] /= np.linalg.norm(table[owners], axis=1, keepdims=True)
        return table, region[labels]  # (R,D) unit rows, (h,w) row of each cell

    def _encode_batch(self, rgb: np.ndarray, depth_m, instance) -> PaletteFeatures:
        """Region features are one vector per region: a palette (all frames' regions) and each cell's row."""
        self._check(instance)
        B, H, W = instance.shape
        tables, index, offset = [], [], 0
        for b in range(B):
            table, cells = self._frame(instance[b], _frame_rng(self.p.seed, self.name, self._gt.name, instance[b]))
            tables.append(table)
            index.append(cells + offset)
            offset += len(table)
        palette = torch.from_numpy(np.concatenate(tables).astype(np.float32))
        idx = torch.from_numpy(np.stack(index).astype(np.int64))
        return PaletteFeatures(palette, idx, torch.ones(idx.shape, dtype=torch.bool), (H, W))
