"""The ``abys`` predictor: pure analysis-by-synthesis on the detector's predicted masks (the
paper's Table 3 ablation, "MEPNet (a-by-s)").

The detector (:meth:`mepnet.stage2.detector.MEPNetPredictor.detect`) gives each component
type of the step its mask: the pixels that changed from the base shape (the change map, as
the detector's decoding reads it) which the network's mask head gives to that type rather than
another. Then, for each component in turn (callout order, each type's instances one after
another): every valid pose -- 4 yaws x every stud, anti-stud and ground placement, collision
free, on the shape built so far -- is rasterized and scored by the IoU of its visible silhouette
with the type's mask less the pixels the components placed before it explain
(:func:`mepnet._brickgeom.abys_ranked`, in parallel); the best is placed. Each component has a
time limit (the paper's: 60 s), past which the best pose scored so far is taken and the
component counts as over the limit (``timeouts``; ``mepnet.eval`` reports the share).

No keypoints, no rotation classes, no colours: what sets it apart from ``mepnet`` (whose
stage 2 by synthesis also weighs the type beliefs, the keypoint heatmaps and the callout
colours, and picks the best component of all types at every turn) and from ``oracle-abys``
(the same search on the true instance masks).
"""

from __future__ import annotations

import numpy as np
import torch

from mepnet import _brickgeom as _bg
from mepnet.stage2.base import Prediction, Predictor, StepContext
from mepnet.stage2.detector import MEPNetPredictor
from mepnet.stage2.synthesis import step_change, step_picture


class AbysPredictor(Predictor):
    """Analysis-by-synthesis on the detector's per-type masks (module docstring)."""

    name = "abys"

    def __init__(self, detector: MEPNetPredictor, time_limit_s: float = 60.0):
        self.detector = detector
        self.time_limit_s = time_limit_s
        self.timeouts = 0

    @torch.no_grad()
    def predict(self, ctx: StepContext) -> list[Prediction]:
        model = self.detector.model
        was_training = model.training
        model.eval()
        try:
            return self._predict(ctx)
        finally:
            model.train(was_training)

    def _predict(self, ctx: StepContext) -> list[Prediction]:
        self.detector._note_size(ctx)
        w, h = ctx.image_size
        change = None
        if self.detector.use_change and w == h:
            change, _ = step_change(ctx, step_picture(ctx))
        types, _ = self.detector.detect(ctx, change)
        asm = ctx.base.copy()
        cam = ctx.camera
        explained = np.zeros((h, w), bool)
        preds: list[Prediction] = []
        for entries, t in types:
            dets = t.detections
            mask = dets.masks.any(axis=0) if len(dets) else np.zeros((h, w), bool)
            left = {e: ctx.step.components[e].count for e in entries}
            for _ in range(t.count):
                entry = next(e for e in entries if left[e] > 0)
                left[entry] -= 1
                ref = ctx.step.components[entry].component
                target = mask & ~explained
                if not target.any():  # all of it explained: the type's whole mask again
                    target = mask
                if not target.any():
                    preds.append(
                        Prediction(entry, ref, None, None, failure="the detector's mask is empty")
                    )
                    continue
                ranked, timed_out = _bg.abys_ranked(
                    asm, cam, w, h, t.component, target, 1, self.time_limit_s
                )
                self.timeouts += int(timed_out)
                if not ranked:
                    preds.append(
                        Prediction(
                            entry,
                            ref,
                            None,
                            None,
                            failure="no valid placement",
                            extra={"timed_out": timed_out},
                        )
                    )
                    continue
                yaw, tr, iou = ranked[0]
                new_id, attach = asm.add_checked(t.component, yaw, tr)
                explained |= _bg.render(asm, cam, w, h, line_px=0.0).ids == new_id
                preds.append(
                    Prediction(
                        entry,
                        ref,
                        yaw,
                        tr,
                        attach=attach,
                        extra={"iou": iou, "timed_out": timed_out},
                    )
                )
        return preds
