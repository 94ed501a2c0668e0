"""Typed settings of the simulated perception models (no torch here: the params schema imports it).

- :class:`SimulatedLSegParams` / :class:`SimulatedCFParams`: the ``simulated_lseg`` / ``simulated_cf``
  encoders of :mod:`pipeline.encoders.perception` (sections ``encoders.simulated_lseg`` /
  ``encoders.simulated_cf``); ``encoders.simulated: perception`` gives the vlmap the LSeg-like one and
  the cfmap the ConceptFusion-like one.
- :class:`DetectorParams`: the simulated open-vocabulary detector of the evaluator's CoW and ORION
  agents (:mod:`orion_eval.detector`, section ``eval.detector``).

Every default says which published figure it was set from; ``benchmarks/quality_maps.py`` prints the
simulated maps' mAcc / F-mIoU next to those figures. Where a default is a modelling choice that no
published figure pins down, its description says so.
"""

from __future__ import annotations

from typing import Optional

from pydantic import Field

from pipeline.section import CellSize, Section

# Published perception-level figures the defaults are calibrated to (3D open-vocabulary semantic
# segmentation on Replica, ConceptFusion's protocol; ConceptGraphs, Gu et al., arXiv 2309.16650, Table I).
PUBLISHED = {
    "ConceptFusion": {"mAcc": 24.16, "F-mIoU": 31.31, "source": "ConceptGraphs (arXiv 2309.16650) Table I, Replica"},
    "ConceptFusion + SAM": {"mAcc": 31.53, "F-mIoU": 38.70,
                            "source": "ConceptGraphs (arXiv 2309.16650) Table I, Replica"},
    "ConceptGraphs": {"mAcc": 40.63, "F-mIoU": 35.95, "source": "ConceptGraphs (arXiv 2309.16650) Table I, Replica"},
    "OpenSeg (privileged)": {"mAcc": 41.19, "F-mIoU": 53.74,
                             "source": "ConceptGraphs (arXiv 2309.16650) Table I, Replica"},
    "LSeg (privileged)": {"mAcc": 33.39, "F-mIoU": 51.54,
                          "source": "ConceptGraphs (arXiv 2309.16650) Table I, Replica"},
}


class _PerceptionParams(Section):
    """What both simulated perception models share: the text space, the seed and the class confusions."""

    embeddings: Optional[str] = Field(
        None, description="folder with lvis_v1_clip_vitb32_a+cname.npy and lvis_v1_names.txt (CLIP ViT-B/32 text "
        "embeddings of the LVIS names, float (1203, D) and 1203 name lines); null = the ones shipped with zipon "
        "(pipeline/data/clip_text, from Detic, Apache-2.0); a relative path is taken from the working directory"
    )
    seed: int = Field(0, description="seed of every draw (per object and per frame); the same seed gives the same map")
    out_size: CellSize = Field((120, 160), description="feature (height, width), cells (LSeg and ConceptFusion: 120x160)")
    confusion_temperature: float = Field(
        0.02, gt=0, description="a confused object takes class c' with probability ~ exp(cos(c, c') / T) over the "
        "scene's other classes and the background (real CLIP similarities: desk->table 0.93, cabinet->nightstand); "
        "T = 0.02 puts most mass on the 2-3 nearest (modelling choice)"
    )
    object_confusion: float = Field(
        0.35, ge=0, le=1, description="probability an object is confused in most views (a persistent error: the same "
        "object looks like its neighbour class from every side); with blur_cells 3 the vlmap's mAcc / F-mIoU on the "
        "two demo scenes is 39.6 / 45.2 against LSeg's 33.4 / 51.5 (0.2 with blur 4 gave 52.8 / 49.7 on sim_00; "
        "benchmarks/quality_maps.py)"
    )
    object_confusion_strength: tuple[float, float] = Field(
        (0.5, 1.0), description="mixing weight (uniform in [lo, hi]) of the confused class in a persistently "
        "confused object's feature"
    )
    frame_confusion: float = Field(
        0.15, ge=0, le=1, description="probability an object takes a confused class in one frame (per-view error)"
    )
    attribute_weight: float = Field(
        0.3, ge=0, description="weight of the object's colour / material direction in its features (text side: "
        "colour 0.5, material 0.3 against the class, as in 'a red chair' vs 'a chair' ~0.9 in CLIP); each model "
        "sets its own"
    )
    attribute_confusion: float = Field(
        0.4, ge=0, le=1, description="probability an object's colour (and, drawn apart, its material) is perceived as "
        "another catalogue colour / material, persistently: CLIP binds attributes to objects little better than "
        "chance (ARO VG-Attribution, Yuksekgonul et al. ICLR 2023: CLIP ViT-B/32 62 % where chance is 50 %; recalled, "
        "a modelling anchor)"
    )
    noise_cells: int = Field(
        12, gt=0, description="edge (feature cells) of the coarse grid of the smooth false responses (a ViT patch "
        "group: 12 cells of 120 = 1/10 of the image height)"
    )
    background_noise: float = Field(
        0.6, ge=0, description="amplitude of the smooth false class responses on background (walls, floor): "
        "low-confidence background"
    )
    object_noise: float = Field(0.25, ge=0, description="amplitude of the same smooth false responses on objects")


