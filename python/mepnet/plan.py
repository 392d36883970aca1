"""Build plans: the one loop that runs a predictor over a whole manual, and the files a plan
is written as.

:func:`run_manual` builds the submodules first (their predicted shapes become the components
of later steps), then the main model, each step on the shape built so far: the predictor's own
earlier predictions (autoregressive, what a user gets: :mod:`mepnet.infer`), or with
``teacher_forced=True`` the true shapes (the paper's Table 1 protocol: :mod:`mepnet.eval`).
Predictors see only the page; oracles are handed the step's answers (``predict_step``).

:func:`write_plan` writes ``plan.json``, ``plan.mpd`` (LDraw: opens in LeoCAD, LDView, LPub3D
and Studio, and reads back with :mod:`mepnet.ldraw`) and step overlay images, atomically.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.cameras import SMALL_BASE, BuildCameras, CameraEstimate, PageStyle
from mepnet.consistency import Placement, Revision, StepCheck, View, check_step, tie_distances
from mepnet.consistency import build as build_placements
from mepnet.consistency import repair as repair_placements
from mepnet.errors import MepnetError
from mepnet.files import atomic_folder
from mepnet.frames import (
    IDENTITY,
    Motion,
    best_motion,
    candidate_motions,
    matches,
    moved,
    placement_key,
    symmetries,
)
from mepnet.geom import BrickGeomError, placement_box, submodule_from_placed
from mepnet.ldraw.io import LDrawFile, LDrawModel, LDrawRef, ldraw_placement
from mepnet.ldraw.io import write as write_ldraw
from mepnet.manual import Build, ComponentRef, Manual, Step, StepTruth
from mepnet.stage2 import Prediction, Predictor, StepContext, predict_step
from mepnet.stage2.base import EarlierStep
from mepnet.stage2.synthesis import shared_changes

PLAN_SCHEMA = "mepnet.plan"

#: A placed component: (reference, yaw, t, colour).
Placed = tuple[ComponentRef, int, tuple[int, int, int], int]


@dataclass
class StepRun:
    """One step as the loop ran it."""

    index: int
    image: str
    predictions: list[Prediction]
    #: per prediction: the placement added to the shape (None: not placed)
    placed: list[Placed | None]
    seconds: float
    #: the step's answers (None for a manual without answers)
    truth: StepTruth | None = None
    #: the camera the step was predicted with: given by the page, or estimated
    camera: CameraEstimate | None = None
    #: how well the predicted step explains its picture (:mod:`mepnet.consistency`)
    check: StepCheck | None = None
    #: earlier placements this step's picture contradicted, changed (:func:`repair`)
    revisions: list[Revision] = field(default_factory=list)
    #: wall time of the repair after this step
    repair_seconds: float = 0.0
    #: other solutions of the step that no picture told apart from the plan's (autoregressive,
    #: at the end of the build; :func:`_unsettled`): per solution, the placements ``(prediction
    #: index, yaw, t)`` where it differs from the plan
    alternatives: list[list[tuple[int, int, tuple[int, int, int]]]] = field(default_factory=list)


@dataclass
class BuildRun:
    """A build (submodule ``key``, or the main model: None) as the loop ran it."""

    key: int | None
    build: Build
    steps: list[StepRun] = field(default_factory=list)

    @property
    def name(self) -> str:
        """The build's name (``main`` for the main model)."""
        return self.build.name

    def placed(self) -> list[Placed]:
        """Everything the build placed, in order."""
        return [p for s in self.steps for p in s.placed if p is not None]


@dataclass
class ManualRun:
    """A whole manual as the loop ran it: builds in build order (submodules, then main)."""

    manual: Manual
    predictor: str
    teacher_forced: bool
    builds: list[BuildRun]
    components: dict[ComponentRef, _bg.Component]
    #: motions into the truth's frame, computed on first use (:func:`step_motion`)
    motions: dict[tuple[int | None, int], Motion] = field(default_factory=dict)

    @property
    def main(self) -> BuildRun:
        """The main model's run."""
        return self.builds[-1]


def _missing_entries(
    ctx_components: dict[ComponentRef, _bg.Component], run_step: Any
) -> tuple[Any, list[int]]:
    """The page step without callout entries whose component does not exist (a submodule
    whose build placed nothing), and the original indices of the entries kept."""
    keep = [k for k, c in enumerate(run_step.components) if c.component in ctx_components]
    if len(keep) == len(run_step.components):
        return run_step, keep
    return dataclasses.replace(run_step, components=[run_step.components[k] for k in keep]), keep


