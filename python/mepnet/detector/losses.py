"""The training objective (paper §4.1): L = 1 * (focal heatmap + L1 offset)
+ 1 * (mask cross-entropy + associative-embedding pull/push) + 0.1 * rotation cross-entropy.
Only the slots a step uses count.

Direct3D (``ModelConfig.head == "direct3d"``; supplementary: L_keypoint and L_mask replaced by
L_trans, weight 1): focal heatmap (it only says where an instance's translation and rotation are
read) + L1 on the translation in units of :data:`mepnet.detector.net.TRANSLATION_NORM` lattice
cells + 0.1 * rotation cross-entropy."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from mepnet.detector.config import ModelConfig
from mepnet.detector.net import TRANSLATION_NORM

WEIGHTS = {"keypoint": 1.0, "mask": 1.0, "rotation": 0.1}
#: Direct3D's weights (the supplementary's: L_trans weight 1).
DIRECT3D_WEIGHTS = {"heatmap": 1.0, "translation": 1.0, "rotation": 0.1}


def focal_loss(logits: torch.Tensor, target: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss on Gaussian targets; ``valid`` (B, K) masks slots."""
    p = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    pos = target.ge(0.999).float()
    neg = 1 - pos
    pos_loss = torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = torch.log(1 - p) * p**2 * (1 - target) ** 4 * neg
    v = valid[:, :, None, None]
    n_pos = (pos * v).sum().clamp(min=1.0)
    return -((pos_loss + neg_loss) * v).sum() / n_pos


def _gather(x: torch.Tensor, slot: torch.Tensor, cell: torch.Tensor) -> torch.Tensor:
    """x: (B, K, C, h, w); per instance (B, M) slot and (B, M, 2) cell -> (B, M, C)."""
    b, _, c, h, w = x.shape
    m = slot.shape[1]
    bi = torch.arange(b, device=x.device)[:, None].expand(b, m)
    return x[bi, slot, :, cell[..., 1].clamp(0, h - 1), cell[..., 0].clamp(0, w - 1)]


def embedding_loss(
    emb: torch.Tensor,
    inst_map: torch.Tensor,
    inst_slot: torch.Tensor,
    inst_valid: torch.Tensor,
    margin: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Associative embedding: pull each instance's pixels to their mean (in its slot's
    channels), push the means of instances of one slot at least ``margin`` apart."""
    b, k, d, h, w = emb.shape
    pull = emb.new_zeros(())
    push = emb.new_zeros(())
    n_pull = n_push = 0
    for i in range(b):
        means: dict[int, list[torch.Tensor]] = {}
        for j in torch.nonzero(inst_valid[i] > 0).flatten().tolist():
            pix = inst_map[i] == j + 1
            if not pix.any():
                continue
            s = int(inst_slot[i, j])
            e = emb[i, s][:, pix]  # (d, n)
            mu = e.mean(dim=1)
            pull = pull + ((e - mu[:, None]) ** 2).sum(0).mean()
            n_pull += 1
            means.setdefault(s, []).append(mu)
        for mus in means.values():
            for a in range(len(mus)):
                for c in range(a + 1, len(mus)):
                    dist = torch.linalg.vector_norm(mus[a] - mus[c])
                    push = push + F.relu(margin - dist) ** 2
                    n_push += 1
    return pull / max(n_pull, 1), push / max(n_push, 1)


def total_loss(
    out: dict[str, torch.Tensor], batch: dict[str, torch.Tensor], cfg: ModelConfig
) -> tuple[torch.Tensor, dict[str, float]]:
    """The weighted sum and its parts (floats, for logging)."""
    if cfg.head == "direct3d":
        return direct3d_loss(out, batch)
    valid = batch["comp_valid"]
    inst_valid = batch["inst_valid"]
    n_inst = inst_valid.sum().clamp(min=1.0)
    heat = focal_loss(out["heatmap"], batch["heatmap"], valid)
    off_pred = _gather(out["offset"], batch["inst_slot"], batch["inst_cell"])  # (B, M, 2)
    offset = (
        F.l1_loss(off_pred, batch["inst_offset"], reduction="none").sum(-1) * inst_valid
    ).sum() / n_inst
    seg = F.binary_cross_entropy_with_logits(out["mask"], batch["seg"], reduction="none")
    seg = (seg * valid[:, :, None, None]).sum() / (
        valid.sum().clamp(min=1.0) * seg.shape[-1] * seg.shape[-2]
    )
    pull, push = embedding_loss(out["embedding"], batch["inst_map"], batch["inst_slot"], inst_valid)
    rot_logits = _gather(out["rotation"], batch["inst_slot"], batch["inst_cell"])  # (B, M, 7)
    rot = (
        F.cross_entropy(rot_logits.flatten(0, 1), batch["inst_rot"].flatten(), reduction="none")
        * inst_valid.flatten()
    ).sum() / n_inst
    loss = (
        WEIGHTS["keypoint"] * (heat + offset)
        + WEIGHTS["mask"] * (seg + pull + push)
        + WEIGHTS["rotation"] * rot
    )
    parts = {
        "heatmap": heat,
        "offset": offset,
        "mask": seg,
        "pull": pull,
        "push": push,
        "rotation": rot,
    }
    return loss, {k: float(v.detach()) for k, v in parts.items()}


def _rotation_loss(out: torch.Tensor, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Rotation cross-entropy at the instances' centre cells, averaged over instances."""
    inst_valid = batch["inst_valid"]
    logits = _gather(out, batch["inst_slot"], batch["inst_cell"])  # (B, M, 7)
    ce = F.cross_entropy(logits.flatten(0, 1), batch["inst_rot"].flatten(), reduction="none")
    return (ce * inst_valid.flatten()).sum() / inst_valid.sum().clamp(min=1.0)


def direct3d_loss(
    out: dict[str, torch.Tensor], batch: dict[str, torch.Tensor]
) -> tuple[torch.Tensor, dict[str, float]]:
    """Direct3D's objective (module docstring); ``batch`` needs ``inst_translation``
    (:func:`mepnet.detector.direct3d.add_translation_targets`)."""
    inst_valid = batch["inst_valid"]
    n_inst = inst_valid.sum().clamp(min=1.0)
    heat = focal_loss(out["heatmap"], batch["heatmap"], batch["comp_valid"])
    pred = _gather(out["translation"], batch["inst_slot"], batch["inst_cell"])  # (B, M, 3)
    err = F.l1_loss(pred, batch["inst_translation"], reduction="none").sum(-1) / TRANSLATION_NORM
    trans = (err * inst_valid).sum() / n_inst
    rot = _rotation_loss(out["rotation"], batch)
    w = DIRECT3D_WEIGHTS
    loss = w["heatmap"] * heat + w["translation"] * trans + w["rotation"] * rot
    parts = {"heatmap": heat, "translation": trans, "rotation": rot}
    return loss, {k: float(v.detach()) for k, v in parts.items()}
