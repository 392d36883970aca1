"""The ``direct3d`` predictor: the paper's Direct3D baseline (§5.1; supplementary, "Baseline
models on LEGO datasets"). The network (:class:`mepnet.detector.net.Direct3DNet`) regresses
each instance's 3D translation and rotation class; stage 2 only quantises them with the
connection constraint (:func:`quantise`): the translation rounded to the lattice, then the
connected, collision-free placement nearest to the regressed translation within the paper's
neighbourhood of the rounded one. No keypoint lift, no mask, no synthesis.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch

from mepnet import _brickgeom as _bg
from mepnet.detector.config import ModelConfig
from mepnet.detector.direct3d import decode_direct3d, world_translation
from mepnet.detector.net import Direct3DNet
from mepnet.detector.targets import collate, component_slots, make_sample, world_rotations
from mepnet.geom import ATTACH_KINDS, LDU_PER_CELL
from mepnet.stage2.base import Prediction, Predictor, StepContext
from mepnet.stage2.synthesis import step_change, step_picture
from mepnet.threads import one_thread

#: The neighbourhood searched around the rounded translation, in lattice cells (x, y, z): the
#: paper's offsets {0, +-0.5, +-1} in units of a 1x1x1 brick are +-2 half-studs across and +-3
#: plates (one brick) up and down on our finer lattice.
NEIGHBOURHOOD = (2, 3, 2)

#: The yaw (0..3) each rotation class stands for (class 0: 4-fold symmetric; 1, 2: 2-fold at
#: 0 / 90 degrees; 3..6: no symmetry, 0..270 degrees), and the classes a component of each
#: symmetry order can take.
YAW_OF_CLASS = (0, 0, 1, 0, 1, 2, 3)
CLASSES_OF_SYMMETRY = {4: (0,), 2: (1, 2), 1: (3, 4, 5, 6)}


def _offsets(radius: tuple[int, int, int]) -> np.ndarray:
    """Every offset within ``radius``, nearest (in LDU) first, then in lexicographic order: the
    search order, so ties go to the smaller move."""
    rx, ry, rz = radius
    offs = np.array(
        list(itertools.product(range(-rx, rx + 1), range(-ry, ry + 1), range(-rz, rz + 1))),
        dtype=np.int64,
    )
    d = ((offs * LDU_PER_CELL) ** 2).sum(axis=1)
    return offs[np.lexsort((offs[:, 2], offs[:, 1], offs[:, 0], d))]


def quantise(
    asm: _bg.Assembly,
    component: _bg.Component,
    yaw: int,
    t: np.ndarray,
    radius: tuple[int, int, int] = NEIGHBOURHOOD,
) -> tuple[tuple[int, int, int], str] | None:
    """The valid placement (connected by studs, from below or on the ground, and free of
    collisions) of ``component`` at ``yaw`` nearest in LDU to the regressed translation ``t``
    (lattice cells, fractional) within ``radius`` cells of its rounding, with how it attaches;
    None when there is none (the paper then keeps the invalid rounded translation; we report
    the component as not placed)."""
    t = np.asarray(t, dtype=np.float64)
    if t.shape != (3,) or not np.isfinite(t).all():
        return None
    rounded = np.rint(t).astype(np.int64)
    cands = rounded + _offsets(radius)
    poses = np.concatenate([np.full((len(cands), 1), yaw % 4, np.int64), cands], axis=1)
    codes = asm.check_many(component, poses)
    ok = np.flatnonzero(codes >= 0)
    if len(ok) == 0:
        return None
    dist = (((cands[ok] - t) * LDU_PER_CELL) ** 2).sum(axis=1)
    best = ok[int(np.argmin(dist))]  # first of equals: the smaller move (_offsets' order)
    x, y, z = (int(v) for v in cands[best])
    return (x, y, z), ATTACH_KINDS[int(codes[best])]


def class_yaw(component: _bg.Component, rotations: np.ndarray) -> int:
    """The yaw of the most probable rotation class the component's symmetry allows."""
    allowed = CLASSES_OF_SYMMETRY.get(component.symmetry, tuple(range(7)))
    best = max(allowed, key=lambda c: float(rotations[c]))
    return YAW_OF_CLASS[best]


class Direct3DPredictor(Predictor):
    """Direct3D's regressed poses, quantised with the connection constraint (the ``direct3d``
    predictor)."""

    name = "direct3d"

    def __init__(self, model: Direct3DNet, cfg: ModelConfig, use_change: bool = True):
        self.model = model
        self.cfg = cfg
        self.use_change = use_change

    @torch.no_grad()
    def predict(self, ctx: StepContext) -> list[Prediction]:
        was_training = self.model.training
        self.model.eval()
        try:
            with one_thread():
                return self._predict(ctx)
        finally:
            self.model.train(was_training)

    def _predict(self, ctx: StepContext) -> list[Prediction]:
        w, h = ctx.image_size
        # the network's inputs exactly as the detector's (the change map among them)
        change = step_change(ctx, step_picture(ctx))[0] if self.use_change and w == h else None
        slots = component_slots(ctx.step)
        found = []  # (score, slot, translation, rotations, centre px), the manual's world
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
            turn = int(sample.tensors["turn"])
            counts = [sum(ctx.step.components[e].count for e in slots[i][1]) for i in chunk]
            for i, dets in zip(chunk, decode_direct3d(out, counts, self.cfg, (w, h)), strict=True):
                for j in range(len(dets)):
                    found.append(
                        (
                            float(dets.scores[j]),
                            i,
                            world_translation(dets.translations[j], turn),
                            world_rotations(dets.rotations[j], turn),
                            dets.keypoints[j],
                        )
                    )
        # the most confident instance first, each quantised on the shape with the ones before
        found.sort(key=lambda f: -f[0])
        asm = ctx.base.copy()
        left = {e: ctx.step.components[e].count for _, entries in slots for e in entries}
        preds = []
        for score, i, t, rot, kp in found:
            ref, entries = slots[i]
            comp = ctx.components[ref]
            entry = next((e for e in entries if left[e] > 0), entries[0])
            left[entry] -= 1
            yaw = class_yaw(comp, rot)
            extra = {"score": score, "regressed": [float(v) for v in t], "keypoint": kp.tolist()}
            q = quantise(asm, comp, yaw, t)
            if q is None:
                preds.append(
                    Prediction(
                        entry,
                        ref,
                        None,
                        None,
                        failure="no connected, collision-free placement near the regressed pose",
                        extra=extra,
                    )
                )
                continue
            tr, attach = q
            asm.add(comp, yaw, tr)
            preds.append(Prediction(entry, ref, yaw, tr, attach=attach, extra=extra))
        for e, n in left.items():  # (the decoder gives every stated instance; to be safe)
            ref = ctx.step.components[e].component
            preds += [Prediction(e, ref, None, None, failure="not detected") for _ in range(n)]
        return preds