def run_build(
    predictor: Predictor,
    manual: Manual,
    key: int | None,
    components: dict[ComponentRef, _bg.Component],
    teacher_forced: bool = False,
    on_step: Callable[[], None] | None = None,
    repair: bool = True,
    style: PageStyle | None = None,
) -> BuildRun:
    """Run every step of one build (see :func:`run_manual`); ``style``: the manual's drawing
    style as the builds before it saw it."""
    build = manual.main if key is None else manual.submodules[key]
    answers = manual.answers.build(key) if manual.answers is not None else None
    if teacher_forced and answers is None:
        from mepnet.errors import ManualFormatError

        raise ManualFormatError(f"{manual.path}: teacher forcing needs the manual's answers")
    run = BuildRun(key, build)
    base = _bg.Assembly()
    cameras = BuildCameras(manual.image_size, style)
    earlier: list[EarlierStep] = []  # the page steps so far, with the cameras predicted with
    placements: list[Placement] = []  # the shape built so far, in order (autoregressive)
    views: list[View] = []  # the pictures so far as the repair sees them
    # the latest steps whose pictures could not tell solutions apart: (step, the others)
    open_ties: list[tuple[int, list[list[tuple[int, int, tuple[int, int, int]]]]]] = []
    tie_views: dict[int, list[tuple[float, float, float]]] = {}  # the views each was judged by
    # ties no longer judged (more than :data:`TIE_KEPT` steps back): never told apart
    aged_ties: list[tuple[int, list[list[tuple[int, int, tuple[int, int, int]]]]]] = []
    w, h = manual.image_size
    for k, step in enumerate(build.steps):
        truth = full_truth = answers.truth(k) if answers is not None else None
        page_step, kept = _missing_entries(components, step)
        if truth is not None and len(kept) != len(step.components):
            truth = StepTruth(
                dataclasses.replace(
                    truth.answers, instances_of=[truth.instances_of[i] for i in kept]
                ),
                truth.instances,
            )

        def predict(
            page: Any,
            truth: StepTruth | None = truth,
            where: str = step.where,
            earlier: tuple[EarlierStep, ...] = tuple(earlier),
            base: _bg.Assembly = base,
            budget_s: float | None = None,
        ) -> tuple[list[Prediction], float]:
            ctx = StepContext(page, base.copy(), components, manual.image_size, earlier, budget_s)
            try:
                return predict_step(predictor, ctx, truth)
            except (MepnetError, BrickGeomError) as err:
                if where and where not in str(err):  # name the manual and the step
                    raise type(err)(f"{where}: {err}") from None
                raise

        if step.camera is not None:
            camera = CameraEstimate.given(step)
            preds, seconds = predict(page_step)
            cameras.accept(step, camera, None, _trial_shape(base, preds, components, page_step))
        else:
            preds, seconds, camera = _estimated_camera_step(
                cameras, predict, page_step, base, components, teacher_forced
            )
        seen = None if camera.camera is None else camera.step_camera()
        page_seen = dataclasses.replace(step, camera=seen)

        def judge(
            preds: list[Prediction],
            before: _bg.Assembly,
            built: _bg.Assembly,
            page_seen: Step = page_seen,
            earlier: tuple[EarlierStep, ...] = tuple(earlier),
        ) -> StepCheck:
            """The check of the step's ``preds`` placed on the shape ``before`` (making
            ``built``)."""
            ctx = StepContext(page_seen, before, components, manual.image_size, earlier)
            return check_step(ctx, preds, built)

        def finish(
            preds: list[Prediction],
            before: _bg.Assembly,
            step: Step = step,
            k: int = k,
            kept: list[int] = kept,
            judge: Callable[..., StepCheck] = judge,
        ) -> tuple[list[Prediction], list[Placed | None], list[Placement], _bg.Assembly, StepCheck]:
            """The step's predictions back in the page's entry numbering (a failure for every
            entry left out) placed on a copy of the shape ``before`` and checked: the
            predictions, what each placed, the new placements, the shape after, the check."""
            preds = [dataclasses.replace(p, entry=kept[p.entry]) for p in preds]
            for e, c in enumerate(step.components):
                if e not in kept:
                    why = f"submodule {manual.submodules[c.component.submodule].name} was not built"  # type: ignore[index]
                    preds += [
                        Prediction(e, c.component, None, None, failure=why) for _ in range(c.count)
                    ]
            built = before.copy()
            placed: list[Placed | None] = []
            new: list[Placement] = []
            for j, p in enumerate(preds):
                pl: Placed | None = None
                if p.placed and p.failure is None:
                    colour = step.components[p.entry].colour
                    try:
                        built.add(components[p.component], p.yaw, p.t, colour)
                        pl = (p.component, int(p.yaw), tuple(p.t), colour)  # type: ignore[arg-type]
                        new.append(
                            Placement(k + 1, j, components[p.component], pl[1], pl[2], colour)
                        )
                    except BrickGeomError as e:  # a predictor other than stage 2 may collide
                        p.failure = str(e)
                placed.append(pl)
            return preds, placed, new, built, judge(preds, before, built)

        def predict_again(
            before: _bg.Assembly,
            page: Step = page_seen,
            predict: Callable[..., tuple[list[Prediction], float]] = predict,
            finish: Callable[..., Finished] = finish,
        ) -> Finished:
            """The step predicted again on the shape ``before`` (a repair's retries: a tie
            taken, an earlier part moved), within :data:`TIE_RETRY_BUDGET_S`, and finished."""
            return finish(predict(page, base=before, budget_s=TIE_RETRY_BUDGET_S)[0], before)

        # the predictions join the shape (teacher-forced: a trial copy; the true step joins it)
        preds, placed, new, built, checked = finish(preds, base)
        tie_revisions: list[Revision] = []
        tie_seconds = 0.0  # the step predicted again on ties: part of the repair's time
        if not teacher_forced:
            if repair and seen is not None and open_ties:
                t0 = time.perf_counter()
                preds, placed, new, built, checked, placements, tie_revisions = _try_ties(
                    run,
                    open_ties,
                    placements,
                    (preds, placed, new, built, checked),
                    (camera.camera, w, h),
                    predict_again,
                )
                tie_seconds = time.perf_counter() - t0
            base = built
            ties = next((p.extra["ties"] for p in preds if p.extra.get("ties")), None)
            if ties:
                open_ties.append((k + 1, [[(kept[e], y, t) for e, y, t in alt] for alt in ties]))
                aged_ties += open_ties[:-TIE_KEPT]
                del open_ties[:-TIE_KEPT]
                if camera.camera is not None:
                    tie_views[k + 1] = [_view(camera.camera)]
        checked.changed = None  # for the tie retries only: a plan keeps no mask per step
        placements += new
        if teacher_forced:
            for inst in full_truth.placed():  # type: ignore[union-attr]
                base.add(components[inst.component], inst.yaw, inst.t, inst.colour)
        run.steps.append(
            StepRun(
                k + 1, step.image_path.name, preds, placed, seconds, full_truth, camera, checked
            )
        )
        if camera.camera is not None and repair and not teacher_forced:
            t0 = time.perf_counter()
            picture = step.image()
            views.append(View.of(k + 1, camera.camera, picture))
            placements, revisions = repair_placements(placements, views, w, h)
            if open_ties:
                placements, seen_revisions = _ties_seen(
                    run, open_ties, tie_views, placements, camera.camera, picture
                )
                revisions += seen_revisions
            for r in revisions:  # the earlier step's prediction takes its new pose
                old = run.steps[r.step - 1]
                p, pl = old.predictions[r.pred], old.placed[r.pred]
                old.predictions[r.pred] = dataclasses.replace(
                    p, yaw=r.after[0], t=r.after[1], extra={**p.extra, "revised_at": k + 1}
                )
                old.placed[r.pred] = (pl[0], r.after[0], r.after[1], pl[3])  # type: ignore[index]
            if revisions:
                rebuilt = build_placements(placements)
                assert rebuilt is not None  # the repair keeps every placement valid
                base = rebuilt
            if any(r.step == k + 1 for r in revisions):
                # the step's own part put back (consistency.OWN_STEP): its check judges the
                # step as the plan now has it
                before = build_placements([p for p in placements if p.step <= k])
                assert before is not None
                run.steps[-1].check = judge(run.steps[-1].predictions, before, base)
                run.steps[-1].check.changed = None
            if AGAIN_AFTER_REPAIR and any(r.step <= k for r in revisions):
                # an earlier part this picture moved: the step was predicted on the shape
                # with it where it was, so it is predicted again on the shape as revised
                placements, base, again = _again_after_repair(
                    run.steps[-1],
                    placements,
                    predict_again,
                    base,
                )
                if again:  # the ties kept were the old prediction's
                    open_ties[:] = [t for t in open_ties if t[0] != k + 1]
                revisions += again
            run.steps[-1].revisions = tie_revisions + revisions
            run.steps[-1].repair_seconds = time.perf_counter() - t0 + tie_seconds
        earlier.append(EarlierStep(page_seen, len(base)))
        if on_step is not None:
            on_step()
    if not teacher_forced:
        _unsettled(run, aged_ties + open_ties, placements)
    return run


