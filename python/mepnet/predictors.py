"""Predictors behind one interface: given a step's context (image, camera, base shape, the
components the step adds), return a pose for every instance.

- ``oracle``: 2D detections computed from ground truth (keypoints, rotation classes, visible
  masks from the instance map), then stage 2 — the upper bound of stage 2.
- ``oracle-noisy``: the same with Gaussian keypoint jitter of ``sigma`` pixels.
- ``abys``: pure analysis-by-synthesis (the paper's ablation): every valid pose of each
  component rasterized over the current shape and scored by mask IoU, with a per-component
  time limit.
- ``synthesis``: stage 2 by synthesis without a detector (:mod:`mepnet.lift`): the change
  between the picture and the rendered base shape, the callout colours and the geometry.

The detector (``mepnet``) and the Direct3D baseline plug in by subclassing :class:`Predictor`.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.data import ComponentRef, Step


@dataclass
class StepContext:
    """Everything a predictor may use for one step (ground truth only through ``truth``, which
    oracles read and real predictors must not)."""

    step: Step
    base: _bg.Assembly
    components: dict[ComponentRef, _bg.Component]
    image_size: tuple[int, int]
    truth: Any = None

    @property
    def camera(self) -> _bg.Camera:
        return self.step.camera_object()


@dataclass
class Prediction:
    """A predicted instance: its component type, and its pose or why there is none."""

    component: ComponentRef
    yaw: int | None
    t: tuple[int, int, int] | None
    attach: str | None = None
    failure: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)


class Predictor:
    """Base class: ``predict(ctx)`` returns one :class:`Prediction` per instance of the step."""

    name = "base"

    def predict(self, ctx: StepContext) -> list[Prediction]:
        raise NotImplementedError


def _gt_detections(
    ctx: StepContext, sigma: float, rng: np.random.Generator | None
) -> list[dict[str, Any]]:
    """Per component type, detections built from the ground truth of the step."""
    ids = ctx.step.ids()
    views = {v.id: v for v in ctx.step.views}
    types = []
    for sc in ctx.step.components:
        comp = ctx.components[sc.component]
        dets = []
        for iid in sc.instances:
            v = views[iid]
            inst = ctx.truth.instances[iid]
            kp = np.array(v.keypoints[0], dtype=float)
            if sigma > 0 and rng is not None:
                kp = kp + rng.normal(0.0, sigma, size=2)
            rot = np.zeros(7, dtype=np.float32)
            rot[_bg.rotation_class(comp.symmetry, inst.yaw)] = 1.0
            dets.append(
                {
                    "keypoint": (float(kp[0]), float(kp[1])),
                    "score": 1.0,
                    "rotation": rot.tolist(),
                    "mask": ids == iid,
                }
            )
        types.append(
            {"component": comp, "count": sc.count, "detections": dets, "ref": sc.component}
        )
    return types


#: Placements whose keypoint reprojects within this many pixels of the best one are compared by
#: mask IoU (then depth): about 2.5 sigma of a detector's keypoint error at 256 px.
TIE_PX = 2.5


def run_stage2(
    ctx: StepContext, types: list[dict[str, Any]], tie_px: float = TIE_PX
) -> list[Prediction]:
    """Stage 2 on per-type detections (each dict also carries its ``ref``)."""
    w, h = ctx.image_size
    out = _bg.infer_step(
        ctx.base,
        ctx.camera,
        w,
        h,
        [{k: t[k] for k in ("component", "count", "detections")} for t in types],
        tie_px=tie_px,
    )
    preds = []
    for p in out:
        ref = types[p["type"]]["ref"]
        preds.append(
            Prediction(
                component=ref,
                yaw=p["yaw"],
                t=tuple(p["t"]) if p["t"] is not None else None,
                attach=p["attach"],
                failure=p["failure"],
                extra={"error_px": p["error_px"], "iou": p["iou"]},
            )
        )
    return preds


class OraclePredictor(Predictor):
    """Ground-truth 2D detections (optionally with keypoint noise), then stage 2."""

    name = "oracle"

    def __init__(self, sigma: float = 0.0, seed: int = 0):
        self.sigma = float(sigma)
        self.seed = seed
        if self.sigma > 0:
            self.name = "oracle-noisy"

    def predict(self, ctx: StepContext) -> list[Prediction]:
        # noise drawn per step image (seed, manual, file), so a step gets the same jitter in
        # every mode and order of evaluation
        key = f"{ctx.step.image_path.parent.name}/{ctx.step.image_path.name}".encode()
        rng = np.random.default_rng([self.seed, zlib.crc32(key)])
        return run_stage2(ctx, _gt_detections(ctx, self.sigma, rng))


class AbysPredictor(Predictor):
    """Pure analysis-by-synthesis from ground-truth instance masks."""

    name = "abys"

    def __init__(self, time_limit_s: float = 60.0):
        self.time_limit_s = time_limit_s
        self.timeouts = 0

    def predict(self, ctx: StepContext) -> list[Prediction]:
        ids = ctx.step.ids()
        w, h = ctx.image_size
        items, refs = [], []
        for sc in ctx.step.components:
            for iid in sc.instances:
                items.append((ctx.components[sc.component], ids == iid))
                refs.append(sc.component)
        out = _bg.abys_step(ctx.base, ctx.camera, w, h, items, self.time_limit_s)
        preds = []
        for ref, (pose, iou, timed_out) in zip(refs, out, strict=True):
            self.timeouts += int(timed_out)
            preds.append(
                Prediction(
                    component=ref,
                    yaw=pose[0] if pose else None,
                    t=tuple(pose[1]) if pose else None,
                    failure=None if pose else "no valid placement",
                    extra={"iou": iou, "timed_out": timed_out},
                )
            )
        return preds


def bundled_weights() -> Path:
    """Path of the shipped slim detector weights."""
    return Path(str(resources.files("mepnet") / "data" / "weights" / "slim.safetensors"))


PREDICTORS = ("oracle", "oracle-noisy", "abys", "synthesis", "mepnet", "direct3d")


def make_predictor(
    name: str,
    sigma: float = 1.0,
    seed: int = 0,
    time_limit_s: float = 60.0,
    weights: str | Path | None = None,
    lift: str = "synthesis",
) -> Predictor:
    """A predictor by name (``mepnet`` takes ``weights``, a ``model.safetensors``; default: the
    shipped slim weights)."""
    if name == "oracle":
        return OraclePredictor(0.0, seed)
    if name == "oracle-noisy":
        return OraclePredictor(sigma, seed)
    if name == "abys":
        return AbysPredictor(time_limit_s)
    if name == "synthesis":
        from mepnet.lift import SynthesisPredictor

        return SynthesisPredictor(min(time_limit_s, 10.0))
    if name == "mepnet":
        from mepnet.checkpoint import load_predictor

        weights = str(weights or bundled_weights())
        if not Path(weights).is_file():
            raise ValueError(f"{weights}: detector weights not found")

        return load_predictor(weights, lift=lift)
    if name == "direct3d":
        raise ValueError(
            "predictor 'direct3d' (the Direct3D baseline) is not part of this build yet"
        )
    raise ValueError(f"unknown predictor '{name}' (choose from {', '.join(PREDICTORS)})")


def timed_predict(p: Predictor, ctx: StepContext) -> tuple[list[Prediction], float]:
    """Predict and measure wall time."""
    t0 = time.perf_counter()
    out = p.predict(ctx)
    return out, time.perf_counter() - t0
