"""The ``mepnet`` predictor: the detector (stage 1) followed by stage 2. As CenterNet's
detector class, this wraps model + pure decoding + post-processing and lives with the stage
that uses it, so the detector package never imports stage 2.

Lifts: ``synthesis`` (default: :mod:`mepnet.stage2.synthesis` from the detector's type masks and
beliefs) or ``keypoint`` (the paper's keypoint ray search, :mod:`mepnet.stage2.keypoint`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from mepnet.cli import note
from mepnet.detector.config import ModelConfig
from mepnet.detector.decode import decode
from mepnet.detector.net import MEPNet
from mepnet.detector.targets import collate, component_slots, make_sample, world_rotations
from mepnet.errors import ConfigError
from mepnet.stage2.base import LIFTS, Prediction, Predictor, StepContext
from mepnet.stage2.keypoint import DetectedType, lift_keypoints
from mepnet.stage2.synthesis import SynthesisType, Tone, step_change, step_picture, synthesize
from mepnet.threads import one_thread

#: How the detector's detections are lifted to 3D.


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
            raise ConfigError(f"unknown lift '{lift}' (choose from {', '.join(LIFTS)})")
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
            note(
                f"{w}x{h} step images are resized to the detector's "
                f"{self.cfg.image_size}x{self.cfg.image_size} (keypoints are mapped back)"
            )

    def detect(
        self, ctx: StepContext, change: np.ndarray | None
    ) -> tuple[list[tuple[list[int], DetectedType]], np.ndarray | None]:
        """The detector's detections per component type (:func:`component_slots`: the callout
        entries of one component share a slot; K_max types per forward pass, a step with more
        takes several), each with the callout entries it covers, and the change map used (the
        network input's when none was given)."""
        w, h = ctx.image_size
        slots = component_slots(ctx.step)
        types: list[tuple[list[int], DetectedType]] = []
        for first in range(0, len(slots), self.cfg.k_max):
            chunk = list(range(first, min(first + self.cfg.k_max, len(slots))))
            sample = make_sample(
                ctx.step,
                self.cfg,
                base=ctx.base,
                components=ctx.components,
                slot_types=chunk,
                change=change,
            )
            out = self.model(collate([sample]))
            if change is None and self.use_change:
                change = sample.tensors["state_maps"][9].numpy()
            counts = [sum(ctx.step.components[e].count for e in slots[i][1]) for i in chunk]
            turn = int(sample.tensors["turn"])
            dets = [
                dataclasses.replace(d, rotations=world_rotations(d.rotations, turn))
                for d in decode(out, counts, self.cfg, (w, h), change)
            ]
            types += [
                (slots[i][1], DetectedType(slots[i][1][0], ctx.components[slots[i][0]], c, d))
                for i, c, d in zip(chunk, counts, dets, strict=True)
            ]
        return types, change

    @torch.no_grad()
    def detections(
        self, ctx: StepContext
    ) -> tuple[list[tuple[list[int], DetectedType]], np.ndarray, Tone | None]:
        """The step's detections per component type (:meth:`detect`) with the picture and the
        tone mapping the change map was found with."""
        was_training = self.model.training
        self.model.eval()
        try:
            self._note_size(ctx)
            w, h = ctx.image_size
            picture = step_picture(ctx)
            # where the picture differs from the base shape (lines tolerated), at the image's
            # size; a non-square image: the change map of the network's (resized) input
            change, tone = step_change(ctx, picture) if self.use_change and w == h else (None, None)
            with one_thread():
                types, _ = self.detect(ctx, change)
            return types, picture, tone
        finally:
            self.model.train(was_training)

    def predict(self, ctx: StepContext) -> list[Prediction]:
        types, picture, tone = self.detections(ctx)
        w, h = ctx.image_size
        if self.lift == "keypoint":
            return share_out(ctx, lift_keypoints(ctx, [t for _, t in types]), types)
        return synthesize(
            ctx,
            [
                SynthesisType(
                    entry=e,
                    component=t.component,
                    count=ctx.step.components[e].count,
                    mask=t.detections.type_mask
                    if t.detections.type_mask is not None
                    else np.zeros((h, w), bool),
                    belief=t.detections.type_prob,
                    heat=t.detections.type_heat,
                )
                for entries, t in types
                for e in entries
            ],
            time_limit_s=self.time_limit_s,
            picture=picture,
            tone=tone,
        )


def share_out(
    ctx: StepContext, preds: list[Prediction], types: list[tuple[list[int], DetectedType]]
) -> list[Prediction]:
    """The keypoint lift's predictions of a component type handed to the callout entries that
    share it, as many as each entry's count, in order (the lift does not see colours)."""
    slots = {t.entry: entries for entries, t in types}
    left = {e: ctx.step.components[e].count for entries, _ in types for e in entries}
    out = []
    for p in preds:
        entry = next((e for e in slots[p.entry] if left[e] > 0), p.entry)
        left[entry] = left.get(entry, 0) - 1
        out.append(dataclasses.replace(p, entry=entry))
    return out
