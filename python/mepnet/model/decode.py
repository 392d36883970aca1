"""From network outputs to stage-2 detections: heatmap peaks (3x3 max-pool NMS), the top
``count`` per component type (the manual states the counts), sub-cell offsets, rotation-class
probabilities at the peak, and instance masks by clustering the associative embeddings around
the peaks within the type's semantic mask."""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from mepnet.model.config import ModelConfig
from mepnet.model.net import MEPNet
from mepnet.model.targets import collate, make_sample
from mepnet.predictors import Prediction, Predictor, StepContext, run_stage2


def decode(
    out: dict[str, torch.Tensor], counts: list[int], cfg: ModelConfig, image_size: int
) -> list[list[dict[str, Any]]]:
    """Detections per slot for one sample (batch of 1): keypoints in pixels of ``image_size``."""
    heat = torch.sigmoid(out["heatmap"][0])  # (K, h, w)
    peaks = heat * (F.max_pool2d(heat[None], 3, 1, 1)[0] == heat)
    n = heat.shape[-1]
    px = image_size / n
    seg = torch.sigmoid(out["mask"][0]) > 0.5  # (K, h, w)
    result = []
    for s, count in enumerate(counts[: cfg.k_max]):
        flat = peaks[s].flatten()
        k = min(max(count, 0), flat.numel())
        scores, idx = flat.topk(k) if k else (flat[:0], flat[:0].long())
        dets = []
        centres = []
        for score, i in zip(scores.tolist(), idx.tolist(), strict=True):
            y, x = divmod(i, n)
            dx, dy = out["offset"][0, s, :, y, x].tolist()
            rot = torch.softmax(out["rotation"][0, s, :, y, x], 0).tolist()
            centres.append(out["embedding"][0, s, :, y, x])
            dets.append(
                {"keypoint": ((x + dx) * px, (y + dy) * px), "score": float(score), "rotation": rot}
            )
        if dets:
            emb = out["embedding"][0, s]  # (d, h, w)
            dist = torch.stack(
                [((emb - c[:, None, None]) ** 2).sum(0) for c in centres]
            )  # (k, h, w)
            owner = dist.argmin(0)
            for j, d in enumerate(dets):
                m = (seg[s] & (owner == j)).numpy()
                d["mask"] = (
                    np.kron(m, np.ones((int(px), int(px)), dtype=bool)) if px == int(px) else None
                )
        result.append(dets)
    return result


class MEPNetPredictor(Predictor):
    """The detector followed by stage 2 (the ``mepnet`` predictor)."""

    name = "mepnet"

    def __init__(self, model: MEPNet, cfg: ModelConfig):
        self.model = model
        self.cfg = cfg
        self._sizes_noted: set[tuple[int, int]] = set()

    def _note_size(self, ctx: StepContext) -> None:
        """Say once per image size that the manual's images are resized for the detector."""
        w, h = ctx.image_size
        if (w, h) != (self.cfg.image_size, self.cfg.image_size) and (w, h) not in self._sizes_noted:
            self._sizes_noted.add((w, h))
            print(
                f"mepnet: {w}x{h} step images are resized to the detector's "
                f"{self.cfg.image_size}x{self.cfg.image_size} (keypoints are mapped back)",
                file=sys.stderr,
            )

    @torch.no_grad()
    def predict(self, ctx: StepContext) -> list[Prediction]:
        was_training = self.model.training
        self.model.eval()
        try:
            build = ctx.truth
            k = build.steps.index(ctx.step)
            self._note_size(ctx)
            w, h = ctx.image_size
            types = []
            # K_max component types per forward pass; a step with more takes several
            n_types = len(ctx.step.components)
            for first in range(0, n_types, self.cfg.k_max):
                chunk = list(range(first, min(first + self.cfg.k_max, n_types)))
                sample = make_sample(
                    _ManualView(ctx),
                    build,
                    k,
                    self.cfg,
                    components=ctx.components,
                    base=ctx.base,
                    slot_types=chunk,
                )
                out = self.model(collate([sample]))
                slots = [ctx.step.components[i] for i in chunk]
                dets = decode(out, [c.count for c in slots], self.cfg, w)
                types += [
                    {
                        "component": ctx.components[c.component],
                        "count": c.count,
                        "detections": d,
                        "ref": c.component,
                    }
                    for c, d in zip(slots, dets, strict=True)
                ]
            return run_stage2(ctx, types)
        finally:
            self.model.train(was_training)


class _ManualView:
    """The bits of a Manual that make_sample needs, from a step context (components given)."""

    def __init__(self, ctx: StepContext):
        self.ctx = ctx

    def component(self, ref: Any) -> Any:
        return self.ctx.components[ref]
