"""How well a predicted step explains its picture: a confidence per step and flags for what
nothing explains (issue 14's plan checks).

The confidence of a step is the overlap (IoU) between the pixels its predicted components
cover, drawn over the shape built so far with the step's camera, and the pixels where the
step's picture changed (:func:`mepnet.stage2.synthesis.step_change`: against the manual's own
earlier pictures of the same view where there are any, else against the base as mepnet draws
it). 1 when the predicted parts cover exactly what changed; low when the picture shows new parts
where nothing was placed, or parts were placed where the picture shows nothing new.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.errors import MepnetError
from mepnet.geom import BrickGeomError
from mepnet.stage2.base import Prediction, StepContext
from mepnet.stage2.synthesis import (
    PAGE_LIKE,
    _max_filter,
    drawn_differ,
    edge_map,
    silhouette,
    step_change,
    step_picture,
)
from mepnet.state import CHANGE_THRESHOLD

#: A step whose confidence is below this is flagged: its picture is not explained.
UNEXPLAINED = 0.5


@dataclass
class StepCheck:
    """A step's confidence (None: it could not be checked) and flags."""

    confidence: float | None
    flags: list[str] = field(default_factory=list)
    #: pixels changed where no placed part is drawn, or drawn where nothing changed
    unexplained: int = 0
    #: (H, W) bool: where the picture changed (None: not checked); kept for the tie retries of
    #: :mod:`mepnet.plan`, not written to the plan
    changed: np.ndarray | None = field(default=None, repr=False, compare=False)


def check_step(ctx: StepContext, preds: list[Prediction], shape: _bg.Assembly) -> StepCheck:
    """The confidence and flags of a predicted step: ``ctx`` the step as it was predicted (its
    base the shape before the step), ``shape`` the shape after it (the base and the placed
    predictions, in that order)."""
    flags = []
    missing = sum(1 for p in preds if not p.placed or p.failure is not None)
    if missing:
        flags.append(f"{missing} of {len(preds)} components not placed")
    if any(p.extra.get("over_budget") for p in preds):
        flags.append("stage 2 ran out of time: its first solution kept, not revisited")
    if ctx.step.camera is None:
        return StepCheck(None, [*flags, "no camera"])
    w, h = ctx.image_size
    if w != h:
        return StepCheck(None, flags)
    try:
        change = step_change(ctx, step_picture(ctx))[0] > CHANGE_THRESHOLD
    except MepnetError:
        return StepCheck(None, flags)
    ids = _bg.render(shape, ctx.camera, w, h, line_px=0.0).ids
    new = ids >= len(ctx.base)
    union = int((new | change).sum())
    confidence = float((new & change).sum() / union) if union else 1.0
    if confidence < UNEXPLAINED:
        flags.append(
            f"the picture is not explained: the placed parts cover {100 * confidence:.0f}% "
            "of what changed"
        )
    return StepCheck(round(confidence, 4), flags, union - int((new & change).sum()), change)


# ---------------------------------------------------------------------------------------------
# Repair: earlier placements that later pictures contradict


#: How far (px) the picture's silhouette is widened before a drawn pixel outside it counts as
#: a contradiction (and narrowed before a pixel inside counts as unexplained).
SILHOUETTE_SLACK = 2
#: An earlier instance is suspect when at least this many of its drawn pixels, and this share
#: of them, lie where the step's picture shows the page.
SUSPECT_PX, SUSPECT_SHARE = 15, 0.2
#: Placements tried per suspect (ranked by their overlap with what is unexplained).
REPAIR_CANDIDATES = 8
#: ... and, for a part of the latest step (:data:`OWN_STEP`), this many ranked by their overlap
#: with the picture's whole silhouette (0: none; symmetric parts' equal yaws each count: 16
#: are 8 placements of a 2x4 plate).
SILHOUETTE_CANDIDATES = 16
#: Pictures a repair is judged on: the suspect's own step and the latest ones.
REPAIR_VIEWS = 4
#: A repair is made when it lowers the pictures' disagreement by this many pixels and share.
REPAIR_GAIN_PX, REPAIR_GAIN_SHARE = 20, 0.1
#: Suspects looked at per step.
REPAIRS_PER_STEP = 2
#: Whether the latest step's own instances may be suspects too: stage 2 placed them to explain
#: where its picture changed, but where the change map misses a part (a dark part on a base of
#: its colour, drawn with no edge lines) it may stand one beside the model, over the page.
OWN_STEP = True


