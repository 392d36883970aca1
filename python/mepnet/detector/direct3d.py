"""Direct3D (the paper's second baseline, §5.1 and supplementary): targets and pure decoding.
The network is :class:`mepnet.detector.net.Direct3DNet` (the detector's encoders and
hourglass, heads that regress each instance's 3D translation and rotation, CoordConv), its
objective :func:`mepnet.detector.losses.direct3d_loss`; quantisation with the connection
constraint and the predictor are :mod:`mepnet.stage2.direct3d`.

Translations are lattice cells (x, z half-studs, y plates) of the component origin in the
network's world: the manual's world turned to the canonical view
(:func:`mepnet.detector.targets.canonical_turn`), as the base shape and the camera it is shown;
:func:`world_translation` turns a prediction back.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from mepnet.detector.config import ModelConfig
from mepnet.detector.targets import MAX_INSTANCES, StepSample, component_slots
from mepnet.manual import Step, StepTruth


def turned_translation(t: tuple[float, float, float] | np.ndarray, turn: int) -> np.ndarray:
    """A lattice translation turned by ``turn`` quarter turns about +y, as
    :func:`mepnet.geom.rotate_lattice` (fractional cells allowed)."""
    x, y, z = (float(v) for v in t)
    return np.array([(x, y, z), (z, y, -x), (-x, y, -z), (-z, y, x)][turn % 4])


def world_translation(t: np.ndarray, turn: int) -> np.ndarray:
    """A translation predicted in the network's (turned) world, in the manual's world."""
    return turned_translation(t, (4 - turn % 4) % 4)


def add_translation_targets(
    sample: StepSample, step: Step, truth: StepTruth, cfg: ModelConfig
) -> StepSample:
    """``sample`` (from :func:`mepnet.detector.targets.make_sample` with ``truth``, its slots the
    first K_max component types) with ``inst_translation`` (MAX_INSTANCES, 3): each instance's
    true translation in the turned world, in the order of its other per-instance targets."""
    turn = int(sample.tensors["turn"])
    out = np.zeros((MAX_INSTANCES, 3), np.float32)
    slot_of = np.zeros(MAX_INSTANCES, np.int64)
    k = 0
    for s, (_, entries) in enumerate(component_slots(step)[: cfg.k_max]):
        for iid in (i for e in entries for i in truth.instances_of[e]):
            if k >= MAX_INSTANCES:
                break
            out[k] = turned_translation(truth.instances[iid].t, turn)
            slot_of[k] = s
            k += 1
    valid = sample.tensors["inst_valid"].numpy()
    if k != int(valid.sum()) or (slot_of[:k] != sample.tensors["inst_slot"].numpy()[:k]).any():
        raise ValueError(f"{step.where}: Direct3D targets do not follow the sample's instances")
    sample.tensors["inst_translation"] = torch.from_numpy(out)
    return sample


@dataclass(frozen=True)
class Direct3DDetections:
    """Direct3D's instances of one component type, best score first: ``keypoints`` (N, 2) the
    centre cells in pixels, ``scores`` (N,), ``translations`` (N, 3) lattice cells of the
    network's (turned) world, ``rotations`` (N, 7) rotation-class probabilities (turned world)."""

    keypoints: np.ndarray
    scores: np.ndarray
    translations: np.ndarray
    rotations: np.ndarray

    def __len__(self) -> int:
        return len(self.scores)


def decode_direct3d(
    out: dict[str, torch.Tensor],
    counts: list[int],
    cfg: ModelConfig,
    image_size: tuple[int, int],
) -> list[Direct3DDetections]:
    """Per slot of one sample (batch of 1), the ``count`` strongest centre peaks (3x3 max-pool
    NMS) with the translation and rotation read there; ``image_size`` (W, H) for the pixels."""
    heat = torch.sigmoid(out["heatmap"][0])  # (K, h, w)
    peaks = heat * (F.max_pool2d(heat[None], 3, 1, 1)[0] == heat)
    h, w = heat.shape[1:]
    sx, sy = image_size[0] / w, image_size[1] / h
    result = []
    for s, count in enumerate(counts[: cfg.k_max]):
        flat = peaks[s].flatten()
        k = min(max(count, 0), flat.numel())
        scores, idx = flat.topk(k)
        ys, xs = idx // w, idx % w
        trans = out["translation"][0, s][:, ys, xs].T  # (k, 3)
        rot = torch.softmax(out["rotation"][0, s][:, ys, xs].T, dim=1)  # (k, 7)
        cells = np.stack([xs.numpy(), ys.numpy()], axis=1).reshape(-1, 2) + 0.5
        result.append(
            Direct3DDetections(
                keypoints=cells * np.array([sx, sy]),
                scores=scores.numpy().astype(np.float32),
                translations=trans.double().numpy(),
                rotations=rot.float().numpy(),
            )
        )
    return result