class SimulatedLSegParams(_PerceptionParams):
    """Simulated LSeg-like dense perception (the vlmap's): boundary bleeding, small objects washed out,
    confusions toward CLIP-similar classes, low-confidence background. Not a trained model."""

    attribute_weight: float = Field(
        0.1, ge=0, description="weight of the object's colour / material direction in its pixel features: LSeg "
        "trains its image encoder so each pixel's feature matches the frozen CLIP text feature of its CATEGORY label "
        "(Li et al., ICLR 2022: per-pixel cross-entropy over the label set's text features); no label names a "
        "colour or material, so what survives is a weak residue of the CLIP initialisation (modelling choice: a "
        "third of the 0.3 a CLIP image feature keeps; no published figure measures it)"
    )
    blur_cells: float = Field(
        3.0, ge=0, description="gaussian sigma (feature cells) of the per-class masks before features are mixed: "
        "LSeg's ViT-L/16 tokens are 16 px of a 480 px crop (4 cells of 120), its decoder upsamples them, so edges "
        "bleed over ~2-3 cells and objects thinner than ~2 cells are washed out"
    )


class SimulatedCFParams(_PerceptionParams):
    """Simulated ConceptFusion-like region perception (the cfmap's): whole-object mask errors, merged
    neighbouring regions, global-context mixing. Not a trained model."""

    object_confusion: float = Field(
        0.45, ge=0, le=1, description="as for the LSeg-like model; higher: a region's CLIP crop is classified as "
        "a whole. Set against ConceptFusion with SAM's automatic masks, the variant the paper's code runs (navchat's "
        "orion/perception/extractor/concept_fusion_extractor.py: SamAutomaticMaskGenerator): mAcc 31.5 / F-mIoU "
        "38.7 in ConceptGraphs Table I (ConceptFusion with its first region proposer: 24.2 / 31.3; LSeg 33.4 / "
        "51.5). With merges 0.15, on the three findings_* check scenes 0.45 gives 29.5 / 31.3 where 0.55 with merges "
        "0.2 gives 23.1 / 24.5: the move between the two published rows (+7.4 / +7.4); on three other HM3D-sized "
        "scenes 36.7 / 37.4 against 29.7 / 26.4 (benchmarks/quality_maps.py --maps cfmap)"
    )
    object_confusion_strength: tuple[float, float] = Field((0.6, 1.0), description="see simulated_lseg")
    frame_confusion: float = Field(0.2, ge=0, le=1, description="see simulated_lseg (a whole region per frame)")
    attribute_weight: float = Field(
        0.5, ge=0, description="weight of colour / material in a CLIP crop's feature (plain CLIP, not trained on "
        "labels: text side uses 0.5 for colour); the crop is the region's BOUNDING BOX and CLIP does not bind "
        "attributes to objects (ARO, see attribute_confusion), so a region gets the area-weighted attributes of "
        "everything in its box (background: none), and the 3D fusion then averages what each view's box held"
    )
    attribute_confusion: float = Field(0.3, ge=0, le=1, description="see simulated_lseg (CLIP crops: fewer misreads)")
    merge_probability: float = Field(
        0.15, ge=0, le=1, description="per frame, probability two touching objects are one region (SAM/felzenszwalb "
        "under-segmentation: the lamp with its nightstand); both get the area-weighted mean feature"
    )
    min_region_frac: float = Field(
        0.002, ge=0, lt=1, description="regions smaller than this image fraction are dropped (ConceptFusion's SAM "
        "min area); their cells take the surrounding background region"
    )
    global_temperature: float = Field(
        1.0, gt=0, description="ConceptFusion's fusion: w_i = softmax_i(cos(global, local_i) / T), f_i = w_i global "
        "+ (1 - w_i) local_i (the real encoder's rule, encoders.conceptfusion.softmax_temperature)"
    )


class DetectorParams(Section):
    """Simulated open-vocabulary detector (GroundingDINO-like boxes + verification) on the ego view, used by
    the CoW and ORION agents instead of ground-truth visibility. Not a trained model."""

    seed: int = Field(0, description="seed of the per-view detection draws")
    max_recall: float = Field(
        0.9, gt=0, le=1, description="recall of a large, unoccluded object whose class is the query (Grounding DINO "
        "reaches ~0.9 recall on large COCO objects; modelling anchor)"
    )
    half_recall_area: float = Field(
        0.0033, gt=0, lt=1, description="image fraction where recall is half of max_recall: COCO's 'small' limit "
        "(32x32 px of 640x480), where detector AP drops to about half"
    )
    size_slope: float = Field(0.8, gt=0, description="width of the recall ramp in log(area) units")
    occlusion_power: float = Field(
        0.5, ge=0, description="recall is multiplied by (visible share of the object's own silhouette) ** this: half "
        "hidden keeps ~0.7 of the recall (modelling choice; the reconstructed mesh's holes count as occlusion)"
    )
    match_threshold: float = Field(
        0.92, gt=0, le=1, description="CLIP cosine of query and object class at which the phrase grounding fires half "
        "the time: 'table' finds desks (0.93) often, 'chair' armchairs (0.96) mostly, sofas (0.87) seldom, toilets "
        "(0.85) almost never (modelling choice on CLIP's text similarities)"
    )
    match_width: float = Field(0.015, gt=0, description="width of the grounding ramp in cosine units")
    min_pixels: int = Field(2, gt=0, description="objects with fewer visible ego-view pixels are never detected")
