"""Evaluation of a predictor on manual folders (synthetic or converted from real models).

    python -m mepnet.eval --data DIR --predictor {mepnet,synthesis,abys,direct3d,oracle,...}
                          [--json FILE] [--autoregressive] [--sigma PX] [--weights W]
                          [--time-limit S]

Metrics (paper §5.1), written as JSON with the keys of DESIGN §8:

- ``component_acc`` / ``step_acc``: exact pose equality on the lattice (rotation modulo the
  component's symmetry: two poses are equal when they place identical geometry), given the
  ground-truth base shape and submodules. Within a component type, predictions are matched to
  ground-truth instances: exact matches first, the rest by Hungarian matching on Chamfer
  distance. A step is correct when all of its components are.
- ``component_cd`` / ``step_cd``: Chamfer distance (sum of the two mean squared nearest-point
  distances) between 10,000 points sampled on the predicted and ground-truth meshes, both
  scaled so the ground-truth final shape of the build has a bounding-box diagonal of 1,
  reported x1e5 as the paper does. An exactly correct pose counts 0; an instance the predictor
  could not place is left out of the CD means and counted in ``n_failures``.
- ``set_cd`` (with ``--autoregressive``): submodules are built by the predictor first, then the
  main model step by step on its own predictions; CD between the final predicted and
  ground-truth shapes (same scaling).
- ``autoregressive_component_acc`` / ``manuals_exact`` (with ``--autoregressive``): what a user
  gets from ``mepnet.infer``: the share of components placed exactly when every step is built
  on the predictor's own earlier placements, and the share of manuals whose final model is
  exactly right (parts, colours and placements, submodules expanded).
- ``undetermined_components`` / ``component_acc_pictures`` and ``manuals_drawn_alike`` (with
  ``--autoregressive``): what no picture of the manual can tell apart. A wrong step is
  *undetermined* when its prediction, put in place of the truth, changes no picture of the
  build from that step on (drawn by mepnet's renderer with the manual's cameras: e.g. a side
  stud turned where every picture hides it); ``component_acc_pictures`` counts the components of
  such steps as right. A plan is *drawn alike* when every step's predicted shape gives the
  truth's picture (``manuals_drawn_alike``: the share of manuals). Both are reported beside the
  strict figures, never in their place.
- ``camera_undecidable_components`` (with ``--camera estimated``): components of the wrong
  steps (not undetermined) whose prediction, drawn with the camera the step estimated, gives the
  step's picture as the truth gives it with the manual's camera (a part wholly hidden under
  the new one: where the new one sits on it no picture without a camera can tell). Reported
  beside the strict figure, never in its place.
- ``mtc``: mistakes to complete, the fraction of steps with a wrong prediction given the
  ground-truth base (averaged over manuals).
- ``seconds_per_step``: the predictor's wall time per step (detection + stage 2).
- ``n_timeouts`` / ``timeout_share`` (predictors with a per-component time limit: ``abys``,
  ``oracle-abys``): components whose search hit the limit in the teacher-forced run, as a count
  and as a share of the components (the paper's TLE).
- ``over_budget_steps``: steps whose stage 2 ran out of its time budget (the greedy's first
  solution kept, nothing revisited: ``mepnet.stage2.synthesis.STEP_BUDGET_S``), with where
  they are per manual (``over_budget``). The budget is CPU time, so other jobs on the machine
  do not change it, but a slower CPU may hit it more often; a figure with none is unaffected.
- ``submodule_component_acc`` / ``submodule_component_cd``: the same, over submodule components.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet import metrics
from mepnet.cameras import drop_cameras
from mepnet.cli import ArgumentParser
from mepnet.cli import run as run_cli
from mepnet.errors import ConfigError, ManualFormatError
from mepnet.files import atomic_write_json, check_output_file
from mepnet.frames import moved, symmetries
from mepnet.geom import BrickGeomError
from mepnet.manual import ComponentRef, answers_of, iter_manual_dirs, load_manual
from mepnet.plan import (
    accuracy,
    built_exactly,
    frame_free,
    predicted_placements,
    run_manual,
    same_shape,
    step_matches,
    step_motion,
)
from mepnet.stage2 import LIFTS, PREDICTORS, Prediction, Predictor, make_predictor
from mepnet.stage2.synthesis import DRAWN_LEVEL, drawn_differ

#: The ``written_by`` mark of the metrics files ``--json`` writes (and may replace).
WRITER = "mepnet.eval"

Placement = tuple[_bg.Component, int, tuple[int, int, int]]


def _diag(placements: Sequence[Placement]) -> float:
    v, _ = metrics.union_mesh(placements)
    return float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) or 1.0


class Scorer:
    """Accumulates step results."""

    def __init__(self, cd_points: int):
        self.cd_points = cd_points
        self.components = 0
        self.correct = 0
        self.steps = 0
        self.steps_correct = 0
        self.failures = 0
        self.comp_cd: list[float] = []
        self.step_cd: list[float] = []
        self.sub_components = 0
        self.sub_correct = 0
        self.sub_cd: list[float] = []
        self.seconds: list[float] = []
        self.supported = 0
        self.supported_correct = 0

    def cd(self, pred: Sequence[Placement], gt: Sequence[Placement], scale: float) -> float:
        pred, gt = _canonical(pred, gt)
        return metrics.chamfer(
            metrics.union_mesh(pred), metrics.union_mesh(gt), n=self.cd_points, scale=scale
        )

    def step(
        self,
        preds: list[Prediction],
        gt: list[tuple[ComponentRef, int, tuple[int, int, int]]],
        comps: dict[ComponentRef, _bg.Component],
        scale: float,
        supported: list[bool] | None = None,
    ) -> bool:
        """Score one step; returns whether it is entirely correct. ``supported`` flags, per
        ground-truth instance, whether it is connected to the base (converted real models keep
        parts that rest on dropped ones; no connection-based method can place those)."""
        all_ok = True
        if supported is not None:
            for (ref, y, t), sup in zip(gt, supported, strict=True):
                if sup:
                    self.supported += 1
                    self.supported_correct += int(
                        any(
                            x.component == ref
                            and x.t is not None
                            and comps[ref].same_shape(y, t, x.yaw, x.t)
                            for x in preds
                        )
                    )
        step_pred: list[Placement] = []
        for ref in dict.fromkeys(r for r, _, _ in gt):
            comp = comps[ref]
            g = [(y, t) for r, y, t in gt if r == ref]
            p = [(x.yaw, x.t) for x in preds if x.component == ref and x.t is not None]
            self.failures += sum(1 for x in preds if x.component == ref and x.t is None)
            step_pred += [(comp, y, t) for y, t in p]
            # exact matches first
            used_p: set[int] = set()
            unmatched_g = []
            for gy, gt_t in g:
                j = next(
                    (
                        j
                        for j, (py, pt) in enumerate(p)
                        if j not in used_p and comp.same_shape(gy, gt_t, py, pt)
                    ),
                    None,
                )
                if j is None:
                    unmatched_g.append((gy, gt_t))
                else:
                    used_p.add(j)
                    self.comp_cd.append(0.0)
            ok = len(g) - len(unmatched_g)
            type_cd = [0.0] * ok
            rest_p = [p[j] for j in range(len(p)) if j not in used_p]
            if unmatched_g and rest_p:
                for i, j in metrics.match_instances(
                    rest_p, unmatched_g, lambda a, b, c=comp: self.cd([(c, *a)], [(c, *b)], scale)
                ):
                    type_cd.append(self.cd([(comp, *rest_p[i])], [(comp, *unmatched_g[j])], scale))
            self.comp_cd += type_cd
            self.components += len(g)
            self.correct += ok
            if ref.submodule is not None:
                self.sub_components += len(g)
                self.sub_correct += ok
                self.sub_cd += type_cd
            all_ok &= ok == len(g)
        gt_pl = [(comps[r], y, t) for r, y, t in gt]
        self.step_cd.append(
            0.0 if all_ok else (self.cd(step_pred, gt_pl, scale) if step_pred else float("nan"))
        )
        self.steps += 1
        self.steps_correct += int(all_ok)
        return all_ok


#: What went wrong with a true instance the predictor did not place exactly (``per_manual``).
ERROR_KINDS = ("unsupported", "not_placed", "rotation", "near", "far")


def error_kinds(
    preds: list[Prediction],
    gt: list[tuple[ComponentRef, int, tuple[int, int, int]]],
    comps: dict[ComponentRef, _bg.Component],
    supported: list[bool],
) -> dict[str, int]:
    """Counts, per kind of :data:`ERROR_KINDS`, the true instances of one step that no
    prediction places exactly: ``unsupported`` (it rests only on parts dropped from a converted
    real model: no connection-based method can place it), ``not_placed`` (no prediction of its
    type left), ``rotation`` (a prediction of its type at its translation, turned wrongly),
    ``near`` (the nearest prediction of its type within one stud across and one brick up or
    down) and ``far``. Instances and predictions are paired exactly first, as the score does,
    then each instance left with the nearest prediction of its type left."""
    kinds = dict.fromkeys(ERROR_KINDS, 0)
    for ref in dict.fromkeys(r for r, _, _ in gt):
        comp = comps[ref]
        rest = [(x.yaw, x.t) for x in preds if x.component == ref and x.t is not None]
        missed = []
        for (r, y, t), sup in zip(gt, supported, strict=True):
            if r != ref:
                continue
            j = next((j for j, (py, pt) in enumerate(rest) if comp.same_shape(y, t, py, pt)), None)
            if j is None:
                missed.append((y, t, sup))
            else:
                rest.pop(j)
        kinds["unsupported"] += sum(1 for _, _, sup in missed if not sup)
        missed = [(y, t) for y, t, sup in missed if sup]
        # each missed instance paired with the nearest prediction left (closest pairs first)
        pairs = sorted(
            (sum((a - b) ** 2 for a, b in zip(t, pt, strict=True)), i, j)
            for i, (_, t) in enumerate(missed)
            for j, (_, pt) in enumerate(rest)
        )
        partner: dict[int, tuple[int, int, int]] = {}
        taken: set[int] = set()
        for _, i, j in pairs:
            if i not in partner and j not in taken:
                partner[i] = tuple(rest[j][1])
                taken.add(j)
        for i, (_, t) in enumerate(missed):
            pt = partner.get(i)
            if pt is None:
                kinds["not_placed"] += 1
            elif tuple(pt) == tuple(t):
                kinds["rotation"] += 1
            elif abs(pt[0] - t[0]) <= 2 and abs(pt[2] - t[2]) <= 2 and abs(pt[1] - t[1]) <= 3:
                kinds["near"] += 1
            else:
                kinds["far"] += 1
    return kinds


def _same_shape(a: _bg.Component, b: _bg.Component) -> bool:
    """Whether two components are the same shape (a part: the same part; a submodule: the same
    bricks, whatever their order or the yaws of symmetric parts)."""
    if a.name != b.name or a.is_submodule != b.is_submodule:
        return False
    if not a.is_submodule or a is b or a.bricks == b.bricks:
        return True
    return same_shape([(a, 0, (0, 0, 0), 16)], [(b, 0, (0, 0, 0), 16)])


def _canonical(
    pred: Sequence[Placement], gt: Sequence[Placement]
) -> tuple[list[Placement], list[Placement]]:
    """Predicted placements equal to a ground-truth one (modulo symmetry) replaced by it, and
    both lists in one order, so identical shapes sample identical points (CD exactly 0)."""
    used: set[int] = set()
    out = []
    for c, y, t in pred:
        j = next(
            (
                j
                for j, (gc, gy, gt_t) in enumerate(gt)
                if j not in used
                and _same_shape(gc, c)  # a predicted submodule may differ from the true one
                and c.same_shape(y, t, gy, gt_t)
            ),
            None,
        )
        if j is None:
            out.append((c, y, t))
        else:
            used.add(j)
            out.append(gt[j])

    def key(p: Placement) -> tuple[str, int, tuple[int, int, int]]:
        return (p[0].name, p[1], p[2])

    return sorted(out, key=key), sorted(gt, key=key)


#: Where the cameras come from: the manual (``given``) or the pictures (``estimated``).
CAMERAS = ("given", "estimated")
#: An estimated camera whose mean reprojection error exceeds this many pixels is listed per
#: manual (``camera_off``: step -> [degrees, pixels]; None where no camera was estimated).
CAMERA_OFF_PX = 1.0


def _camera_errors(man: Any, run: Any, b: Any, s: Any) -> tuple[float, float] | None:
    """Rotation error (degrees) and mean reprojection error (pixels) of the true shape's voxel
    corners after the step, of a step's estimated camera against the manual's, in the truth's
    frame (the step's motion undone); None when the step has no estimate or no true camera."""
    if s.camera is None or s.camera.source != "estimated" or s.camera.camera is None:
        return None
    page = (man.main if b.key is None else man.submodules[b.key]).steps[s.index - 1]
    if page.camera is None:
        return None
    true_cam = page.camera_object()
    answers = answers_of(man).build(b.key)
    shape = answers.assembly_before(s.index, run.components)
    occ, origin = shape.occupancy()
    cells = np.argwhere(occ > 0) + np.asarray(origin)
    if len(cells) == 0:
        return None
    corners = np.unique(
        np.concatenate([cells + d for d in np.ndindex(2, 2, 2)]), axis=0
    ) * np.array([10.0, 8.0, 10.0])
    motion = step_motion(run, b, s)
    motions = [motion]
    if s.index == 1:  # a symmetric first shape is aligned as well by its symmetries
        motions += [motion.after(m) for m in symmetries(predicted_placements(run, s))]
    est = s.camera.camera
    w, h = man.image_size
    pt, _ = true_cam.project(corners, w, h)
    best: tuple[float, float] | None = None
    for m in motions:
        back = m.inverse()  # truth frame -> the estimate's frame
        turn = back.yaw_matrix()
        in_est = corners @ turn.T + np.asarray(back.shift) * np.array([10.0, 8.0, 10.0])
        pe, _ = est.project(in_est, w, h)
        reproj = float(np.linalg.norm(pe - pt, axis=1).mean())
        r = np.asarray(est.rotation()) @ turn @ np.asarray(true_cam.rotation()).T
        rot = math.degrees(math.acos(max(-1.0, min(1.0, (float(np.trace(r)) - 1.0) / 2.0))))
        if best is None or reproj < best[1]:
            best = (rot, reproj)
    return best


def evaluate(
    data: str | os.PathLike[str],
    predictor: Predictor,
    autoregressive: bool = False,
    cd_points: int = 10_000,
    progress: bool = True,
    camera: str = "given",
    repair: bool = True,
) -> dict[str, Any]:
    """Evaluate ``predictor`` on every manual under ``data``; returns the metrics dict.
    ``camera="estimated"``: the manuals' cameras are dropped and estimated from the pictures
    (:mod:`mepnet.cameras`); poses are then compared up to each build's frame
    (:mod:`mepnet.frames`) and the camera errors reported. ``repair=False``: the autoregressive
    run makes no revisions across steps (:func:`mepnet.consistency.repair`), to measure what the
    repair buys."""
    if camera not in CAMERAS:
        raise ConfigError(f"unknown camera source '{camera}' (choose from {', '.join(CAMERAS)})")
    from tqdm import tqdm

    dirs = list(iter_manual_dirs(data))
    if not dirs:
        raise ManualFormatError(f"{data}: no manual folders (manual.json) found")
    manuals = [load_manual(d) for d in dirs]  # every manual checked before the work starts
    for m in manuals:
        answers_of(m)
    scorer = Scorer(cd_points)
    mtc, set_cd = [], []
    cam_first: list[tuple[float, float]] = []
    cam_later: list[tuple[float, float]] = []
    cam_seconds: list[float] = []
    cam_failures = cam_steps = 0
    ar_right = ar_total = manuals_exact = manuals_alike = undetermined_comps = 0
    undecidable_comps = 0
    ar_revisions = 0
    ar_repair_seconds: list[float] = []
    # the plan's steps with alternatives no picture told apart, and its wrong steps: all, those
    # flagged so, those one of whose alternatives is the truth (:func:`alternatives_counts`)
    ar_alternatives = np.zeros(4, int)
    timeouts = 0
    over_budget = 0  # steps whose stage 2 ran out of its time budget
    regressed: list[np.ndarray] = []  # Direct3D: regressed minus true translation (cells)
    per_manual: list[dict[str, Any]] = []
    bar = tqdm(
        total=sum(len(m.all_steps()) * (2 if autoregressive else 1) for m in manuals),
        unit="step",
        disable=not progress,
        leave=False,  # an error then stays one line
        file=sys.stderr,
    )
    try:
        for man in manuals:
            answers = answers_of(man)
            source = drop_cameras(man) if camera == "estimated" else man
            # teacher-forced: every step on the true shape (the paper's Table 1)
            before = getattr(predictor, "timeouts", 0)
            run = run_manual(source, predictor, teacher_forced=True, on_step=lambda: bar.update(1))
            timeouts += getattr(predictor, "timeouts", 0) - before
            comps = run.components
            wrong = 0
            seen = (scorer.components, scorer.correct, scorer.supported, scorer.supported_correct)
            kinds = dict.fromkeys(ERROR_KINDS, 0)
            first_wrong = 0
            wrong_where: list[str] = []
            undetermined_where: list[str] = []
            undecidable_where: list[str] = []
            camera_off: dict[str, Any] = {}  # estimated cameras off by > CAMERA_OFF_PX, or none
            over_budget_where: list[str] = []
            for b in run.builds:
                truth = answers.build(b.key)
                scale = _diag([(comps[i.component], i.yaw, i.t) for i in truth.instances])
                truth_steps: list[list[Any]] | None = None  # made for the first wrong step
                for s in b.steps:
                    assert s.truth is not None
                    scorer.seconds.append(s.seconds)
                    if any(p.extra.get("over_budget") for p in s.predictions):
                        over_budget_where.append(f"{b.name} step {s.index}")
                    gt = [(i.component, i.yaw, i.t) for i in s.truth.placed()]
                    supported = [v.attach != "unsupported" for v in s.truth.answers.views]
                    preds = _in_truth_frame(run, b, s)
                    if camera == "given":
                        regressed += _regression_errors(preds, gt)
                    ok = scorer.step(preds, gt, comps, scale, supported)
                    wrong += int(not ok)
                    if not ok:
                        first_wrong += int(s.index == 1)
                        wrong_where.append(f"{b.name} step {s.index}")
                        step_kinds = error_kinds(preds, gt, comps, supported)
                        for k, v in step_kinds.items():
                            kinds[k] += v
                        if truth_steps is None:
                            truth_steps = _true_steps(answers, b.key, comps)
                        if undetermined(man, run, b, s, truth_steps):
                            undetermined_where.append(f"{b.name} step {s.index}")
                            undetermined_comps += sum(step_kinds.values())
                        elif camera == "estimated" and undecidable(man, run, b, s, truth_steps):
                            undecidable_where.append(f"{b.name} step {s.index}")
                            undecidable_comps += sum(step_kinds.values())
                    if s.camera is not None and s.camera.source == "estimated":
                        cam_steps += 1
                        cam_seconds.append(s.camera.seconds)
                        cam_failures += int(s.camera.camera is None)
                        err = _camera_errors(man, run, b, s)
                        if err is not None:
                            (cam_first if s.index == 1 else cam_later).append(err)
                        where = f"{b.name} step {s.index}"
                        if s.camera.camera is None:
                            camera_off[where] = None
                        elif err is not None and err[1] > CAMERA_OFF_PX:
                            camera_off[where] = [round(err[0], 2), round(err[1], 2)]
            mtc.append(wrong / max(len(man.all_steps()), 1))
            over_budget += len(over_budget_where)
            n, right, sup, sup_right = (
                now - then
                for now, then in zip(
                    (scorer.components, scorer.correct, scorer.supported, scorer.supported_correct),
                    seen,
                    strict=True,
                )
            )
            per_manual.append(
                {
                    "manual": Path(man.path).name,
                    "source": str(man.source.get("file") or man.source.get("model") or ""),
                    "steps": len(man.all_steps()),
                    "wrong_steps": wrong,
                    "wrong_first_steps": first_wrong,
                    "components": n,
                    "correct": right,
                    "supported": sup,
                    "supported_correct": sup_right,
                    "errors": kinds,
                    "wrong": wrong_where,
                    "undetermined": undetermined_where,
                    "over_budget": over_budget_where,
                    **(
                        {"camera_off": camera_off, "camera_undecidable": undecidable_where}
                        if camera == "estimated"
                        else {}
                    ),
                }
            )
            if autoregressive:
                # the plan a user gets: every step on the predictor's own earlier placements
                ar = run_manual(source, predictor, on_step=lambda: bar.update(1), repair=repair)
                for b in ar.builds:
                    for s in b.steps:
                        ar_revisions += len(s.revisions)
                        ar_repair_seconds.append(s.repair_seconds)
                right, total = accuracy(ar)
                ar_right += right
                ar_total += total
                counts = alternatives_counts(ar)
                ar_alternatives += counts
                exact = bool(built_exactly(ar))
                manuals_exact += int(exact)
                alike = bool(drawn_alike(man, ar))
                manuals_alike += int(alike)
                per_manual[-1].update(
                    autoregressive_correct=right,
                    built_exactly=exact,
                    drawn_alike=alike,
                    revisions=sum(len(s.revisions) for b in ar.builds for s in b.steps),
                    alternatives=dict(zip(ALTERNATIVES_KEYS, counts.tolist(), strict=True)),
                )
                motion = step_motion(ar, ar.main, ar.main.steps[0]) if ar.main.steps else None
                placed = [
                    moved((ar.components[r], y, t, c), motion)[:3]
                    if motion
                    else (ar.components[r], y, t)
                    for r, y, t, c in ar.main.placed()
                ]
                gt_final = [(comps[i.component], i.yaw, i.t) for i in answers.main.instances]
                set_cd.append(
                    scorer.cd(placed, gt_final, _diag(gt_final)) if placed else float("nan")
                )
    finally:
        bar.close()  # also on Ctrl-C, before the one-line message

    def mean(x: list[float]) -> float | None:
        x = [v for v in x if v == v]
        return float(np.mean(x)) if x else None

    def cd(x: list[float]) -> float | None:
        m = mean(x)
        return None if m is None else m * metrics.CD_REPORT_SCALE

    return {
        "predictor": predictor.name,
        "data": str(data),
        "n_manuals": len(dirs),
        "n_steps": scorer.steps,
        "n_components": scorer.components,
        "n_failures": scorer.failures,
        "component_acc": scorer.correct / max(scorer.components, 1),
        "step_acc": scorer.steps_correct / max(scorer.steps, 1),
        "component_cd": cd(scorer.comp_cd),
        "step_cd": cd(scorer.step_cd),
        "set_cd": cd(set_cd) if autoregressive else None,
        "autoregressive_component_acc": ar_right / max(ar_total, 1) if autoregressive else None,
        "manuals_exact": manuals_exact / len(manuals) if autoregressive else None,
        "undetermined_components": undetermined_comps,
        "component_acc_pictures": (scorer.correct + undetermined_comps) / max(scorer.components, 1),
        "camera_undecidable_components": undecidable_comps if camera == "estimated" else None,
        "manuals_drawn_alike": manuals_alike / len(manuals) if autoregressive else None,
        "repair": repair if autoregressive else None,
        "revisions": ar_revisions if autoregressive else None,
        "alternatives": dict(zip(ALTERNATIVES_KEYS, ar_alternatives.tolist(), strict=True))
        if autoregressive
        else None,
        "repair_seconds_per_step": float(np.mean(ar_repair_seconds))
        if autoregressive and ar_repair_seconds
        else None,
        "mtc": float(np.mean(mtc)) if mtc else None,
        "seconds_per_step": float(np.mean(scorer.seconds)) if scorer.seconds else None,
        "median_seconds_per_step": float(np.median(scorer.seconds)) if scorer.seconds else None,
        "n_submodule_components": scorer.sub_components,
        "submodule_component_acc": scorer.sub_correct / scorer.sub_components
        if scorer.sub_components
        else None,
        "submodule_component_cd": cd(scorer.sub_cd),
        "cd_points": cd_points,
        "n_timeouts": timeouts,
        "over_budget_steps": over_budget,
        "timeout_share": timeouts / max(scorer.components, 1),
        "n_unsupported": scorer.components - scorer.supported,
        "supported_component_acc": scorer.supported_correct / scorer.supported
        if scorer.supported
        else None,
        "camera": camera,
        "errors": {k: sum(m["errors"][k] for m in per_manual) for k in ERROR_KINDS},
        "per_manual": per_manual,
        **_camera_metrics(camera, cam_first, cam_later, cam_seconds, cam_failures, cam_steps),
        "regression": _regression_metrics(regressed),
    }


def _regression_errors(preds: Sequence[Prediction], gt: Sequence[Any]) -> list[np.ndarray]:
    """For each prediction carrying a regressed translation (``extra["regressed"]``: Direct3D)
    the regressed minus the true translation (lattice cells) of the nearest true instance of
    its component."""
    out = []
    for p in preds:
        if p.extra.get("regressed") is None:
            continue  # (every other predictor)
        near = [np.asarray(t, dtype=np.float64) for ref, _, t in gt if ref == p.component]
        if not near:
            continue
        r = np.asarray(p.extra["regressed"], dtype=np.float64)
        out.append(r - min(near, key=lambda t: float(np.abs(t - r).sum())))
    return out


def _regression_metrics(errors: list[np.ndarray]) -> dict[str, Any] | None:
    """How near a regressing predictor's translations come to the truth before quantisation
    (given cameras): median absolute error per axis (cells: x, z half-studs, y plates), the
    share that rounds to the true cell, and the share whose rounding has the truth within the
    quantiser's neighbourhood (:data:`mepnet.stage2.direct3d.NEIGHBOURHOOD`)."""
    if not errors:
        return None
    from mepnet.stage2.direct3d import NEIGHBOURHOOD

    e = np.array(errors)
    off = np.abs(np.rint(e))  # the rounding's distance from the truth, per axis
    return {
        "instances": len(e),
        "median_abs_error_cells": [float(v) for v in np.median(np.abs(e), axis=0)],
        "rounds_to_truth": float((off == 0).all(axis=1).mean()),
        "truth_in_neighbourhood": float((off <= np.array(NEIGHBOURHOOD)).all(axis=1).mean()),
    }


def _camera_metrics(
    camera: str,
    first: list[tuple[float, float]],
    later: list[tuple[float, float]],
    seconds: list[float],
    failures: int,
    steps: int,
) -> dict[str, Any]:
    """Camera errors of the teacher-forced run: rotation (degrees) and mean reprojection of the
    true shape's voxel corners (pixels), later steps and first steps (in the truth's frame)
    apart; estimation time per step; steps whose camera could not be estimated."""
    if camera != "estimated":
        return {}

    def stats(errs: list[tuple[float, float]], i: int, q: float) -> float | None:
        return float(np.quantile([e[i] for e in errs], q)) if errs else None

    def mean(errs: list[tuple[float, float]], i: int) -> float | None:
        return float(np.mean([e[i] for e in errs])) if errs else None

    return {
        "camera_steps": steps,
        "camera_failures": failures,
        "camera_rotation_deg_median": stats(later, 0, 0.5),
        "camera_rotation_deg_mean": mean(later, 0),
        "camera_reprojection_px_median": stats(later, 1, 0.5),
        "camera_reprojection_px_mean": mean(later, 1),
        "camera_reprojection_px_p90": stats(later, 1, 0.9),
        "camera_within_1px": sum(e[1] <= 1.0 for e in later) / len(later) if later else None,
        "camera_first_rotation_deg_median": stats(first, 0, 0.5),
        "camera_first_reprojection_px_median": stats(first, 1, 0.5),
        "camera_first_reprojection_px_mean": mean(first, 1),
        "camera_seconds_per_step": float(np.mean(seconds)) if seconds else None,
        "camera_median_seconds_per_step": float(np.median(seconds)) if seconds else None,
        "camera_p95_seconds_per_step": float(np.quantile(seconds, 0.95)) if seconds else None,
    }


#: Pixels in which two drawings may differ and still be the same picture (:func:`pictures_alike`;
#: a pixel differs as :func:`mepnet.stage2.synthesis.drawn_differ` says).
DRAWN_TOLERANCE_PX = 2


def pictures_alike(
    manual: Any,
    key: int | None,
    first: Sequence[Sequence[Any]],
    second: Sequence[Sequence[Any]],
    start: int = 0,
) -> bool | None:
    """Whether two ways to build build ``key`` of ``manual`` (per step the placements
    ``(component, yaw, t, colour)`` it adds) give the same picture at every step from
    ``start`` (0-based) on: drawn by mepnet's renderer with the manual's cameras, the two
    shapes after the step differ in at most :data:`DRAWN_TOLERANCE_PX` pixels. None when a step
    has no camera; False when one way cannot be built (a placement collides: a wrong step's
    parts put in place of the truth's, with the true later steps after them)."""
    build = manual.main if key is None else manual.submodules[key]
    if any(st.camera is None for st in build.steps[start:]):
        return None
    w, h = manual.image_size
    so_far_a: list[Any] = []
    so_far_b: list[Any] = []
    for k, (xa, xb) in enumerate(zip(first, second, strict=True)):
        so_far_a += xa
        so_far_b += xb
        if k < start:
            continue
        try:
            a, b = _drawn_shape(so_far_a), _drawn_shape(so_far_b)
        except BrickGeomError:
            return False
        cam = build.steps[k].camera_object()
        ra = _bg.render(a, cam, w, h).rgb.astype(np.int16)
        rb = _bg.render(b, cam, w, h).rgb.astype(np.int16)
        if int(drawn_differ(ra, rb).sum()) > DRAWN_TOLERANCE_PX:
            return False
    return True


#: The keys of ``alternatives`` in the JSON (:func:`alternatives_counts`).
ALTERNATIVES_KEYS = ("steps", "wrong_steps", "wrong_flagged", "truth_offered")


def alternatives_counts(run: Any) -> np.ndarray:
    """Over every step of the plan ``run`` (autoregressive, with answers): the steps with
    alternatives no picture told apart (``StepRun.alternatives``, flagged in plan.json); the
    wrong steps (some true instance not placed exactly); of those, the ones flagged so; and
    the ones one of whose alternatives, taken, places every true instance exactly."""
    out = np.zeros(4, int)
    for b in run.builds:
        for s in b.steps:
            out[0] += bool(s.alternatives)
            if s.truth is None:
                continue
            total = len(s.truth.placed())
            if step_matches(run, s) == total:
                continue
            out[1] += 1
            out[2] += bool(s.alternatives)
            for alt in s.alternatives:
                preds, placed = list(s.predictions), list(s.placed)
                for i, yaw, t in alt:
                    preds[i] = dataclasses.replace(preds[i], yaw=yaw, t=t)
                    pl = placed[i]
                    assert pl is not None  # an alternative moves placed parts only
                    placed[i] = (pl[0], yaw, t, pl[3])
                trial = dataclasses.replace(s, predictions=preds, placed=placed)
                if step_matches(run, trial, b) == total:
                    out[3] += 1
                    break
    return out


def _drawn_shape(placements: Sequence[Any]) -> _bg.Assembly:
    """The shape of ``placements`` (``(component, yaw, t, colour)``) with its instances in one
    order whatever order they came in: where two parts' faces meet, which one the renderer
    draws there follows instance order, so the same shape added in another order differs in a
    few pixels (F20v manual 3 step 24: 3 pixels, a slope beside a corner plate), which
    :data:`DRAWN_TOLERANCE_PX` must not be spent on. Raises ``BrickGeomError`` where two
    placements collide (adding checks collisions only, so any order gives the same answer)."""
    shape = _bg.Assembly()
    for x in sorted(placements, key=lambda x: (x[0].name, x[1], tuple(x[2]), x[3])):
        shape.add(*x)
    return shape


def _true_steps(answers: Any, key: int | None, comps: Any) -> list[list[Any]]:
    """Per step of build ``key``, the true placements ``(component, yaw, t, colour)`` it adds."""
    truth = answers.build(key)
    return [
        [(comps[i.component], i.yaw, i.t, i.colour) for i in truth.truth(k).placed()]
        for k in range(len(truth.steps))
    ]


def undetermined(man: Any, run: Any, b: Any, s: Any, truth: list[list[Any]]) -> bool:
    """Whether a (wrong, teacher-forced) step's prediction changes no picture of the manual
    ``man`` (with its cameras): every component placed, and the build with the prediction in
    place of the step's truth draws every picture from the step on as the truth does.
    ``truth``: the build's true placements per step (:func:`_true_steps`)."""
    preds = _in_truth_frame(run, b, s)
    if not preds or not all(p.placed for p in preds):
        return False
    k = s.index - 1
    entries = b.build.steps[k].components
    other = list(truth)
    other[k] = [(run.components[p.component], p.yaw, p.t, entries[p.entry].colour) for p in preds]
    return bool(pictures_alike(man, b.key, truth, other, start=k))


def drawn_alike(man: Any, run: Any) -> bool | None:
    """Whether the plan ``run`` (autoregressive) draws every picture of the manual ``man``
    (with its cameras) as the truth does, build by build (in the truth's frame: a build with
    estimated cameras moved by its motion). None when a picture has no camera."""
    answers = answers_of(man)
    comps = answers.components(man)
    for b in run.builds:
        motion = step_motion(run, b, b.steps[0]) if frame_free(b) and b.steps else None
        plan = [
            [moved(x, motion) if motion else x for x in predicted_placements(run, s)]
            for s in b.steps
        ]
        alike = pictures_alike(man, b.key, _true_steps(answers, b.key, comps), plan)
        if not alike:
            return alike
    return True


def undecidable(man: Any, run: Any, b: Any, s: Any, truth: list[list[Any]]) -> bool:
    """Whether a (wrong, teacher-forced) step's prediction, drawn with the camera the step
    estimated, gives the step's picture as the truth gives it with the manual's camera (drawn
    by mepnet's renderer, at most :data:`DRAWN_TOLERANCE_PX` pixels unmatched within a pixel,
    :func:`_unmatched`): without a camera, the step's own picture cannot tell the two apart.
    The true shape before the step is in the predictions' frame (teacher-forced, the cameras
    are carried into it)."""
    if s.camera is None or s.camera.camera is None or s.camera.source != "estimated":
        return False
    if not s.predictions or not all(p.placed for p in s.predictions):
        return False
    k = s.index - 1
    page = b.build.steps[k]
    true_page = (man.main if b.key is None else man.submodules[b.key]).steps[k]
    if true_page.camera is None:
        return False
    before = [x for step in truth[:k] for x in step]
    try:
        truth_shape = _drawn_shape(before + list(truth[k]))
        predicted = _drawn_shape(
            before
            + [
                (run.components[p.component], p.yaw, p.t, page.components[p.entry].colour)
                for p in s.predictions
            ]
        )
    except BrickGeomError:
        return False
    w, h = man.image_size
    drawn = _bg.render(truth_shape, true_page.camera_object(), w, h).rgb.astype(np.int16)
    mine = _bg.render(predicted, s.camera.camera, w, h).rgb.astype(np.int16)
    return max(_unmatched(drawn, mine), _unmatched(mine, drawn)) <= DRAWN_TOLERANCE_PX


def _unmatched(a: np.ndarray, b: np.ndarray) -> int:
    """Pixels of drawing ``a`` that differ from every pixel of ``b`` in their 3x3
    neighbourhood (an estimated camera is fitted, a fraction of a pixel off: edges move)."""
    h, w = a.shape[:2]
    pad = np.pad(b, ((1, 1), (1, 1), (0, 0)), mode="edge")
    differs = np.ones((h, w), dtype=bool)
    for dy in range(3):
        for dx in range(3):
            near = pad[dy : dy + h, dx : dx + w]
            differs &= np.abs(a - near).max(axis=-1) > DRAWN_LEVEL
    return int(differs.sum())


def _in_truth_frame(run: Any, b: Any, s: Any) -> list[Prediction]:
    """A step's predictions moved into the truth's frame (:func:`mepnet.plan.step_motion`;
    the identity with the cameras the manual states)."""
    motion = step_motion(run, b, s)
    if motion.is_identity:
        return s.predictions
    out = []
    for p in s.predictions:
        if p.placed:
            yaw, t = motion.apply(p.yaw, p.t)
            p = dataclasses.replace(p, yaw=yaw, t=t)
        out.append(p)
    return out


def format_table(rows: list[dict[str, Any]]) -> str:
    """Rows in the layout of the paper's Table 1."""

    def f(v: Any, pct: bool = False) -> str:
        if v is None:
            return "-"
        return f"{100 * v:.2f}" if pct else f"{v:.2f}"

    head = (
        f"{'':14s} {'Pose Acc (%)':^17s} {'CD (x1e5)':^17s} {'Setwise':^17s}\n"
        f"{'Method':14s} {'Comp.':>8s} {'Step':>8s} {'Comp.':>8s} {'Step':>8s} {'CD':>8s} {'MTC':>8s} {'s/step':>8s}"
    )
    lines = [head]
    for r in rows:
        lines.append(
            f"{r['predictor']:14s} {f(r['component_acc'], True):>8s} {f(r['step_acc'], True):>8s} "
            f"{f(r['component_cd']):>8s} {f(r['step_cd']):>8s} {f(r['set_cd']):>8s} "
            f"{f(r['mtc'], True):>8s} {r['seconds_per_step']:>8.4f}"
        )
        if r["n_submodule_components"]:
            lines.append(
                f"{'  submodules':14s} {f(r['submodule_component_acc'], True):>8s} {'':>8s} "
                f"{f(r['submodule_component_cd']):>8s}"
            )
        if r.get("component_acc_pictures") is not None:
            alike = r.get("manuals_drawn_alike")
            lines.append(
                f"{'  pictures':14s} {f(r['component_acc_pictures'], True):>8s} (counting as right "
                f"the {r['undetermined_components']} components wrong only where no picture "
                "shows it"
                + (
                    f"; plans drawing every picture as the truth: {f(alike, True)}%)"
                    if alike is not None
                    else ")"
                )
            )
        if r.get("autoregressive_component_acc") is not None:
            lines.append(
                f"{'  on its own':14s} {f(r['autoregressive_component_acc'], True):>8s} "
                f"(the plan built on its own predictions; manuals built exactly right: "
                f"{f(r['manuals_exact'], True)}%)"
            )
            if r.get("repair"):
                lines.append(
                    f"{'  repair':14s} {r['revisions']} revisions across steps; "
                    f"{r['repair_seconds_per_step'] or 0:.4f} s per step"
                )
            elif r.get("repair") is False:
                lines.append(f"{'  repair':14s} off (--no-repair)")
            if a := r.get("alternatives"):
                lines.append(
                    f"{'  unsettled':14s} {a['steps']} steps flagged with alternatives no picture "
                    f"tells apart; of the {a['wrong_steps']} wrong steps {a['wrong_flagged']} "
                    f"flagged, {a['truth_offered']} with the truth among the alternatives"
                )
    for r in rows:
        if r.get("over_budget_steps"):
            lines.append(
                f"{'  budget':14s} {r['over_budget_steps']} of {r['n_steps']} steps ran out of "
                "stage 2's time budget (their first solution kept)"
            )
    for r in rows:
        if r["predictor"] in ("abys", "oracle-abys") or r.get("n_timeouts"):
            lines.append(
                f"{'  time limit':14s} {r['n_timeouts']} of {r['n_components']} components over "
                f"their limit ({f(r['timeout_share'], True)}%); "
                f"{r['seconds_per_step']:.3f} s per step (median "
                f"{r['median_seconds_per_step']:.3f})"
            )
    for r in rows:
        if r.get("camera") == "estimated":
            lines.append(
                f"{'  cameras':14s} estimated from the pictures: rotation error median "
                f"{f(r['camera_rotation_deg_median'])} deg, reprojection median "
                f"{f(r['camera_reprojection_px_median'])} px (mean "
                f"{f(r['camera_reprojection_px_mean'])}, within 1 px "
                f"{f(r['camera_within_1px'], True)}%), first steps "
                f"{f(r['camera_first_reprojection_px_median'])} px; "
                f"{r['camera_failures']} of {r['camera_steps']} not estimated; "
                f"{1000 * (r['camera_seconds_per_step'] or 0):.1f} ms/step"
            )
            lines.append(
                f"{'':14s} (poses compared up to each build's frame: one quarter turn and "
                "lattice shift per build, fixed by its first step; "
                f"{r['camera_undecidable_components']} components wrong where the step's "
                "picture, without its camera, cannot tell)"
            )
    lines.append(
        f"({rows[0]['n_manuals']} manuals, {rows[0]['n_steps']} steps, {rows[0]['n_components']} components, "
        f"{rows[0]['n_failures']} not placed; MTC in % of steps)"
    )
    return "\n".join(lines)


def format_per_manual(result: dict[str, Any]) -> str:
    """One line per manual: components right (of those supported), wrong steps (first steps
    among them) and what went wrong (:data:`ERROR_KINDS`)."""
    width = max([6, *(len(m["manual"]) for m in result["per_manual"])])
    lines = [
        f"{'manual':{width}s} {'source':32s} {'right':>9s} {'supp.':>7s} {'acc':>7s} "
        f"{'wrong steps':>11s} " + " ".join(f"{k:>11s}" for k in ERROR_KINDS)
    ]
    for m in result["per_manual"]:
        acc = m["supported_correct"] / m["supported"] if m["supported"] else None
        lines.append(
            f"{m['manual']:{width}s} {m['source'][:32]:32s} {m['correct']:>4d}/{m['components']:<4d} "
            f"{m['supported']:>7d} {'-' if acc is None else f'{100 * acc:.1f}':>7s} "
            f"{m['wrong_steps']:>5d} ({m['wrong_first_steps']} 1st) "
            + " ".join(f"{m['errors'][k]:>11d}" for k in ERROR_KINDS)
            + (
                f"  on its own {m['autoregressive_correct']}/{m['components']}"
                f"{' exact' if m['built_exactly'] else ' drawn alike' if m.get('drawn_alike') else ''}"
                if "built_exactly" in m
                else ""
            )
        )
    e = result["errors"]
    lines.append(
        f"{'all':{width}s} {'':32s} {'':>9s} {'':>7s} {'':>7s} {'':>11s} "
        + " ".join(f"{e[k]:>11d}" for k in ERROR_KINDS)
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (2 on bad input, with one line on stderr)."""
    ap = ArgumentParser(prog="python -m mepnet.eval", description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="a manual folder, or a folder of manual folders")
    ap.add_argument("--predictor", required=True, choices=PREDICTORS)
    ap.add_argument("--json", help="write the metrics to this JSON file")
    ap.add_argument(
        "--autoregressive", action="store_true", help="also run setwise (predictions fed forward)"
    )
    ap.add_argument("--sigma", type=float, default=1.0, help="keypoint noise (px) for oracle-noisy")
    ap.add_argument("--seed", type=int, default=0, help="noise seed for oracle-noisy")
    ap.add_argument(
        "--time-limit",
        type=float,
        default=60.0,
        help="abys, oracle-abys: seconds per component (default 60, the paper's)",
    )
    ap.add_argument("--cd-points", type=int, default=10_000, help="points sampled per surface")
    ap.add_argument(
        "--weights",
        help="network weights (model.safetensors): the detector's for --predictor mepnet and "
        "abys (default: the shipped slim weights), Direct3D's for --predictor direct3d",
    )
    ap.add_argument(
        "--lift",
        choices=LIFTS,
        default="synthesis",
        help="mepnet: lift detections to 3D by synthesis from the masks (default) or by the "
        "paper's keypoint ray search",
    )
    ap.add_argument(
        "--camera",
        choices=CAMERAS,
        default="given",
        help="the cameras the manual states (default), or estimated from the pictures with the "
        "manual's dropped (poses then compared up to each build's frame; camera errors reported)",
    )
    ap.add_argument(
        "--no-repair",
        action="store_true",
        help="--autoregressive: make no revisions across steps (to measure what they buy)",
    )
    ap.add_argument(
        "--per-manual",
        action="store_true",
        help="also print one line per manual: accuracy and what went wrong (the JSON always "
        "has it)",
    )
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    return run_cli("mepnet.eval", lambda: _main(args))


def _main(args: argparse.Namespace) -> int:
    if not Path(args.data).is_dir():
        raise ManualFormatError(f"{args.data}: not a folder")
    if not 1 <= args.cd_points <= 10_000_000:
        raise ConfigError(f"--cd-points must be within 1..10000000, got {args.cd_points}")
    if args.seed < 0:
        raise ConfigError(f"--seed must not be negative, got {args.seed}")
    if not (math.isfinite(args.sigma) and args.sigma >= 0):
        raise ConfigError(f"--sigma must be a finite number >= 0, got {args.sigma}")
    if not (math.isfinite(args.time_limit) and args.time_limit > 0):
        raise ConfigError(f"--time-limit must be a finite number > 0, got {args.time_limit}")
    if args.json:
        check_output_file(args.json, WRITER)  # before the work, not after it
    predictor = make_predictor(
        args.predictor, args.sigma, args.seed, args.time_limit, args.weights, args.lift
    )
    result = evaluate(
        args.data,
        predictor,
        args.autoregressive,
        args.cd_points,
        not args.no_progress,
        args.camera,
        not args.no_repair,
    )
    print(format_table([result]))
    if (reg := result["regression"]) is not None:
        med = ", ".join(f"{v:.2f}" for v in reg["median_abs_error_cells"])
        print(
            f"regressed translations ({reg['instances']}): median error {med} cells (x, y, z); "
            f"{100 * reg['rounds_to_truth']:.1f}% round to the truth, "
            f"{100 * reg['truth_in_neighbourhood']:.1f}% have it within the quantiser's reach"
        )
    if args.per_manual:
        print(format_per_manual(result))
    if args.json:
        atomic_write_json(args.json, {"written_by": WRITER, **result})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