@dataclass(frozen=True)
class Placement:
    """A placed instance of the plan: which step (1-based) and prediction (index in the
    step's predictions) it came from, the component and its pose and colour."""

    step: int
    pred: int
    component: _bg.Component
    yaw: int
    t: tuple[int, int, int]
    colour: int


@dataclass
class View:
    """A step's picture as the repair sees it: the camera and the picture's silhouette,
    widened and narrowed by :data:`SILHOUETTE_SLACK`."""

    step: int
    camera: _bg.Camera
    wide: np.ndarray
    narrow: np.ndarray
    #: the page's colour (RGB 0-255)
    page: np.ndarray

    @classmethod
    def of(cls, step: int, camera: _bg.Camera, rgb: np.ndarray) -> View:
        """The view of a step picture ((H, W, 3) uint8)."""
        fg, page = silhouette(rgb)
        wide = _max_filter(fg.astype(np.uint8), SILHOUETTE_SLACK).astype(bool)
        narrow = ~_max_filter((~fg).astype(np.uint8), SILHOUETTE_SLACK).astype(bool)
        return cls(step, camera, wide, narrow, page)

    def drawn(self, shape: _bg.Assembly, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
        """The shape drawn with the view's camera: its instance map, and where it is drawn in
        colours the page could not be mistaken for (a white part on white paper is told from
        the page only by outlines other renderers may not draw: no evidence either way)."""
        r = _bg.render(shape, self.camera, w, h, line_px=0.0)
        return r.ids, (r.ids >= 0) & self.unlike(r.rgb)

    def unlike(self, rgb: np.ndarray) -> np.ndarray:
        """Where drawn colours ``rgb`` (..., 3) could not be mistaken for the page."""
        return np.abs(rgb.astype(np.float32) - self.page).max(axis=-1) > PAGE_LIKE

    def count(self, drawn: np.ndarray, seen: np.ndarray) -> int:
        """The disagreement of a shape drawn at ``drawn`` (of it, ``seen`` in colours unlike
        the page) with the picture (:func:`disagreement`)."""
        return int((seen & ~self.wide).sum() + (self.narrow & ~drawn).sum())


@dataclass(frozen=True)
class Revision:
    """An earlier placement changed because a later picture contradicted it."""

    #: the step (1-based) whose placement changed, and the prediction's index in it
    step: int
    pred: int
    before: tuple[int, tuple[int, int, int]]
    after: tuple[int, tuple[int, int, int]]
    #: the step whose picture showed the contradiction
    found_at: int
    #: pixels of disagreement over the pictures judged, before and after
    disagreement: tuple[int, int]


def build(placements: list[Placement]) -> _bg.Assembly | None:
    """The shape of ``placements`` added in order, each checked (connected and collision-free
    when it is added); None when one is not valid."""
    asm = _bg.Assembly()
    for p in placements:
        try:
            asm.check(p.component, p.yaw, p.t)
            asm.add(p.component, p.yaw, p.t, p.colour)
        except BrickGeomError:
            return None
    return asm


def disagreement(placements: list[Placement], views: list[View], w: int, h: int) -> list[int]:
    """Per view, the pixels where the plan and the picture disagree: drawn where the picture
    shows the page, or not drawn where it shows the model (the shape as it was after the
    view's step; an invalid shape disagrees everywhere)."""
    out = []
    for v in views:
        shape = build([p for p in placements if p.step <= v.step])
        if shape is None:
            out.append(w * h)
            continue
        ids, seen = v.drawn(shape, w, h)
        out.append(v.count(ids >= 0, seen))
    return out


@dataclass
class _Backdrop:
    """A view drawn without one instance (the shape as it was after the view's step): what
    each placement tried for that instance is drawn over (:meth:`over`)."""

    view: View
    drawn: np.ndarray
    depth: np.ndarray
    seen: np.ndarray

    def over(self, alone: _bg.Assembly, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
        """Where the backdrop's shape with the one part of ``alone`` added is drawn, and where
        in colours unlike the page (:meth:`View.drawn`): the part drawn alone and laid over
        the backdrop where it is in front, the same pixels as drawing the whole shape."""
        r = _bg.render(alone, self.view.camera, w, h, line_px=0.0)
        front = (r.ids >= 0) & (r.depth < self.depth)
        seen = self.seen.copy()
        seen[front] = self.view.unlike(r.rgb[front])
        return self.drawn | (r.ids >= 0), seen


def _backdrops(rest: list[Placement], views: list[View], w: int, h: int) -> list[_Backdrop]:
    """Each view of ``rest`` (valid in the plan's order, so step by step), the shape as it was
    after the view's step: one pass adding the placements, drawn at each view's step."""
    asm = _bg.Assembly()
    n = 0
    out: dict[int, _Backdrop] = {}
    for v in sorted(views, key=lambda v: v.step):
        while n < len(rest) and rest[n].step <= v.step:
            asm.add(rest[n].component, rest[n].yaw, rest[n].t, rest[n].colour)
            n += 1
        r = _bg.render(asm, v.camera, w, h, line_px=0.0)
        out[id(v)] = _Backdrop(v, r.ids >= 0, r.depth, (r.ids >= 0) & v.unlike(r.rgb))
    return [out[id(v)] for v in views]


def _disagreement_with(part: Placement, backdrops: list[_Backdrop], w: int, h: int) -> list[int]:
    """Per backdrop, the disagreement (:func:`disagreement`) of its shape with ``part`` added
    (:meth:`_Backdrop.over`; one part drawn instead of the whole shape)."""
    alone = _bg.Assembly()
    alone.add(part.component, part.yaw, part.t, part.colour)
    out = []
    for b in backdrops:
        if part.step > b.view.step:
            out.append(b.view.count(b.drawn, b.seen))
        else:
            out.append(b.view.count(*b.over(alone, w, h)))
    return out


def suspects(
    ids: np.ndarray, seen: np.ndarray, view: View, placements: list[Placement]
) -> list[int]:
    """Indices into ``placements`` of instances from earlier steps (and, with :data:`OWN_STEP`,
    from the view's own) drawn where ``view``'s picture shows the page (``ids``, ``seen``:
    :meth:`View.drawn` of the shape, ids in placement order), worst first."""
    bad = np.bincount(ids[seen & ~view.wide], minlength=len(placements))
    drawn = np.bincount(ids[ids >= 0], minlength=len(placements))
    out = [
        i
        for i in np.argsort(-bad)
        if bad[i] >= SUSPECT_PX
        and bad[i] >= SUSPECT_SHARE * drawn[i]
        and (placements[i].step < view.step or OWN_STEP)
    ]
    return [int(i) for i in out[:REPAIRS_PER_STEP]]


def repair(
    placements: list[Placement], views: list[View], w: int, h: int
) -> tuple[list[Placement], list[Revision]]:
    """Re-place the instances the latest view's picture contradicts (:func:`suspects`: earlier
    steps', and the latest step's own): each is taken out and the placements that best explain
    what the pictures show and nothing explains (:func:`mepnet._brickgeom.abys_ranked` on the
    latest view and on the suspect's own step; for the latest step's own, also those best
    inside the whole silhouette, :data:`SILHOUETTE_CANDIDATES`) are tried in its place; one
    that keeps every placement valid in order and lowers the disagreement over the suspect's
    own picture and the latest ones (:func:`disagreement`) by :data:`REPAIR_GAIN_PX` pixels
    and :data:`REPAIR_GAIN_SHARE`, without raising it on any of them, replaces it. Returns
    the placements and the revisions made."""
    if not views or not placements:
        return placements, []
    latest = views[-1]
    shape = build(placements)
    if shape is None:
        return placements, []
    ids, seen = latest.drawn(shape, w, h)
    revisions: list[Revision] = []
    for i in suspects(ids, seen, latest, placements):
        sus = placements[i]
        judged = [v for v in views if v.step == sus.step] + [
            v for v in views[-REPAIR_VIEWS + 1 :] if v.step != sus.step
        ]
        rest = placements[:i] + placements[i + 1 :]
        rest_shape = build(rest)
        if rest_shape is None:
            continue  # later parts stand on it: left as it is
        backdrops = _backdrops(rest, judged, w, h)
        before_views = _disagreement_with(sus, backdrops, w, h)
        before = sum(before_views)
        tried: set[tuple[int, tuple[int, int, int]]] = {(sus.yaw, sus.t)}
        best: tuple[int, list[int], Placement] | None = None
        for v in {
            latest.step: latest,
            **{x.step: x for x in judged if x.step == sus.step},
        }.values():
            drawn = _bg.render(rest_shape, v.camera, w, h, line_px=0.0).ids >= 0
            unexplained = v.narrow & ~drawn
            if not unexplained.any():
                continue
            ranked, _ = _bg.abys_ranked(
                rest_shape, v.camera, w, h, sus.component, unexplained, REPAIR_CANDIDATES, 1.0
            )
            if SILHOUETTE_CANDIDATES and sus.step == latest.step:
                # a part of the latest step: also those best inside the whole silhouette (a
                # part laid over parts drawn already, a plate on a brick of its size, adds
                # little that is unexplained; an earlier part so placed explains too readily
                # what a later step's wrong part left unexplained)
                ranked += _bg.abys_ranked(
                    rest_shape, v.camera, w, h, sus.component, v.narrow, SILHOUETTE_CANDIDATES, 1.0
                )[0]
            for yaw, t, _iou in ranked:
                if (yaw, tuple(t)) in tried:
                    continue
                tried.add((yaw, tuple(t)))
                moved = Placement(sus.step, sus.pred, sus.component, yaw, tuple(t), sus.colour)
                trial = placements[:i] + [moved] + placements[i + 1 :]
                if build(trial) is None:
                    continue  # not valid where it stands in the plan's order
                per_view = _disagreement_with(moved, backdrops, w, h)
                if best is None or sum(per_view) < best[0]:
                    best = (sum(per_view), per_view, moved)
        if best is None:
            continue
        after, after_views, moved = best
        # better over the pictures judged, and worse on none of them (the suspect's own step
        # placed it to explain its picture)
        if before - after >= max(REPAIR_GAIN_PX, REPAIR_GAIN_SHARE * before) and all(
            a <= b for a, b in zip(after_views, before_views, strict=True)
        ):
            placements = placements[:i] + [moved] + placements[i + 1 :]
            revisions.append(
                Revision(
                    sus.step,
                    sus.pred,
                    (sus.yaw, sus.t),
                    (moved.yaw, moved.t),
                    latest.step,
                    (before, after),
                )
            )
    return placements, revisions


# ---------------------------------------------------------------------------------------------
# Ties: an earlier step's solutions its picture could not tell apart, seen from a new side


#: A picture tells two shapes apart only where their drawings differ in at least this many
#: pixels.
TIE_SEEN_PX = 12


def tie_distances(
    picture: np.ndarray, a: _bg.Assembly, b: _bg.Assembly, camera: _bg.Camera
) -> tuple[float, float, int] | None:
    """How far the picture ``picture`` ((H, W, 3) uint8) is from the shapes ``a`` and ``b``
    drawn with ``camera``, where the two drawings differ (widened by a pixel): per pixel there,
    the colour residual (the largest channel's, 0-1) plus the edges (:func:`edge_map`) one has
    and the other has not within a pixel (a renderer shows every face's outline as a change of
    colour, whatever its shading). Returns the two distances and the pixels compared; None
    where the drawings differ in fewer than :data:`TIE_SEEN_PX` pixels."""
    h, w = picture.shape[:2]
    ra = _bg.render(a, camera, w, h).rgb
    rb = _bg.render(b, camera, w, h).rgb
    differ = drawn_differ(ra, rb)
    if int(differ.sum()) < TIE_SEEN_PX:
        return None
    region = _max_filter(differ, 1)
    n = int(region.sum())
    pic = picture.astype(np.float32) / 255.0
    edges = edge_map(pic)
    near_edges = _max_filter(edges, 1)
    out = []
    for r in (ra, rb):
        rgb = r.astype(np.float32) / 255.0
        colour = float(np.abs(pic[region] - rgb[region]).max(axis=-1).mean())
        drawn = edge_map(rgb)
        unseen = drawn & ~near_edges & region  # drawn, the picture shows none
        undrawn = edges & ~_max_filter(drawn, 1) & region  # the picture's, not drawn
        out.append(colour + float(unseen.sum() + undrawn.sum()) / n)
    return out[0], out[1], n


__all__ = [
    "UNEXPLAINED",
    "Placement",
    "Revision",
    "StepCheck",
    "View",
    "build",
    "check_step",
    "disagreement",
    "repair",
    "silhouette",
    "suspects",
    "tie_distances",
]