def _unsettled(
    run: BuildRun,
    ties: list[tuple[int, list[list[tuple[int, int, tuple[int, int, int]]]]]],
    placements: list[Placement],
) -> None:
    """Each step's ties that no picture told apart (``ties``: those still open at the end of
    the build and those no longer judged), as the plan now allows them: the step's
    :attr:`StepRun.alternatives` and a flag on its check. A part whose turn or place the
    manual never shows (a side stud facing into the model) is a guess either way; the plan
    says so rather than hand a robot one of them as certain."""
    for j, alts in ties:
        s = run.steps[j - 1]
        mine = {(p.pred, p.yaw, p.t) for p in placements if p.step == j}
        for alt in alts:
            trial = _tie_placements(placements, s, alt)
            if trial is None or build_placements(trial) is None:
                continue  # the plan since does not allow it
            differ = [
                (p.pred, p.yaw, p.t)
                for p in trial
                if p.step == j and (p.pred, p.yaw, p.t) not in mine
            ]
            if differ and differ not in s.alternatives:
                s.alternatives.append(differ)
        if s.alternatives and s.check is not None:
            n = len(s.alternatives)
            s.check.flags.append(
                f"{n} other solution{'s' if n > 1 else ''} explain{'' if n > 1 else 's'} the "
                "pictures as well: the manual does not show which (plan.json: alternatives)"
            )


#: A step explained worse than this (its check's confidence) is predicted again on each
#: solution of an earlier step that the earlier picture could not tell apart from the one
#: taken (stage 2's ``extra["ties"]``): a later part's true place may collide with a part the
#: tie hid, or need the side stud it turned away. (0.9 until stop 62: F20z manual 6 step 25
#: explains its picture 0.98 with an inverted slope turned to fit beside step 23's panel, a
#: tie its picture drew alike; 72 pixels of the picture show the slope's true turn, which the
#: panel as the plan has it blocks.)
TIE_RETRY_BELOW = 0.995
#: ... and such a solution is taken when the step then explains its picture this much better
#: (0.01 until stop 62: on our pictures a step explained 0.98 has little more to gain).
TIE_GAIN = 0.001
#: CPU seconds each such prediction may take (:attr:`mepnet.stage2.StepContext.budget_s`): a
#: step of many parts on another renderer's picture uses stage 2's whole budget (30 s), and
#: predicting it again in full on a tie cost LeoCAD's F20c set 0.064 s a step on average, more
#: than the rest of the repair together.
TIE_RETRY_BUDGET_S = 3.0
#: The latest steps with ties the retries look at (each retry predicts the step again).
TIE_STEPS = 4
#: The latest steps with ties kept open for later pictures to judge (:func:`_ties_seen`).
TIE_KEPT = 16
#: A tie is judged again by a picture whose view turned at least this many degrees (elevation,
#: azimuth or roll) from every picture it was judged by: from the same side, the parts added
#: since only hide more of what the tie's own picture could not tell apart.
TIE_TURN = 10.0
#: ... and taken when that picture is closer to it (:func:`mepnet.consistency.tie_distances`)
#: by this much.
TIE_SEEN_GAIN = 0.05
#: ... and a tie is tried only where a part it moves (at either place) comes within this many
#: lattice cells (x, y, z: half-studs, plates) of a part the step placed: what a later step
#: can tell about a hidden part is where its own parts meet it.
TIE_NEAR = (2, 3, 2)
#: ... and only where it opens a place to the step's parts: a placement of one of their
#: components among the best this many for the step's changed pixels on the shape with the tie
#: (:func:`mepnet._brickgeom.abys_ranked`) that the shape without it does not allow (a later
#: part's true place collides with a part the tie moves, or needs a stud it turns away; 6
#: until stop 62: F20z manual 6 step 25 is settled with 40, not with 6).
TIE_OPENS = 40


def _box(p: Placement) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """The lattice box a placement fills."""
    return placement_box(p.component, p.yaw, p.t)


def _opens(
    before: _bg.Assembly,
    shape: _bg.Assembly,
    new: list[Placement],
    changed: np.ndarray,
    view: tuple[_bg.Camera, int, int],
) -> bool:
    """Whether the shape ``shape`` (a tie taken) allows one of the components of ``new`` (the
    step's placements) a place among the :data:`TIE_OPENS` best for the ``changed`` pixels
    that the shape ``before`` does not."""
    camera, w, h = view
    seen: set[str] = set()
    for p in new:
        if p.component.name in seen:
            continue
        seen.add(p.component.name)
        ranked, _ = _bg.abys_ranked(shape, camera, w, h, p.component, changed, TIE_OPENS, 1.0)
        poses = np.array([[yaw, *t] for yaw, t, _ in ranked], np.int64).reshape(-1, 4)
        if (before.check_many(p.component, poses) < 0).any():
            return True
    return False


def _near(
    a: tuple[tuple[int, int, int], tuple[int, int, int]],
    b: tuple[tuple[int, int, int], tuple[int, int, int]],
) -> bool:
    """Whether the boxes ``a`` and ``b`` (:func:`_box`) come within :data:`TIE_NEAR`."""
    (alo, ahi), (blo, bhi) = a, b
    return all(max(alo[i] - bhi[i], blo[i] - ahi[i]) <= TIE_NEAR[i] for i in range(3))


Finished = tuple[list[Prediction], list["Placed | None"], list[Placement], _bg.Assembly, StepCheck]


