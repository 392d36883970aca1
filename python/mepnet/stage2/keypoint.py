"""The paper's stage 2: detections lifted to 3D through the connection constraint.

For each detected keypoint, brickgeom walks the camera ray and keeps the placements whose
keypoint reprojects within a few pixels and that connect to the base by studs or stand on the
ground; rotation from the detector's class probabilities (and, with masks, the silhouette IoU);
instances placed one after another so that the step stays collision-free
(:func:`mepnet._brickgeom.infer_step`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.detector.detections import TypeDetections
from mepnet.stage2.base import Prediction, StepContext

#: Placements whose keypoint reprojects within this many pixels of the best one are compared by
#: mask IoU (then depth): about 2.5 sigma of a detector's keypoint error at 256 px.
TIE_PX = 2.5


@dataclass(frozen=True)
class DetectedType:
    """One callout entry of a step with its detections."""

    entry: int
    component: _bg.Component
    count: int
    detections: TypeDetections


def lift_keypoints(
    ctx: StepContext, types: list[DetectedType], tie_px: float = TIE_PX
) -> list[Prediction]:
    """Stage 2 on per-type detections: one :class:`Prediction` per instance."""
    w, h = ctx.image_size
    out = _bg.infer_step(
        ctx.base,
        ctx.camera,
        w,
        h,
        [
            _bg.StepDetections(
                t.component,
                t.count,
                np.ascontiguousarray(t.detections.keypoints, np.float64),
                np.ascontiguousarray(t.detections.scores, np.float32),
                np.ascontiguousarray(t.detections.rotations, np.float32),
                np.ascontiguousarray(t.detections.masks, bool),
            )
            for t in types
        ],
        tie_px=tie_px,
    )
    preds = []
    for p in out:
        entry = types[p.type].entry
        preds.append(
            Prediction(
                entry=entry,
                component=ctx.step.components[entry].component,
                yaw=p.yaw,
                t=p.t,
                attach=p.attach,
                failure=p.failure,
                extra={"error_px": p.error_px, "iou": p.iou},
            )
        )
    return preds
