"""Detections as a typed container (as detectron2's ``Instances``): what the detector (or an
oracle) says about one component type of a step. Per-type arrays are stored once; per-instance
arrays have the instances along their first axis."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TypeDetections:
    """The detections of one component type (one callout entry) of a step.

    Per instance (N of them, best score first): ``keypoints`` (N, 2) float64 pixels,
    ``scores`` (N,) float32, ``rotations`` (N, 7) float32 rotation-class probabilities,
    ``masks`` (N, H, W) bool instance masks. Per type (None where the source has none):
    ``type_mask`` (H, W) bool, the pixels that may show the type; ``type_prob`` (H, W) float32,
    the belief that a pixel shows it; ``type_heat`` (H, W) float32, the keypoint heatmap."""

    keypoints: np.ndarray
    scores: np.ndarray
    rotations: np.ndarray
    masks: np.ndarray
    type_mask: np.ndarray | None = None
    type_prob: np.ndarray | None = None
    type_heat: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.keypoints)
        if self.keypoints.shape != (n, 2) or self.scores.shape != (n,):
            raise ValueError("keypoints must be (N, 2) and scores (N,)")
        if self.rotations.shape != (n, 7) or self.masks.ndim != 3 or len(self.masks) != n:
            raise ValueError("rotations must be (N, 7) and masks (N, H, W)")

    def __len__(self) -> int:
        return len(self.keypoints)

    @classmethod
    def empty(cls, size: tuple[int, int]) -> TypeDetections:
        """No detections, for an image of ``size`` (W, H)."""
        w, h = size
        return cls(
            keypoints=np.zeros((0, 2)),
            scores=np.zeros(0, np.float32),
            rotations=np.zeros((0, 7), np.float32),
            masks=np.zeros((0, h, w), bool),
        )