def _tie_placements(
    placements: list[Placement],
    s: StepRun,
    alt: list[tuple[int, int, tuple[int, int, int]]],
) -> list[Placement] | None:
    """``placements`` with step ``s``'s replaced by the solution ``alt`` ((page entry, yaw,
    translation) per instance, in the order it was solved): each instance takes a prediction
    of its entry, one it leaves in place first; None when the two do not match."""
    mine = [p for p in placements if p.step == s.index]
    free = list(mine)
    chosen: list[Placement | None] = []
    for e, yaw, t in alt:
        hit = next(
            (
                p
                for p in free
                if s.predictions[p.pred].entry == e
                and p.component.same_placement(p.yaw, p.t, yaw, t)
            ),
            None,
        )
        if hit is not None:
            free.remove(hit)
        chosen.append(hit)
    block = []
    for (e, yaw, t), hit in zip(alt, chosen, strict=True):
        if hit is None:
            hit = next((p for p in free if s.predictions[p.pred].entry == e), None)
            if hit is None:
                return None
            free.remove(hit)
        block.append(dataclasses.replace(hit, yaw=yaw, t=tuple(t)))
    if free or len(block) != len(mine):
        return None
    at = placements.index(mine[0])
    rest = [p for p in placements if p.step != s.index]
    return rest[:at] + block + rest[at:]


def _try_ties(
    run: BuildRun,
    open_ties: list[tuple[int, list[list[tuple[int, int, tuple[int, int, int]]]]]],
    placements: list[Placement],
    done: Finished,
    view: tuple[_bg.Camera, int, int],
    again: Callable[[_bg.Assembly], Finished],
) -> tuple[
    list[Prediction],
    list[Placed | None],
    list[Placement],
    _bg.Assembly,
    StepCheck,
    list[Placement],
    list[Revision],
]:
    """A step explained worse than :data:`TIE_RETRY_BELOW` predicted again (``again``, on a
    shape) on each open tie of an earlier step (latest first) that moves a part near one the
    step placed (:data:`TIE_NEAR`) and opens a place to the step's parts where its picture
    changed (:func:`_opens`; ``view``: the step's camera and image size): the first that
    explains the step better by :data:`TIE_GAIN` is taken, the earlier step's predictions
    revised.
    ``done``: the step as predicted; ``placements``: the plan before it. Returns the step's
    (possibly new) predictions, what they placed, its new placements, the shape after it and
    its check, the plan's placements before it, and the revisions."""
    preds, placed, new, built, checked = done
    if checked.confidence is None or checked.confidence >= TIE_RETRY_BELOW:
        return preds, placed, new, built, checked, placements, []
    k = len(run.steps) + 1
    placed_boxes = [_box(b) for b in new]  # the step's parts
    before: _bg.Assembly | None = None  # the shape before the step
    for n in range(len(open_ties) - 1, max(len(open_ties) - TIE_STEPS, 0) - 1, -1):
        j, alts = open_ties[n]
        s = run.steps[j - 1]
        mine = {(p.pred, p.yaw, p.t) for p in placements if p.step == j}
        for alt in alts:
            trial = _tie_placements(placements, s, alt)
            if trial is None:
                continue
            theirs = {(p.pred, p.yaw, p.t) for p in trial if p.step == j}
            # the tie's parts that move, at either place
            moving = [
                p
                for p in placements + trial
                if p.step == j
                and ((p.pred, p.yaw, p.t) in mine) != ((p.pred, p.yaw, p.t) in theirs)
            ]
            moved = [_box(p) for p in moving]
            if not any(_near(a, b) for a in moved for b in placed_boxes):
                continue
            shape = build_placements(trial)
            if shape is None:
                continue
            if before is None:
                before = build_placements(placements)
            if checked.changed is not None and not _opens(
                before, shape, new, checked.changed, view
            ):
                continue
            try:
                result = again(shape)
            except (MepnetError, BrickGeomError):
                continue
            check = result[4]
            if check.confidence is None or check.confidence < checked.confidence + TIE_GAIN:
                continue
            revisions = _revise(s, trial, k, (checked.unexplained, check.unexplained))
            del open_ties[n]
            return (*result, trial, revisions)  # type: ignore[return-value]
    return preds, placed, new, built, checked, placements, []


#: Whether a step whose picture moved an earlier part (:func:`mepnet.consistency.repair`) and
#: that it explains worse than :data:`TIE_RETRY_BELOW` is predicted again on the shape as
#: revised, the new prediction taken when it explains the step better by :data:`TIE_GAIN`
#: (:func:`_again_after_repair`).
AGAIN_AFTER_REPAIR = True


def _again_after_repair(
    s: StepRun,
    placements: list[Placement],
    again: Callable[[_bg.Assembly], Finished],
    base: _bg.Assembly,
) -> tuple[list[Placement], _bg.Assembly, list[Revision]]:
    """The latest step ``s`` predicted again (``again``, on a shape) on the shape before it as
    the plan now has it (``placements``: the plan, the step's placements last; ``base``: the
    shape after it), when it explains its picture worse than :data:`TIE_RETRY_BELOW`; the new
    prediction replaces the step's when it explains the picture better by :data:`TIE_GAIN`.
    Returns the plan's placements, the shape after the step and the revisions of the step's
    own instances (each new placement against the old one of its entry it replaced)."""
    checked = s.check
    if checked is None or checked.confidence is None or checked.confidence >= TIE_RETRY_BELOW:
        return placements, base, []
    earlier = [p for p in placements if p.step < s.index]
    before = build_placements(earlier)
    if before is None:
        return placements, base, []
    try:
        preds, placed, new, built, check = again(before)
    except (MepnetError, BrickGeomError):
        return placements, base, []
    if check.confidence is None or check.confidence < checked.confidence + TIE_GAIN:
        return placements, base, []
    check.changed = None
    # each new placement against an old one of its entry: the same pose first, else the
    # first left of that entry
    free = [(j, s.predictions[j].entry, pl) for j, pl in enumerate(s.placed) if pl is not None]
    revisions = []
    for j, (p, pl) in enumerate(zip(preds, placed, strict=True)):
        if pl is None:
            continue
        same = next((o for o in free if o[1] == p.entry and o[2][1:3] == pl[1:3]), None)
        if same is not None:
            free.remove(same)
            continue
        other = next((o for o in free if o[1] == p.entry), None)
        if other is not None:
            free.remove(other)
            revisions.append(
                Revision(
                    s.index,
                    j,
                    (other[2][1], other[2][2]),
                    (pl[1], pl[2]),
                    s.index,
                    (checked.unexplained, check.unexplained),
                )
            )
        preds[j] = dataclasses.replace(p, extra={**p.extra, "revised_at": s.index})
    s.predictions, s.placed, s.check = preds, placed, check
    return earlier + new, built, revisions


