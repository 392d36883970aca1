"""Pure decoding, from network outputs to :class:`TypeDetections`: heatmap peaks (3x3 max-pool NMS), the top
``count`` per component type (the manual states the counts), sub-cell offsets, rotation-class
probabilities at the peak, and instance masks by clustering the associative embeddings around
the peaks within the type's semantic mask."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from mepnet.detector.config import ModelConfig
from mepnet.detector.detections import TypeDetections
from mepnet.state import CHANGE_THRESHOLD

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
) -> list[TypeDetections]:
    """Detections per slot for one sample (batch of 1): keypoints and masks in pixels of
    ``image_size`` (W, H; an int for a square image).

    Masks: each pixel goes to the slot whose mask probability is highest there, then within the
    slot to the peak with the nearest associative embedding. With ``change`` (a square change
    map of the step, any resolution: :func:`mepnet.stage2.synthesis.step_change`), the pixels are those
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
        keypoints, rotations, centres = [], [], []
        for i in idx.tolist():
            y, x = divmod(i, n)
            dx, dy = out["offset"][0, s, :, y, x].tolist()
            rotations.append(torch.softmax(out["rotation"][0, s, :, y, x], 0).numpy())
            centres.append(emb_all[s, :, y, x])
            keypoints.append(((x + dx) * px, (y + dy) * py))
        if not keypoints:
            result.append(TypeDetections.empty(size))
            continue
        mine = support & (slot_of == s)
        emb = emb_all[s][:, rows[:, None], cols[None, :]]  # (d, H, W)
        dist = np.stack([((emb - c[:, None, None]) ** 2).sum(0) for c in centres])
        owner = dist.argmin(0)
        result.append(
            TypeDetections(
                keypoints=np.array(keypoints, dtype=np.float64),
                scores=scores.numpy().astype(np.float32),
                rotations=np.array(rotations, dtype=np.float32),
                masks=np.stack([mine & (owner == j) for j in range(len(keypoints))]),
                # what the slot's type as a whole looks like
                type_mask=support & plausible[s],
                type_prob=type_prob[s].astype(np.float32),
                type_heat=_resize_nearest(heat[s].numpy(), size).astype(np.float32),
            )
        )
    return result
