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

from mepnet.lift import (
    CHANGE_THRESHOLD,
    LIFTS,
    SynthesisType,
    step_change,
    step_picture,
    synthesize,
)
from mepnet.model.config import ModelConfig
from mepnet.model.net import MEPNet
from mepnet.model.targets import collate, make_sample
from mepnet.predictors import Prediction, Predictor, StepContext, run_stage2

#: A pixel is a plausible part of a component type when the network's mask probability for
#: that type is at least this fraction of the most probable type's there (0: every changed
#: pixel may be any type, and the network's belief only weighs in stage 2's scores; narrowing
#: the masks hurt with the shipped weights).
PLAUSIBLE = 0.0


def _cells(size: int, n: int) -> np.ndarray:
    """The cell (of ``n``) each of ``size`` pixel centres falls in."""
    return ((np.arange(size) + 0.5) * n / size).astype(np.int64).clip(0, n - 1)


def _resize_nearest(a: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(..., n, n) -> (..., H, W) by nearest neighbour (pixel centres); ``size`` is (W, H)."""
    n = a.shape[-1]
    return a[..., _cells(size[1], n)[:, None], _cells(size[0], n)[None, :]]


def decode(
    out: dict[str, torch.Tensor],
    counts: list[int],
    cfg: ModelConfig,
    image_size: int | tuple[int, int],
    change: np.ndarray | None = None,
) -> list[list[dict[str, Any]]]:
    """Detections per slot for one sample (batch of 1): keypoints and masks in pixels of
    ``image_size`` (W, H; an int for a square image).

    Masks: each pixel goes to the slot whose mask probability is highest there, then within the
    slot to the peak with the nearest associative embedding. With ``change`` (a square change
    map of the step, any resolution: :func:`mepnet.lift.step_change`), the pixels are those
    that differ from the rendered base shape (the network's masks decide only which component
    and instance a changed pixel belongs to); without it, those the network marks."""
    heat = torch.sigmoid(out["heatmap"][0])  # (K, h, w)
    peaks = heat * (F.max_pool2d(heat[None], 3, 1, 1)[0] == heat)
    n = heat.shape[-1]
    size = (image_size, image_size) if isinstance(image_size, int) else tuple(image_size)
    px, py = size[0] / n, size[1] / n
    k_used = min(len(counts), cfg.k_max)
    prob = torch.sigmoid(out["mask"][0, :k_used]).numpy()  # (k, h, w)
    emb_all = out["embedding"][0].numpy()  # (K, d, h, w)
    if change is not None and k_used:
        support = _resize_nearest(change > CHANGE_THRESHOLD, size)
        hi = change.shape[-1]
        up = F.interpolate(
            torch.from_numpy(prob)[None], size=(hi, hi), mode="bilinear", align_corners=False
        )[0].numpy()
        slot_of = _resize_nearest(up.argmax(0), size)
        # a changed pixel may belong to every component type the network finds about as
        # likely as the best one (stage 2 sorts the rest out by synthesis)
        plausible = _resize_nearest(up >= PLAUSIBLE * up.max(0, keepdims=True), size)
        type_prob = _resize_nearest(up / np.maximum(up.sum(0, keepdims=True), 1e-6), size)
    else:
        type_prob = _resize_nearest(prob / np.maximum(prob.sum(0, keepdims=True), 1e-6), size)
        support = _resize_nearest(prob.max(0) > 0.5, size) if k_used else None
        slot_of = _resize_nearest(prob.argmax(0), size) if k_used else None
        plausible = (
            _resize_nearest(prob >= PLAUSIBLE * prob.max(0, keepdims=True), size)
            if k_used
            else None
        )
    # embedding cell of every output pixel
    rows, cols = _cells(size[1], n), _cells(size[0], n)
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
            centres.append(emb_all[s, :, y, x])
            dets.append(
                {"keypoint": ((x + dx) * px, (y + dy) * py), "score": float(score), "rotation": rot}
            )
        if dets:
            mine = support & (slot_of == s)
            emb = emb_all[s][:, rows[:, None], cols[None, :]]  # (d, H, W)
            dist = np.stack([((emb - c[:, None, None]) ** 2).sum(0) for c in centres])
            owner = dist.argmin(0)
            # what the slot's type as a whole looks like: the same arrays on each detection
            per_type = {
                "type_mask": support & plausible[s],
                "type_prob": type_prob[s],
                "type_heat": _resize_nearest(heat[s].numpy(), size),
            }
            for j, d in enumerate(dets):
                d["mask"] = mine & (owner == j)
                d.update(per_type)
        result.append(dets)
    return result


class MEPNetPredictor(Predictor):
    """The detector followed by stage 2 (the ``mepnet`` predictor)."""

    name = "mepnet"

    def __init__(
        self,
        model: MEPNet,
        cfg: ModelConfig,
        use_change: bool = True,
        lift: str = "synthesis",
        time_limit_s: float = 10.0,
    ):
        if lift not in LIFTS:
            raise ValueError(f"unknown lift '{lift}' (choose from {', '.join(LIFTS)})")
        self.model = model
        self.cfg = cfg
        self.use_change = use_change
        self.lift = lift
        self.time_limit_s = time_limit_s
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
            picture = step_picture(ctx)
            # where the picture differs from the base shape (lines tolerated), at the image's
            # size; a non-square image: the change map of the network's (resized) input
            change, tone = step_change(ctx, picture) if self.use_change and w == h else (None, None)
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
                if change is None and self.use_change:
                    change = sample.tensors["state_maps"][9].numpy()
                dets = decode(out, [c.count for c in slots], self.cfg, (w, h), change)
                types += [
                    {
                        "component": ctx.components[c.component],
                        "count": c.count,
                        "detections": d,
                        "ref": c.component,
                    }
                    for c, d in zip(slots, dets, strict=True)
                ]
            if self.lift == "keypoint":
                return run_stage2(ctx, types)
            return self._synthesis(ctx, types, picture, tone)
        finally:
            self.model.train(was_training)

    def _synthesis(
        self,
        ctx: StepContext,
        types: list[dict[str, Any]],
        picture: np.ndarray,
        tone: np.ndarray | None,
    ) -> list[Prediction]:
        """Lift by synthesis (:func:`mepnet.lift.synthesize`) from the detector's type masks
        and beliefs (``picture``: the step image, floats in [0, 1]; ``tone``: its tone fit to
        the base shape, from :func:`mepnet.lift.step_change`)."""
        h, w = ctx.image_size[1], ctx.image_size[0]
        return synthesize(
            ctx,
            [
                SynthesisType(
                    ref=t["ref"],
                    component=t["component"],
                    count=t["count"],
                    mask=t["detections"][0]["type_mask"]
                    if t["detections"]
                    else np.zeros((h, w), bool),
                    belief=t["detections"][0]["type_prob"] if t["detections"] else None,
                    heat=t["detections"][0]["type_heat"] if t["detections"] else None,
                )
                for t in types
            ],
            time_limit_s=self.time_limit_s,
            picture=picture,
            tone=tone,
        )


class _ManualView:
    """The bits of a Manual that make_sample needs, from a step context (components given)."""

    def __init__(self, ctx: StepContext):
        self.ctx = ctx

    def component(self, ref: Any) -> Any:
        return self.ctx.components[ref]