def _revise(
    s: StepRun, trial: list[Placement], k: int, disagreement: tuple[int, int]
) -> list[Revision]:
    """Step ``s``'s predictions take the poses its placements have in ``trial`` (a tie taken,
    found at step ``k``); returns the revisions made."""
    revisions = []
    for p in trial:
        if p.step != s.index:
            continue
        old = s.placed[p.pred]
        if old is None or (old[1], old[2]) == (p.yaw, p.t):
            continue
        revisions.append(Revision(s.index, p.pred, (old[1], old[2]), (p.yaw, p.t), k, disagreement))
        q = s.predictions[p.pred]
        s.predictions[p.pred] = dataclasses.replace(
            q, yaw=p.yaw, t=p.t, extra={**q.extra, "revised_at": k}
        )
        s.placed[p.pred] = (old[0], p.yaw, p.t, old[3])
    return revisions


def _view(camera: _bg.Camera) -> tuple[float, float, float]:
    """The direction a camera looks from: elevation, azimuth, roll (degrees)."""
    return (camera.elevation, camera.azimuth, camera.roll)


def _turn(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    """The largest difference (degrees) between two views' elevations, azimuths and rolls."""
    return max(abs((x - y + 180.0) % 360.0 - 180.0) for x, y in zip(a, b, strict=True))


def _ties_seen(
    run: BuildRun,
    open_ties: list[tuple[int, list[list[tuple[int, int, tuple[int, int, int]]]]]],
    judged: dict[int, list[tuple[float, float, float]]],
    placements: list[Placement],
    camera: _bg.Camera,
    picture: np.ndarray,
) -> tuple[list[Placement], list[Revision]]:
    """Each open tie (latest first) judged by the latest step's picture (``camera``,
    ``picture``) when it looks from a side none of the tie's pictures so far did (``judged``:
    the views each tie's step has been judged from, this one added; :data:`TIE_TURN`): where
    the plan drawn with a tie taken differs from the plan as it is (:func:`tie_distances`),
    the tie is taken when the picture is closer to it by :data:`TIE_SEEN_GAIN` (the earlier
    step's predictions revised; the step's ties closed), dropped when farther by as much;
    a tie the plan no longer allows is dropped. Returns the plan's placements and the
    revisions."""
    view = _view(camera)
    k = len(run.steps)
    shape: _bg.Assembly | None = None
    revisions: list[Revision] = []
    for n in range(len(open_ties) - 1, -1, -1):
        j, alts = open_ties[n]
        seen = judged.setdefault(j, [])
        if any(_turn(view, v) < TIE_TURN for v in seen):
            continue
        seen.append(view)
        s = run.steps[j - 1]
        shape = build_placements(placements) if shape is None else shape
        if shape is None:
            break
        left = []
        for alt in alts:
            trial = _tie_placements(placements, s, alt)
            other = None if trial is None else build_placements(trial)
            if trial is None or other is None:
                continue  # the plan since does not allow it
            far = tie_distances(picture, shape, other, camera)
            if far is None:
                left.append(alt)
            elif far[1] < far[0] - TIE_SEEN_GAIN:
                revisions += _revise(s, trial, k, (round(far[0] * far[2]), round(far[1] * far[2])))
                placements, shape, left = trial, other, []
                break
            elif far[1] <= far[0] + TIE_SEEN_GAIN:
                left.append(alt)
        if left:
            open_ties[n] = (j, left)
        else:
            del open_ties[n]
    return placements, revisions


#: A camera check this good ends the search over a step's camera hypotheses.
EXPLAINED_IOU, EXPLAINED_AGREE = 0.9, 0.8
#: Over a base of at most :data:`mepnet.cameras.SMALL_BASE` components only a check this good
#: ends it: such a base says little, so a passable check is no proof (a 1x1 plate wholly
#: hidden under the 2x2 tile put on it is explained on 84% of the picture at the previous
#: step's zoom with the tile beside the plate; the tile and the camera searched together
#: explain all of it).
EXPLAINED_SMALL_IOU, EXPLAINED_SMALL_AGREE = 0.95, 0.9
#: In a style whose checks agree less than mepnet's own pictures (:class:`PageStyle`), a step
#: is explained at their median agreement less this (over a small base: at their median).
STYLE_MARGIN = 0.05
#: A later hypothesis replaces the best so far only when its check scores this much more
#: (near ties keep the order: the view the previous step was drawn from first).
BETTER = 0.02
#: A turned or searched view's check must beat a carried one's by this much.
UNLIKELY = 0.1
#: A first step's prior view whose check (fitted to the predicted step) agrees or overlaps less
#: than this explains nothing: the step fails.
POOR = 0.5
#: Camera hypotheses predicted with at most, per step.
MAX_HYPOTHESES = 4
#: No further camera hypothesis is predicted with once a step's predictions took this long
#: (CPU seconds, as stage 2's own budget, which bounds each prediction).
HYPOTHESES_BUDGET_S = 60.0
#: A first step is predicted again when fitting the camera to its predicted shape moved it
#: more than this (pixels, RMS over the shape).
REPREDICT_PX = 0.5


def _trial_shape(
    base: _bg.Assembly,
    preds: list[Prediction],
    components: dict[ComponentRef, _bg.Component],
    page_step: Any,
) -> _bg.Assembly:
    """The base with the predicted components added in their callout colours (those that
    fit)."""
    shape = base.copy()
    for p in preds:
        if p.placed and p.failure is None:
            try:
                colour = page_step.components[p.entry].colour
                shape.add(components[p.component], p.yaw, p.t, colour)
            except BrickGeomError:
                pass
    return shape


def _estimated_camera_step(
    cameras: BuildCameras,
    predict: Callable[[Any], tuple[list[Prediction], float]],
    page_step: Any,
    base: _bg.Assembly,
    components: dict[ComponentRef, _bg.Component],
    teacher_forced: bool,
) -> tuple[list[Prediction], float, CameraEstimate]:
    """Predict a step whose page states no camera (:mod:`mepnet.cameras`): with each camera
    hypothesis in turn until the camera and the predicted shape explain the picture (the best
    kept); a first step is predicted again with the camera fitted to its predicted shape.
    Returns the predictions, the predictor's seconds and the camera used. A camera that
    cannot be estimated fails every component of the step with the reason."""
    seconds = 0.0
    spent = 0.0  # camera estimation: every hypothesis made and checked
    cpu = 0.0  # CPU seconds of the predictions (:data:`HYPOTHESES_BUDGET_S`)
    best: tuple[float, list[Prediction], CameraEstimate, Any, _bg.Assembly, bool] | None = None
    for tried, est in enumerate(cameras.hypotheses(page_step, base, components, teacher_forced)):
        spent += est.seconds
        if est.failure is not None or tried == MAX_HYPOTHESES:
            if best is None:
                est = dataclasses.replace(est, seconds=spent)
                cameras.accept(page_step, est, None)
                preds = [
                    Prediction(e, c.component, None, None, failure=est.failure)
                    for e, c in enumerate(page_step.components)
                    for _ in range(c.count)
                ]
                return preds, seconds, est
            break
        unverified = est.fit is None  # a first step's prior view: judged by its check
        explained = False
        for again in (False, True):
            cpu0 = time.process_time()
            preds, s = predict(dataclasses.replace(page_step, camera=est.step_camera()))
            seconds += s
            cpu += time.process_time() - cpu0
            t0 = time.perf_counter()
            shape = _trial_shape(base, preds, components, page_step)
            fit = cameras.check(page_step, shape, est)
            spent += time.perf_counter() - t0
            score = -1.0 if fit is None else fit.iou + fit.agree
            if est.how in ("turned", "searched") or est.how.endswith("(weak)"):
                score -= UNLIKELY  # a turned, searched or weak view needs clearly better evidence
            # (predicted again with the camera fitted to the step: kept unless clearly worse)
            if (
                best is None
                or score > best[0] + (0.0 if again else BETTER)
                or (again and score >= best[0] - 0.02)
            ):
                best = (score, preds, est, fit, shape, unverified)
            style = cameras.style
            explained = fit is not None and (
                fit.iou >= EXPLAINED_SMALL_IOU
                and fit.agree >= style.explained(EXPLAINED_SMALL_AGREE, 0.0)
                if len(base) <= SMALL_BASE
                else fit.iou >= EXPLAINED_IOU
                and fit.agree >= style.explained(EXPLAINED_AGREE, STYLE_MARGIN)
            )
            # the camera fitted to the predicted step moved: predicted again with it
            if again or fit is None or fit.moved_px <= REPREDICT_PX:
                break
            est = dataclasses.replace(est, camera=fit.camera, fit=fit.agree)
        if explained or cpu >= HYPOTHESES_BUDGET_S:
            break
    assert best is not None
    _, preds, est, fit, shape, unverified = best
    est = dataclasses.replace(est, seconds=spent)
    if unverified and (fit is None or fit.iou < POOR or fit.agree < POOR):
        # nothing the callout shows explains the picture
        why = "the predicted step does not explain the picture" + (
            "" if fit is None else f" ({100 * fit.agree:.0f}% of its pixels agree)"
        )
        est = dataclasses.replace(
            est, camera=None, failure=f"camera could not be estimated: {why}", how="failed"
        )
        preds = [
            Prediction(e, c.component, None, None, failure=est.failure)
            for e, c in enumerate(page_step.components)
            for _ in range(c.count)
        ]
        fit = None
    cameras.accept(page_step, est, fit, shape)
    return preds, seconds, est


def run_manual(
    manual: Manual,
    predictor: Predictor,
    teacher_forced: bool = False,
    on_step: Callable[[], None] | None = None,
    repair: bool = True,
) -> ManualRun:
    """Run ``predictor`` over every build of ``manual``: submodules first, then the main model.
    Autoregressive (default): every step on the predictor's own earlier placements, a
    submodule used as the shape its own steps built. ``teacher_forced``: every step on the true
    shape, submodules as they truly are (needs the answers). ``on_step`` is called after every
    step (progress bars). ``repair`` (autoregressive only): after every step, earlier
    placements its picture contradicts are re-placed (:func:`mepnet.consistency.repair`), and
    a step explained poorly is predicted again on each tie of the latest earlier steps
    (solutions their pictures could not tell apart, :data:`TIE_RETRY_BELOW`)."""
    if teacher_forced:
        from mepnet.manual import answers_of

        components = answers_of(manual).components(manual)
    else:
        components = manual.primitive_components()
    runs = []
    style = PageStyle()
    with shared_changes():  # a step's change map computed once for its prediction and check
        for key, _ in manual.builds():
            run = run_build(
                predictor, manual, key, components, teacher_forced, on_step, repair, style
            )
            runs.append(run)
            if key is not None and not teacher_forced:
                placed = run.placed()
                if placed:
                    components[ComponentRef(submodule=key)] = submodule_from_placed(
                        run.name, [(components[r], y, t, c) for r, y, t, c in placed]
                    )
    return ManualRun(manual, predictor.name, teacher_forced, runs, components)


# ---------------------------------------------------------------------------------------------
# The plan as files


def _ref_json(ref: ComponentRef, manual: Manual) -> dict[str, Any]:
    if ref.part is not None:
        return {"part": ref.part}
    return {"submodule": ref.submodule, "name": manual.submodules[int(ref.submodule)].name}  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------
# Scoring against the answers, up to the frame when cameras were estimated (mepnet.frames)


def frame_free(b: BuildRun) -> bool:
    """Whether the build's frame is the convention's: its first step's camera was estimated
    (then the plan is compared with the truth up to a rigid lattice motion, :mod:`mepnet.frames`)."""
    first = b.steps[0].camera if b.steps else None
    return first is not None and first.source == "estimated"


def predicted_placements(run: ManualRun, s: StepRun) -> list[Any]:
    """A step's placed components ``(component, yaw, t, colour)``, as predicted."""
    return [(run.components[r], y, t, c) for r, y, t, c in (p for p in s.placed if p is not None)]


def _true(run: ManualRun, s: StepRun) -> list[Any]:
    assert s.truth is not None
    comps = run.manual.answers.components(run.manual)
    return [(comps[i.component], i.yaw, i.t, i.colour) for i in s.truth.placed()]


#: Most voted motions of a build tried beside its first step's alignments.
MOTION_CANDIDATES = 8


def step_motion(run: ManualRun, b: BuildRun, s: StepRun) -> Motion:
    """The motion taking a step's predictions into the truth's frame: the identity with the
    cameras the manual states; with estimated ones, autoregressive: one motion per build (from
    those aligning a first-step prediction with a true first-step instance and those most
    predicted placements of the build vote for, the one under which most of the build is
    right); teacher-forced: for the first step the best such motion, for
    a later step the identity or a motion mapping the true base onto itself, whichever makes
    more of the step right (a symmetric base looks the same either way)."""
    if s.truth is None or not frame_free(b):
        return IDENTITY
    key = (b.key, 0 if not run.teacher_forced else s.index)
    if key in run.motions:
        return run.motions[key]
    first = b.steps[0]
    if not run.teacher_forced:
        pairs = [
            (predicted_placements(run, x), _true(run, x)) for x in b.steps if x.truth is not None
        ]
        # the first step's alignments, and the motions most pairs of a predicted and a true
        # placement of any step vote for (a first part hidden under the second leaves its
        # position under it free: the rest of the build is then right under another motion)
        votes: dict[Motion, int] = {}
        for pred, true in pairs:
            for m in candidate_motions(pred, true)[1:]:
                votes[m] = votes.get(m, 0) + 1
        candidates = candidate_motions(predicted_placements(run, first), _true(run, first))
        candidates += sorted(votes, key=lambda m: -votes[m])[:MOTION_CANDIDATES]
        best, hits = IDENTITY, -1
        for m in dict.fromkeys(candidates):
            h = sum(matches(pred, true, m) for pred, true in pairs)
            if h > hits:
                best, hits = m, h
        motion = best
    elif s.index == 1:
        pred, true = predicted_placements(run, s), _true(run, s)
        motion, _ = best_motion(pred, true, candidate_motions(pred, true))
    else:
        pred, true = predicted_placements(run, s), _true(run, s)
        ident = matches(pred, true)
        motion = IDENTITY
        if pred and ident < len(true):
            before = [x for y in b.steps[: s.index - 1] for x in _true(run, y)]
            motion, hits = best_motion(pred, true, [IDENTITY, *symmetries(before)])
    run.motions[key] = motion
    return motion


def correct(run: ManualRun, step: StepRun, p: Prediction, b: BuildRun | None = None) -> bool | None:
    """Whether a prediction equals one of its step's true placements (None without answers);
    ``b``: the step's build, when the comparison is up to the frame (:func:`step_motion`)."""
    if step.truth is None or not p.placed:
        return None if step.truth is None else False
    if b is not None and frame_free(b):
        motion = step_motion(run, b, step)
        colour = b.build.steps[step.index - 1].components[p.entry].colour
        mine = placement_key(moved((run.components[p.component], p.yaw, p.t, colour), motion))  # type: ignore[arg-type]
        return mine in {placement_key(x) for x in _true(run, step)}
    comp = run.components[p.component]
    return any(
        i.component == p.component and comp.same_shape(i.yaw, i.t, p.yaw, p.t)
        for i in step.truth.placed()
    )


def step_matches(run: ManualRun, step: StepRun, build: BuildRun | None = None) -> int:
    """How many of the step's true instances a prediction of the step places exactly (one
    prediction per instance; rotation modulo symmetry); 0 without answers. ``build``: the
    step's build (found in ``run`` when not given; a step made up from one of its steps, a
    solution tried in its place, needs it)."""
    if step.truth is None:
        return 0
    if build is None:
        build = next((b for b in run.builds if any(x is step for x in b.steps)), None)
    if build is not None and frame_free(build):
        return matches(
            predicted_placements(run, step), _true(run, step), step_motion(run, build, step)
        )
    used: set[int] = set()
    hits = 0
    for inst in step.truth.placed():
        comp = run.components.get(inst.component)
        for j, p in enumerate(step.predictions):
            if (
                j not in used
                and comp is not None
                and p.component == inst.component
                and p.placed
                and p.failure is None
                and comp.same_shape(inst.yaw, inst.t, p.yaw, p.t)
            ):
                used.add(j)
                hits += 1
                break
    return hits


def accuracy(run: ManualRun) -> tuple[int, int]:
    """``(right, total)``: the true instances of every step of every build that the run placed
    exactly (:func:`step_matches`), and how many there are."""
    right = sum(step_matches(run, s) for b in run.builds for s in b.steps)
    total = sum(len(s.truth.placed()) for b in run.builds for s in b.steps if s.truth is not None)
    return right, total


def same_shape(
    a: list[tuple[_bg.Component, int, tuple[int, int, int], int]],
    b: list[tuple[_bg.Component, int, tuple[int, int, int], int]],
) -> bool:
    """Whether two sets of placed components are the same shape: brick for brick (submodules
    expanded) the same part and colour at the same placement (``Component.same_shape``: voxels,
    connection points and side studs, so a symmetric part placed either way is the same and a
    slope or a side stud turned is not; nor is which way 2877's grille faces, as the scores)."""
    if not a or not b:
        return not a and not b
    bricks_a = submodule_from_placed("shape", a).bricks
    bricks_b = submodule_from_placed("shape", b).bricks
    if len(bricks_a) != len(bricks_b):
        return False
    left: dict[tuple[str, int], list[tuple[int, tuple[int, int, int]]]] = {}
    for part, yaw, t, colour in bricks_b:
        left.setdefault((part, colour), []).append((yaw, tuple(t)))  # type: ignore[arg-type]
    prims: dict[str, _bg.Component] = {}
    for part, yaw, t, colour in bricks_a:
        prim = prims.setdefault(part, _bg.Component.primitive(part))
        cands = left.get((part, colour), [])
        j = next((j for j, (y, u) in enumerate(cands) if prim.same_shape(yaw, t, y, u)), None)
        if j is None:
            return False
        cands.pop(j)
    return True


def built_exactly(run: ManualRun) -> bool | None:
    """Whether the final model the run built is the true one (:func:`same_shape`: parts,
    colours and placements, every submodule expanded); None without answers."""
    answers = run.manual.answers
    if answers is None:
        return None
    truth_comps = answers.components(run.manual)
    truth = [(truth_comps[i.component], i.yaw, i.t, i.colour) for i in answers.main.instances]
    built = [(run.components[r], y, t, c) for r, y, t, c in run.main.placed()]
    if frame_free(run.main) and run.main.steps:
        motion = step_motion(run, run.main, run.main.steps[0])
        built = [moved(x, motion) for x in built]
    return same_shape(built, truth)


def _ldu(yaw: int, t: tuple[int, int, int]) -> dict[str, Any]:
    """A placement in LDraw's frame, as plan.json gives it."""
    pos, mat = ldraw_placement(yaw, t)
    return {"position": pos, "matrix": mat}


def plan_json(run: ManualRun) -> dict[str, Any]:
    """The plan document (``plan.json``)."""
    manual = run.manual

    def steps(b: BuildRun) -> list[dict[str, Any]]:
        out = []
        for s in b.steps:
            records = []
            for p, pl in zip(s.predictions, s.placed, strict=True):
                rec: dict[str, Any] = {
                    "component": _ref_json(p.component, manual),
                    "colour": b.build.steps[s.index - 1].components[p.entry].colour,
                    "attach": p.attach,
                    "failure": p.failure,
                }
                if pl is not None:
                    rec.update(yaw=pl[1], lattice=list(pl[2]), ldu=_ldu(pl[1], pl[2]))
                    err = p.extra.get("error_px")
                    rec["confidence"] = float(np.exp(-err / 2.0)) if err is not None else None
                ok = correct(run, s, p, b)
                if ok is not None:
                    rec["correct"] = ok
                records.append(rec)
            rec_step: dict[str, Any] = {"index": s.index, "image": s.image, "seconds": s.seconds}
            if s.camera is not None:
                rec_step.update(s.camera.to_json())
            if s.check is not None:
                rec_step.update(confidence=s.check.confidence, flags=s.check.flags)
            rec_step["revisions"] = [
                {
                    "step": r.step,
                    "component": _ref_json(
                        b.steps[r.step - 1].predictions[r.pred].component, manual
                    ),
                    "before": {"yaw": r.before[0], "lattice": list(r.before[1])},
                    "after": {"yaw": r.after[0], "lattice": list(r.after[1])},
                    "disagreement_px": list(r.disagreement),
                }
                for r in s.revisions
            ]
            rec_step["components"] = records
            if s.alternatives:
                rec_step["alternatives"] = [
                    [
                        {"index": x, "yaw": yaw, "lattice": list(t), "ldu": _ldu(yaw, t)}
                        for x, yaw, t in alt
                    ]
                    for alt in s.alternatives
                ]
            out.append(rec_step)
        return out

    recs = [c for b in run.builds for s in steps(b) for c in s["components"]]
    doc: dict[str, Any] = {
        "schema": PLAN_SCHEMA,
        "version": 1,
        "manual": str(manual.path),
        "predictor": run.predictor,
        "units": {
            "lattice": "x, z half-studs (10 LDU), y plates (8 LDU), y up",
            "ldu": "LDraw frame, y down",
        },
        "submodules": [{"name": b.name, "steps": steps(b)} for b in run.builds[:-1]],
        "steps": steps(run.main),
        "components": len(recs),
        "placed": sum(1 for c in recs if c.get("lattice") is not None),
    }
    if manual.answers is not None:
        right, _ = accuracy(run)
        doc["correct"] = right
        doc["exact"] = built_exactly(run)
    return doc


def plan_ldraw(run: ManualRun) -> LDrawFile:
    """The plan as an LDraw file: the main model, one submodel per submodule, one step per
    manual step."""

    def model(b: BuildRun, name: str) -> LDrawModel:
        out_steps = []
        for s in b.steps:
            refs = []
            for ref, yaw, t, colour in (pl for pl in s.placed if pl is not None):
                pos, mat = ldraw_placement(yaw, t)
                is_sub = ref.part is None
                refs.append(
                    LDrawRef(
                        name=f"{ref.part}.dat"
                        if not is_sub
                        else run.manual.submodules[int(ref.submodule)].name.lower(),  # type: ignore[arg-type]
                        colour=colour,
                        position=pos,
                        matrix=mat,
                        is_submodel=is_sub,
                    )
                )
            if refs:
                out_steps.append(refs)
        return LDrawModel(name=name, steps=out_steps, title=f"mepnet plan: {name}")

    models = [model(run.main, "main.ldr")] + [model(b, b.name.lower()) for b in run.builds[:-1]]
    return LDrawFile(name="plan.mpd", models=models)


def overlay(
    image: np.ndarray,
    placed_new: list[tuple[_bg.Component, int, tuple[int, int, int]]],
    camera: _bg.Camera,
) -> np.ndarray:
    """The manual image with the predicted new components outlined in magenta and tinted."""
    h, w = image.shape[:2]
    asm = _bg.Assembly()
    for comp, yaw, t in placed_new:
        try:
            asm.add(comp, yaw, t)
        except BrickGeomError:
            pass
    out = image.copy()
    if len(asm) == 0:
        return out
    mask = _bg.render(asm, camera, w, h, line_px=0).ids >= 0
    tint = np.array([255, 0, 255], dtype=np.float32)
    out[mask] = (0.6 * out[mask] + 0.4 * tint).astype(np.uint8)
    edge = mask & ~(
        np.roll(mask, 1, 0) & np.roll(mask, -1, 0) & np.roll(mask, 1, 1) & np.roll(mask, -1, 1)
    )
    out[edge] = (255, 0, 255)
    return out


#: The writer name in the manifest of plan folders (:mod:`mepnet.files`).
PLAN_WRITER = "mepnet.infer"


def write_plan(run: ManualRun, out: str | os.PathLike[str]) -> dict[str, Any]:
    """Write plan.json, plan.mpd and overlays to the folder ``out`` atomically (an existing
    ``out`` is replaced only when it is an earlier plan folder nobody added to). Returns the
    plan document."""
    from PIL import Image

    from mepnet.report import write_report

    plan = plan_json(run)
    with atomic_folder(out, PLAN_WRITER) as tmp:
        write_ldraw(tmp / "plan.mpd", plan_ldraw(run))
        (tmp / "plan.json").write_text(json.dumps(plan, indent=1) + "\n")
        for b in run.builds:
            prefix = (
                "" if b.key is None else "".join(c if c.isalnum() else "_" for c in b.name) + "_"
            )
            for s, step in zip(b.steps, b.build.steps, strict=True):
                new = [(run.components[r], y, t) for r, y, t, _ in (p for p in s.placed if p)]
                cam = s.camera.camera if s.camera is not None else step.camera_object()
                img = step.image() if cam is None else overlay(step.image(), new, cam)
                Image.fromarray(img).save(tmp / f"{prefix}overlay_{s.index:03d}.png")
        write_report(tmp, plan, run.manual, run.components)  # report.html, beside the overlays
    return plan
