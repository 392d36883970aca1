"""Baselines and oracles behind the stage-2 interface.

- ``oracle``: 2D detections computed from the answers (keypoints, rotation classes, visible
  masks from the instance map), then the keypoint lift -- the upper bound of stage 2.
- ``oracle-noisy``: the same with Gaussian keypoint jitter of ``sigma`` pixels.
- ``oracle-abys``: analysis-by-synthesis on the *true* instance masks (an oracle): every valid
  pose of each component rasterized over the current shape and scored by mask IoU, with a
  per-component time limit. (The paper's a-by-s on the detector's masks is ``abys``,
  :mod:`mepnet.stage2.abys`.)
"""

from __future__ import annotations

import zlib

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.detector.detections import TypeDetections
from mepnet.manual import StepTruth
from mepnet.stage2.base import AnswerReader, Prediction, StepContext
from mepnet.stage2.keypoint import DetectedType, lift_keypoints


def truth_detections(
    ctx: StepContext, truth: StepTruth, sigma: float, rng: np.random.Generator | None
) -> list[DetectedType]:
    """Per callout entry, detections made from the step's answers (keypoints jittered by
    ``sigma`` pixels when ``sigma > 0``)."""
    ids = truth.ids()
    types = []
    for entry, sc in enumerate(ctx.step.components):
        comp = ctx.components[sc.component]
        iids = truth.instances_of[entry]
        kps = np.array([truth.keypoint(i) for i in iids], dtype=np.float64).reshape(-1, 2)
        if sigma > 0 and rng is not None:
            kps = kps + rng.normal(0.0, sigma, size=kps.shape)
        rot = np.zeros((len(iids), 7), np.float32)
        for j, i in enumerate(iids):
            rot[j, _bg.rotation_class(comp.symmetry, truth.instances[i].yaw)] = 1.0
        masks = np.stack([ids == i for i in iids]) if iids else np.zeros((0, *ids.shape), bool)
        dets = TypeDetections(kps, np.ones(len(iids), np.float32), rot, masks)
        types.append(DetectedType(entry, comp, sc.count, dets))
    return types


class OraclePredictor(AnswerReader):
    """True 2D detections (optionally with keypoint noise), then the keypoint lift."""

    name = "oracle"

    def __init__(self, sigma: float = 0.0, seed: int = 0):
        if not sigma >= 0 or not np.isfinite(sigma):
            from mepnet.errors import ConfigError

            raise ConfigError(f"--sigma must be a finite number >= 0, got {sigma}")
        self.sigma = float(sigma)
        self.seed = seed
        if self.sigma > 0:
            self.name = "oracle-noisy"

    def predict_with_answers(self, ctx: StepContext, truth: StepTruth) -> list[Prediction]:
        # noise drawn per step image (seed, manual, file), so a step gets the same jitter in
        # every mode and order of evaluation
        key = f"{ctx.step.image_path.parent.name}/{ctx.step.image_path.name}"
        key = key.encode("utf-8", "surrogateescape")  # file names need not be UTF-8
        rng = np.random.default_rng([self.seed, zlib.crc32(key)])  # type: ignore[arg-type]
        return lift_keypoints(ctx, truth_detections(ctx, truth, self.sigma, rng))


class OracleAbysPredictor(AnswerReader):
    """Analysis-by-synthesis on the true instance masks (an oracle)."""

    name = "oracle-abys"

    def __init__(self, time_limit_s: float = 60.0):
        self.time_limit_s = time_limit_s
        self.timeouts = 0

    def predict_with_answers(self, ctx: StepContext, truth: StepTruth) -> list[Prediction]:
        ids = truth.ids()
        w, h = ctx.image_size
        items, entries = [], []
        for entry, sc in enumerate(ctx.step.components):
            for iid in truth.instances_of[entry]:
                items.append((ctx.components[sc.component], ids == iid))
                entries.append(entry)
        out = _bg.abys_step(ctx.base, ctx.camera, w, h, items, self.time_limit_s)
        preds = []
        for entry, (pose, iou, timed_out) in zip(entries, out, strict=True):
            self.timeouts += int(timed_out)
            preds.append(
                Prediction(
                    entry=entry,
                    component=ctx.step.components[entry].component,
                    yaw=pose[0] if pose else None,
                    t=tuple(pose[1]) if pose else None,
                    failure=None if pose else "no valid placement",
                    extra={"iou": iou, "timed_out": timed_out},
                )
            )
        return preds


def _match(a: np.ndarray, b: np.ndarray) -> list[tuple[int, int]]:
    """Greedy one-to-one matching of the points ``a`` (N, 2) and ``b`` (M, 2), nearest pairs
    first: (index in a, index in b)."""
    if not len(a) or not len(b):
        return []
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    pairs, used_a, used_b = [], set(), set()
    for flat in np.argsort(d, axis=None, kind="stable"):
        i, j = divmod(int(flat), len(b))
        if i not in used_a and j not in used_b:
            pairs.append((i, j))
            used_a.add(i)
            used_b.add(j)
    return pairs


class HalfOraclePredictor(AnswerReader):
    """The supplementary's ablation: the detector and the keypoint lift with one half of the
    answer swapped in. ``swap="translation"``: every true instance's keypoint (so the lift finds
    its true position) with the rotation probabilities and mask of the detection nearest to it
    (uniform rotations and no mask where the detector found fewer instances);
    ``swap="rotation"``: the detector's keypoints and masks with the true rotation class of the
    true instance nearest to each detection."""

    SWAPS = ("translation", "rotation")

    def __init__(self, detector, swap: str):
        if swap not in self.SWAPS:
            from mepnet.errors import ConfigError

            raise ConfigError(f"unknown swap '{swap}' (choose from {', '.join(self.SWAPS)})")
        self.detector = detector
        self.swap = swap
        self.name = f"oracle-{swap}"

    def predict_with_answers(self, ctx: StepContext, truth: StepTruth) -> list[Prediction]:
        from mepnet.stage2.detector import share_out

        types, _, _ = self.detector.detections(ctx)
        true = truth_detections(ctx, truth, 0.0, None)
        swapped = []
        for entries, t in types:
            det = t.detections
            true_kp = np.concatenate([true[e].detections.keypoints for e in entries])
            true_rot = np.concatenate([true[e].detections.rotations for e in entries])
            n = len(true_kp)
            pairs = _match(det.keypoints, true_kp)
            if self.swap == "translation":
                rot = np.full((n, 7), 1.0 / 7.0, np.float32)
                masks = np.zeros((n, *det.masks.shape[1:]), bool)
                for d, j in pairs:
                    rot[j] = det.rotations[d]
                    masks[j] = det.masks[d]
                new = TypeDetections(true_kp, np.ones(n, np.float32), rot, masks)
            else:
                rot = det.rotations.copy()
                for d, j in pairs:
                    rot[d] = true_rot[j]
                new = TypeDetections(det.keypoints, det.scores, rot, det.masks)
            swapped.append((entries, DetectedType(t.entry, t.component, t.count, new)))
        return share_out(ctx, lift_keypoints(ctx, [t for _, t in swapped]), swapped)
