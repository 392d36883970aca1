"""Stage 2 by synthesis: lift a step's components to 3D by making the picture agree.

For every component type the manual says the step adds, a mask of the pixels that may show it
(the change map between the step's picture and the rendered base shape, optionally narrowed by
the detector), and optionally the detector's per-pixel belief that a pixel shows that type.
Then, until every instance is placed: for each type with instances left, brickgeom ranks every
valid placement (collision-free, connected by studs or standing on the ground) by the IoU of
its visible silhouette with the part of the type's mask not yet explained
(:func:`mepnet._brickgeom.abys_ranked`); the best few are rendered over the current shape in the
colour the manual's callout gives the type and scored

    IoU + TYPE_WEIGHT * mean belief over the visible pixels
        + KEYPOINT_WEIGHT * keypoint heatmap at the projected keypoint
        - COLOUR_WEIGHT * colour residual

(the colour residual: the mean over the candidate's visible pixels of the largest channel
difference between the picture and the render, the render first mapped onto the picture's tones
by the per-channel gain and bias that map the rendered base shape onto the picture: the tone fit
of the change map). The best (type, placement) of all joins the shape and its visible pixels
leave every mask, so the next instance fits the rest.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
import hashlib
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.errors import ManualFormatError
from mepnet.geom import (
    LDU_PER_CELL,
    BrickGeomError,
    component_box,
    placement_box,
    rotate_lattice,
    rotate_ldu,
)
from mepnet.stage2.base import Prediction, Predictor, StepContext
from mepnet.state import (
    CHANGE_THRESHOLD,
    SHADE_LEVELS,
    SHADOW_FACTORS,
    change_map,
    darkening,
    expected_colours,
    fit_tone,
    grown_4,
    previous_change,
    same_view,
    shade_classes,
    shade_factors,
    shade_tones,
    shadowed,
    state_render,
    warp_previous,
)

#: Weight of the detector's type belief (mean over a candidate's visible pixels).
TYPE_WEIGHT = 0.3
#: Weight of the colour residual.
COLOUR_WEIGHT = 1.0
#: Weight of the detector's keypoint heatmap at the candidate's projected keypoint.
KEYPOINT_WEIGHT = 0.3
#: Weight of the edge disagreement of a complete solution (:func:`_explained`), per pixel of
#: the IoU's union, near the step's parts and where the picture changed: the picture's edges
#: that the shape with the step's parts draws nowhere near (with outlines or without) ...
#: Edges are where any renderer's picture changes colour (a face's outline, a slope's crease,
#: a stud), whatever its lines and shading: what tells a part's turn where the silhouette and
#: the colours barely do.
EDGE_WEIGHT = 1.0
#: ... and the edges the shape shows without outlines where the picture has none: weaker
#: evidence, as a renderer may soften a crease (POV-Ray's smooth shading) or shade two faces
#: alike.
SHOWN_EDGE_WEIGHT = 0.5
#: A pixel is an edge where a colour channel's Sobel gradient (colours in [0, 1]) reaches this.
EDGE_THRESHOLD = 0.25
#: Placements per type (best mask IoU first) weighed by colour and type belief.
RANKED = 6
#: Line tolerance (:func:`tolerate_lines`): the band either side of the base's part edges, in
#: pixels; how far a change outside the band reaches into it; and the share of the band that
#: must show isolated changes (lines drawn unlike ours) before the band is discounted.
LINE_BAND, LINE_REACH, LINE_MISMATCH = 1, 2, 0.05


@dataclass
class SynthesisType:
    """What stage 2 knows about one component type (callout entry) of a step."""

    entry: int
    component: _bg.Component
    count: int
    #: (H, W) bool: pixels that may show this type.
    mask: np.ndarray
    #: (H, W) float in [0, 1]: the detector's belief that a pixel shows this type (or None).
    belief: np.ndarray | None = None
    #: (H, W) float in [0, 1]: the detector's keypoint heatmap for this type (or None).
    heat: np.ndarray | None = None


def _keypoint_px(
    comp: _bg.Component, yaw: int, t: tuple[int, int, int], cam: _bg.Camera, w: int, h: int
) -> tuple[float, float]:
    """Pixel of a placed component's keypoint (its first: the anchor stage 2 uses)."""
    world = rotate_ldu(comp.keypoints[0], yaw) + np.array(t) * LDU_PER_CELL
    px, _ = cam.project(world[None], w, h)
    return float(px[0, 0]), float(px[0, 1])


def step_picture(ctx: StepContext) -> np.ndarray:
    """The step image, (H, W, 3) floats in [0, 1]."""
    return ctx.step.image().astype(np.float32) / 255.0


def _max_filter(a: np.ndarray, r: int) -> np.ndarray:
    """The maximum over each pixel's (2r+1)^2 neighbourhood (edges padded; a bool ``a``: ``a``
    widened by ``r`` pixels); along the rows, then the columns."""
    h, w = a.shape
    p = np.pad(a, r, mode="edge")
    rows = p[:, r : r + w].copy()
    for dx in range(2 * r + 1):
        np.maximum(rows, p[:, dx : dx + w], out=rows)
    out = rows[r : r + h].copy()
    for dy in range(2 * r + 1):
        np.maximum(out, rows[dy : dy + h], out=out)
    return out


#: A step of this much (any channel, in [0, 1]) between neighbouring pixels of mepnet's drawing
#: of the base is an edge another renderer may draw as a line (a stud's rim, a face's edge).
EDGE_STEP = 0.08


def drawn_edges(state: np.ndarray) -> np.ndarray:
    """Where mepnet's drawing of the base ((3, H, W) in [0, 1]) steps by :data:`EDGE_STEP`
    between neighbouring pixels: (H, W) bool."""
    dx = np.abs(np.diff(state, axis=2)).max(axis=0) > EDGE_STEP
    dy = np.abs(np.diff(state, axis=1)).max(axis=0) > EDGE_STEP
    out = np.zeros(state.shape[1:], bool)
    out[:, 1:] |= dx
    out[:, :-1] |= dx
    out[1:, :] |= dy
    out[:-1, :] |= dy
    return out


def tolerate_lines(change: np.ndarray, outline: np.ndarray) -> np.ndarray:
    """The change map with the base's outlines discounted when the picture draws its lines
    unlike our renderer (thicker, fainter, blurred): then every part edge of the base reads as
    changed. ``outline``: the base's part outlines and the edges of mepnet's drawing of it
    (:func:`drawn_edges`: stud rims, which other renderers outline). Within
    :data:`LINE_BAND` px of them a pixel keeps its change only as far as a change outside the
    band, or one thicker than a line inside it, reaches it (:data:`LINE_REACH` px: the new part
    it borders or that is drawn over them). Applied only when more than :data:`LINE_MISMATCH`
    of the band shows changes no such part explains, so a picture drawn as we draw keeps its
    map (thin new slivers along old edges included)."""
    band = _max_filter(outline.astype(np.uint8), LINE_BAND).astype(bool)
    if not band.any():
        return change
    # what reaches into the band: changes outside it, and changes thicker than a line within
    # it (they survive narrowing by a pixel: a new part drawn over the base's edges)
    changed = change > CHANGE_THRESHOLD
    thick = ~_max_filter((~changed).astype(np.uint8), 1).astype(bool)
    reach = _max_filter(np.where(thick | ~band, change, 0.0).astype(change.dtype), LINE_REACH)
    isolated = band & changed & (reach <= CHANGE_THRESHOLD)
    if isolated.sum() <= LINE_MISMATCH * band.sum():
        return change
    return np.where(band, np.minimum(change, reach), change)


class Tone(NamedTuple):
    """How a step's picture draws what mepnet renders: per channel the gain and bias of the tone
    fit (:func:`mepnet.state.fit_tone`), and whether its renderer casts shadows (then a colour
    darkened with its hue kept also matches: :func:`_colour_off`)."""

    gain: np.ndarray
    bias: np.ndarray
    shadows: bool = False
    #: per shade level of mepnet's renderer, how much brighter the picture draws faces of that
    #: level (:func:`mepnet.state.shade_factors`, learnt from the previous picture; None: as
    #: rendered)
    factors: np.ndarray | None = None


#: Colours compared as rendered.
PLAIN_TONE = Tone(np.ones(3), np.zeros(3))


def base_shades(
    ctx: StepContext, size: int, tone: np.ndarray
) -> tuple[tuple[np.ndarray, dict[int, np.ndarray]], float, np.ndarray] | None:
    """The base's shade classes seen with the step's camera and their tones
    (:func:`mepnet.state.shade_tones`) learnt from the previous step's picture, which shows the
    base and nothing else (from any view: lighting follows the camera); the share of the
    base's pixels that picture draws in shadow (:func:`mepnet.state.shadowed` against those
    tones, in patches: a line is not a shadow), the evidence that the manual's renderer casts
    shadows; and per shade level the factor that picture draws faces of that level at under
    the step's ``tone`` (:func:`mepnet.state.shade_factors`: one number per level for every
    colour, so that a step's new parts are compared as the renderer lights them). None on a
    build's first step and when the previous step has no camera."""
    if not ctx.earlier or len(ctx.base) == 0:
        return None
    prev = ctx.earlier[-1]
    if prev.step.camera is None or prev.instances != len(ctx.base):
        return None
    seen, _ = state_render(ctx.base, prev.step.camera, size)
    picture = prev.step.image().astype(np.float32).transpose(2, 0, 1) / 255.0
    if picture.shape[1:] != seen.shape[1:]:
        return None
    classes = shade_classes(ctx.base, prev.step.camera, size)
    tones = shade_tones(picture, seen, classes)
    dark = shadowed(picture, expected_colours(picture, seen, None, (classes, tones)))
    dark &= ~_max_filter(~dark, SHADOW_PATCH)  # patches, not lines
    share = float(dark[classes >= 0].mean()) if (classes >= 0).any() else 0.0
    factors = shade_factors(picture, seen, classes, tone)
    here = shade_classes(ctx.base, ctx.step.camera, size)  # type: ignore[arg-type]
    return (here, tones), share, factors


#: Whether :func:`step_change` takes the base drawn darker, hue kept, for a cast shadow and not
#: a change, in manuals whose previous picture shows shadows (:func:`base_shades`).
SHADOWS = True
#: ... shadows on more than this share of the base's pixels in the previous picture.
SHADOW_EVIDENCE = 0.002
#: ... counting a pixel when all within this many pixels of it are in shadow.
SHADOW_PATCH = 1
#: ... the range of brightness (a factor of its colour) a step's part may be drawn at, faces
#: turned from the light and in shadow.
PART_LIGHT = (0.3, 1.2)


#: Change maps kept within :func:`shared_changes` (:func:`step_change`), the oldest first out.
CHANGE_KEPT = 4
_changes: contextvars.ContextVar[OrderedDict[tuple[Any, ...], tuple[np.ndarray, Tone]] | None] = (
    contextvars.ContextVar("mepnet_changes", default=None)
)


@contextlib.contextmanager
def shared_changes() -> Iterator[None]:
    """Within it, :func:`step_change` keeps its latest :data:`CHANGE_KEPT` maps, by everything
    they are computed from (:func:`_change_key`): a plan checks each step
    (:func:`mepnet.consistency.check_step`) on the picture, camera, base and earlier pictures its
    predictor's detections used, and the map is a fifth of a step's time. (Outside, every call
    computes its map: the module's settings, which a caller may change between two calls, are
    not part of the key.)"""
    token = _changes.set(OrderedDict())
    try:
        yield
    finally:
        _changes.reset(token)


def _camera_key(camera: dict[str, Any] | None) -> tuple[float, ...] | None:
    """A step camera dict as a tuple of its numbers."""
    if camera is None:
        return None
    return (
        float(camera["elevation"]),
        float(camera["azimuth"]),
        float(camera["roll"]),
        float(camera["scale"]),
        *(float(v) for v in camera["translation"]),
    )


def _change_key(ctx: StepContext, picture: np.ndarray) -> tuple[Any, ...]:
    """Everything :func:`step_change` reads, as a key: the picture's bytes (a digest), the
    step's camera and callout colours, the base's instances with their colours, and the earlier
    steps (their pictures by path, cameras and instance counts)."""
    digest = hashlib.blake2b(np.ascontiguousarray(picture).tobytes(), digest_size=16).digest()
    base = tuple(
        (c.name, int(yaw), tuple(int(v) for v in t), ctx.base.colour(i))
        for i, c, yaw, t in ctx.base.instances()
    )
    earlier = tuple(
        (str(e.step.image_path), e.step.size, _camera_key(e.step.camera), e.instances)
        for e in ctx.earlier
    )
    colours = tuple(sorted({c.colour for c in ctx.step.components}))
    return (
        digest,
        picture.shape,
        picture.dtype.str,
        ctx.image_size,
        _camera_key(ctx.step.camera),
        colours,
        base,
        earlier,
    )


def step_change(ctx: StepContext, picture: np.ndarray) -> tuple[np.ndarray, Tone]:
    """:func:`_step_change`; within :func:`shared_changes` the same map again for the same
    picture, camera, base and earlier steps. The map returned is the caller's to change."""
    kept = _changes.get()
    if kept is None or CHANGE_KEPT <= 0:
        return _step_change(ctx, picture)
    key = _change_key(ctx, picture)
    hit = kept.get(key)
    if hit is None:
        hit = kept[key] = _step_change(ctx, picture)
        while len(kept) > CHANGE_KEPT:
            kept.popitem(last=False)
    else:
        kept.move_to_end(key)
    return hit[0].copy(), hit[1]


def _step_change(ctx: StepContext, picture: np.ndarray) -> tuple[np.ndarray, Tone]:
    """The change map of a step (:func:`mepnet.state.change_map`, lines tolerated by
    :func:`tolerate_lines`): where its ``picture`` (H, W, 3 floats in [0, 1], the manual's
    image size) differs from the base shape rendered with the step's camera, and, where the
    manual's own earlier picture of the view shows the base, from that picture (no change
    where it explains the pixel; a change where it differs over a solid area by more than
    :data:`PREVIOUS_WEAK`); and the tone it compared by (:class:`Tone`: the tone fit and
    whether the renderer casts shadows, for :func:`synthesize`'s colours)."""
    w, h = ctx.image_size
    if w != h:
        raise ManualFormatError(f"{ctx.step.where}: synthesis needs square images, got {w}x{h}")
    ctx.step.camera_object()  # a clear error when the page states no camera
    state, outline = state_render(ctx.base, ctx.step.camera, w)  # type: ignore[arg-type]
    image = picture.transpose(2, 0, 1)
    tone = fit_tone(image, state)
    shades, evidence, factors = base_shades(ctx, w, tone) or (None, 0.0, None)
    change = change_map(image, state, tone, shades)
    shadows = SHADOWS and shades is not None and evidence > SHADOW_EVIDENCE
    before = previous_picture(ctx)
    coloured = (
        _part_coloured(ctx, image, tone)
        if shadows or (before is not None and PREVIOUS_WEAK)
        else np.zeros(image.shape[1:], bool)
    )
    if shadows:
        # the renderer casts shadows: a new part's shadow on the base is no change, unless
        # one of the step's parts, in any light, could be what the picture shows there
        classes, _ = shades
        dark = shadowed(image, expected_colours(image, state, tone, shades)) & (classes >= 0)
        change[dark & ~coloured] = 0.0
    if before is not None:
        # a pixel the manual's own picture of the base explains has not changed, however
        # unlike ours its renderer draws
        picture_before, trusted = before
        since = previous_change(image, picture_before)
        np.minimum(change, np.where(trusted, since, 1.0), out=change)
        if PREVIOUS_WEAK:
            # a whole area the manual's own pictures draw apart, however little, in the colour
            # of one of the step's parts (so no cast shadow): a new part in front of one of a
            # colour close to its own (not a line or a stud's outline resampled: those are a
            # pixel or two wide)
            weak = (since > PREVIOUS_WEAK) & trusted & (change <= CHANGE_THRESHOLD) & coloured
            weak = _solid(weak, PREVIOUS_WEAK_RADIUS)
            change[weak] = np.minimum(since[weak] * (CHANGE_THRESHOLD / PREVIOUS_WEAK), 1.0)
    change = tolerate_lines(change, outline | drawn_edges(state))
    base_ids = _base_ids(ctx)  # drawn once if either fill needs them
    fill_enclosed(change, picture, ctx, None if before is None else before[0], base_ids)
    if FILL_COVERED:
        fill_covered(change, ctx, base_ids)
    return change, Tone(tone[0], tone[1], shadows, factors if PART_SHADES else None)


#: Where the step's picture differs from the manual's own previous picture of the base by more
#: than this (largest channel, in [0, 1]; :func:`mepnet.state.previous_change`), in the colour
#: of one of the step's parts (:func:`_part_coloured`) and over a solid area (:func:`_solid`),
#: the step changed there, under :data:`CHANGE_THRESHOLD` or not: against mepnet's drawing of
#: the base another renderer's colours differ by about that much, its own two pictures only
#: where something changed (LeoCAD's F20p manual 11 step 5: a dark blue 1x10 plate on a dark
#: grey plate, both drawn dark, 0.13 apart at the median). 0: off.
PREVIOUS_WEAK = 0.08
#: ... over every square of ``2 PREVIOUS_WEAK_RADIUS + 1`` pixels it covers. (Without the
#: colour, the studs of our own F20p manual 4 step 11, its previous picture drawn at another
#: zoom, resampled, differ over 3 x 3 squares: 499 pixels more changed, the step wrong; a
#: radius of 2 drops them and the plate's band too.)
PREVIOUS_WEAK_RADIUS = 1


def _part_coloured(ctx: StepContext, image: np.ndarray, tone: np.ndarray) -> np.ndarray:
    """(H, W) bool: where the step's picture ``image`` ((3, H, W)) shows the colour of one of
    its parts in some light (:data:`PART_LIGHT`), mapped by the page's ``tone``."""
    out = np.zeros(image.shape[1:], bool)
    for colour in {c.colour for c in ctx.step.components}:
        rgb = np.asarray(_bg.colour_rgb(colour), np.float32) / 255.0 * tone[0] + tone[1]
        out |= shadowed(image, rgb[:, None, None], PART_LIGHT)
    return out


def _solid(mask: np.ndarray, radius: int = 1) -> np.ndarray:
    """``mask`` (H, W) bool opened by a square of ``2 radius + 1`` pixels: the pixels of the
    squares it fills whole, no line or dot narrower than that."""
    return _max_filter(~_max_filter(~mask, radius), radius)


#: Whether a step's parts are compared with the picture with each face's brightness as the
#: manual's renderer draws it (:func:`base_shades`' factors): another renderer lights faces its own way
#: (LeoCAD draws the faces mepnet shades at 0.62 of their colour at about their full colour), and
#: a part turned about itself shows other faces.
PART_SHADES = True


#: mepnet's white (colour 15), as :func:`mepnet.state.shade_classes` draws the shape.
_WHITE = np.asarray(_bg.colour_rgb(15), np.float64)


def _shade_level(rgb: np.ndarray, colour: np.ndarray) -> np.ndarray:
    """Per pixel ((N, 3) as rendered, and the colour of the part drawn there, (N, 3) or (3,)) its
    shade level (:func:`mepnet.state.shade_classes`): the brightness the part's face is drawn
    at, relative to its colour, as a white part's face would be drawn."""
    s = rgb.astype(np.float64).sum(axis=-1) / np.maximum(
        np.asarray(colour, np.float64).sum(axis=-1), 1.0
    )
    white = np.minimum(s[..., None] * _WHITE, 255.0).mean(axis=-1)
    return np.clip(np.rint(white / 255.0 * SHADE_LEVELS), 0, SHADE_LEVELS).astype(np.intp)


#: Whether :func:`step_change` marks as changed what :func:`fill_covered` finds.
FILL_COVERED = True
#: ... closing gaps of up to twice this many pixels in the changed pixels' ring.
COVERED_GAP = 2


def _base_ids(ctx: StepContext) -> Callable[[], np.ndarray]:
    """The base's instance id per pixel (the step's camera, no lines), drawn on the first call
    only."""
    w, h = ctx.image_size
    return functools.cache(lambda: _bg.render(ctx.base, ctx.camera, w, h, line_px=0.0).ids)


def fill_covered(change: np.ndarray, ctx: StepContext, base_ids: Callable[[], np.ndarray]) -> None:
    """Mark as changed (in place) the unchanged pixels that changed ones enclose where the base
    shape draws a part of a colour the step adds: a new part in front of a part of its own
    colour changes only its outline and the faces shaded otherwise, so the change map has a
    hole where its face covers the old one. ``base_ids``: the base's instance id per pixel
    (drawn with the step's camera, no lines)."""
    changed = change > CHANGE_THRESHOLD
    if not changed.any() or not len(ctx.base):
        return
    ring = _max_filter(changed, COVERED_GAP)
    flat = np.ascontiguousarray(np.repeat(np.where(ring, 0, 255).astype(np.uint8)[..., None], 3, 2))
    hole = _bg.foreground_mask(flat, 127.0, 0)[0] & ~ring
    if not hole.any():
        return
    hole = _max_filter(hole, COVERED_GAP) & ~changed  # out to the changed pixels again
    ids = base_ids()
    colours = {c.colour for c in ctx.step.components}
    same = [int(i) for i in np.unique(ids[hole]) if i >= 0 and ctx.base.colour(int(i)) in colours]
    if same:
        fill = hole & np.isin(ids, same)
        change[fill] = np.maximum(change[fill], 1.0)


#: A drawn colour this close (0-255, any channel) to the page's is no evidence of the model.
PAGE_LIKE = 30.0


def silhouette(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) bool: the model in a step picture ((H, W, 3) uint8), with the page-coloured
    regions the page around it does not reach (:func:`mepnet._brickgeom.foreground_mask`); and
    the page's colour (RGB)."""
    fg, colour = _bg.foreground_mask(np.ascontiguousarray(rgb), PAGE_LIKE)
    return fg, np.asarray(colour, np.float32)


#: ... and one this close (0-255, every channel) is the page itself, seen through a gap in the
#: model, not a face drawn almost as light as the page (LeoCAD's white faces: 11 off white).
PAGE_EXACT = 3.0


def _enclosed_page(picture: np.ndarray) -> np.ndarray:
    """(H, W) bool: the page-coloured pixels of ``picture`` ((H, W, 3) floats in [0, 1]) that
    the page around the drawing does not reach (:func:`silhouette`), except those of exactly
    the page's colour (a gap between parts)."""
    rgb = np.clip(picture * 255.0 + 0.5, 0, 255).astype(np.uint8)
    fg, page = silhouette(rgb)
    off = np.abs(rgb.astype(np.float32) - page).max(axis=2)
    return fg & (off <= PAGE_LIKE) & (off > PAGE_EXACT)


def fill_enclosed(
    change: np.ndarray,
    picture: np.ndarray,
    ctx: StepContext,
    picture_before: np.ndarray | None,
    base_ids: Callable[[], np.ndarray] | None = None,
) -> None:
    """Mark as changed (in place) the page-coloured regions of the picture that the page around
    the drawing does not reach (:func:`_enclosed_page`), where the base shape leaves the page
    bare and a change borders them: the faces of a white part on white paper, told from the
    page only by their outlines and shading, which another renderer may draw lighter than ours
    (then only the outlines read as changed). A region already enclosed in the previous picture
    (``picture_before``, (3, H, W) seen with this step's camera: a gap under an arch) is left
    alone. ``base_ids``: the base's instance ids as :func:`fill_covered` takes them (None:
    drawn here)."""
    hole = _enclosed_page(picture)
    if not hole.any():
        return
    if len(ctx.base):
        hole &= (base_ids or _base_ids(ctx))() < 0
    if picture_before is not None:
        hole &= ~_enclosed_page(picture_before.transpose(1, 2, 0))
    grown = _reconstruct(change > CHANGE_THRESHOLD, hole)
    change[grown] = np.maximum(change[grown], 1.0)


def _reconstruct(seed: np.ndarray, within: np.ndarray) -> np.ndarray:
    """The pixels of ``within`` connected (4-neighbourhood) to ``seed`` through ``within``."""
    grown = np.zeros_like(within)
    front = seed.copy()
    while True:
        new = grown_4(front) & within & ~grown
        if not new.any():
            return grown
        grown |= new
        front = new


def previous_picture(ctx: StepContext) -> tuple[np.ndarray, np.ndarray] | None:
    """The latest earlier picture of the build drawn from this step's view (zoom and pan
    aside) seen with this step's camera, (3, H, W) in [0, 1] (:func:`mepnet.state.warp_previous`),
    and where it shows the base as it is now, (H, W) bool: not where parts added since then
    show. None on a build's first step, and when no earlier step with a camera shares the view."""
    cam = ctx.step.camera
    if cam is None:
        return None
    w, _ = ctx.image_size
    for prev in reversed(ctx.earlier):
        if prev.step.camera is None or not same_view(prev.step.camera, cam):
            continue
        image = prev.step.image().astype(np.float32).transpose(2, 0, 1) / 255.0
        warped = warp_previous(image, prev.step.camera, cam, w)
        if warped is None:  # pragma: no cover - same_view was checked
            return None
        trusted = np.ones((w, w), bool)
        if prev.instances < len(ctx.base):
            ids = _bg.render(ctx.base, ctx.camera, w, w, line_px=0.0).ids
            trusted = ids < prev.instances  # the page (-1) and what existed then
        return warped, trusted
    return None


def synthesize(
    ctx: StepContext,
    types: list[SynthesisType],
    time_limit_s: float = 10.0,
    picture: np.ndarray | None = None,
    tone: Tone | None = None,
) -> list[Prediction]:
    """Poses for every instance of ``types`` on ``ctx.base`` (see the module docstring);
    ``picture``: the step image as floats in [0, 1] when the caller has read it already;
    ``tone``: how it draws colours, from :func:`step_change` (none: compared as rendered);
    ``time_limit_s``: each placement search's limit; the whole step's budget is
    ``ctx.budget_s``, else :data:`STEP_BUDGET_S` (see below).

    A step is solved greedily, one instance at a time; while the finished step explains the
    changed pixels poorly (:func:`_explained` below :data:`WELL_EXPLAINED`), each decision in
    turn is revisited: the greedy is finished again from each of the next
    :data:`FIRST_CHOICES` - 1 best choices there, and the solution whose parts together
    explain the picture best is kept (a stack of equal parts: the part that best fits the
    whole stack is not the bottom one; a single part: the candidate ranked first on its own
    visible pixels may leave more of the change unexplained); before that, a step adding
    several instances is solved again
    with each later decision of the greedy taken first (:data:`LATER_FIRST`: a stack's bottom,
    hidden by its top, is no first choice, and its top is not valid before it). A decision
    forced first keeps its round's choices for the revisits. After the revisits, the later
    decisions of the solution they kept are each taken first too (:data:`LATER_FIRST_AGAIN`),
    and a step of three or more instances takes each pair of its decisions again last, in the
    context of all the others (:data:`PAIRS`: two parts each at the other's place). A part
    placed explains, for the rounds after it, the changed pixels it is drawn at in about the
    picture's colour (:data:`CLAIM_OFF`), not those where a later part shows in front of it.

    Parts stand on the ground right beside the base shape (on a build's first step: anywhere
    the picture changed); when the solution explains the picture worse than
    :data:`WIDE_BELOW`, or leaves changed pixels far from anything drawn
    (:func:`_changed_apart`: a part standing apart in plain view), the step is solved again
    with the ground searched wherever the picture shows a change (a part standing on its own,
    away from the base: see ``abys_ranked``'s ``wide_ground``); explained better, each part the solution stands on the ground is placed
    again last so (:data:`WIDE_ON_GROUND`). Such a solution is kept when it explains the
    picture better: by any amount when it stands no more parts on the ground, none apart from
    the base (:func:`_apart`), else by :data:`WIDE_MARGIN`, and then only if each part it
    stands apart shows itself (:func:`_hidden_on_ground`) or it wins by :data:`WIDE_CLEAR`
    times that margin. Explained worse than
    :data:`DEEP_BELOW` even so, the step is solved once more with :data:`DEEP_RANKED`
    placements scored a round, and that solution kept on the same terms.

    The step's budget (CPU seconds): once it is spent, no decision is revisited and the ground
    is not searched again; the greedy under way is finished, each of its remaining placement searches
    limited to what is left of the budget but at least :data:`MIN_SEARCH_S` (a step whose
    pictures match nothing -- a wrong camera -- would otherwise search for many minutes). The
    predictions of a step that ran out of budget say so (``extra["over_budget"]``).

    Other complete solutions tried that explain the picture as well (within :data:`TIE`: a
    part hidden under the step's others) are handed on as the step's ties
    (``extra["ties"]`` on every prediction, :func:`_ties`): a later step's picture may tell
    them apart (:func:`mepnet.plan.run_build`)."""
    deadline = _clock() + (STEP_BUDGET_S if ctx.budget_s is None else ctx.budget_s)
    if not COLOUR_WEIGHT:
        picture = None
    elif picture is None:
        picture = step_picture(ctx)
    if tone is None:
        tone = PLAIN_TONE
    # a build's first step: every part stands on the ground, wherever the picture shows it
    first = len(ctx.base) == 0
    mask = np.zeros(ctx.image_size[::-1], bool)  # (H, W): every type's changed pixels
    for t in types:
        mask |= t.mask
    edges = edge_map(picture) if picture is not None and EDGE_WEIGHT else None
    # the base's colours as the step's camera draws them, for every solution's score
    behind = (
        _base_colours(ctx) if picture is not None and QUIET_BEHIND and QUIET_LEVEL > 0 else None
    )
    # what the solves below share: each complete solution's score, each candidate drawn alone
    scores: dict[tuple[Any, ...], float] = {}
    drawn: dict[First, _Drawn] = {}

    def solve(wide: bool, ranked: int) -> tuple[list[Prediction], float, Any]:
        """:func:`_solve` on this step, the ground searched wherever the picture changed when
        ``wide``, ``ranked`` placements scored a round."""
        return _solve(
            ctx,
            types,
            time_limit_s,
            picture,
            tone,
            wide,
            mask,
            edges,
            deadline,
            ranked,
            behind,
            scores,
            drawn,
        )

    preds, score, tried = solve(first, RANKED)
    searched_wide = first
    if (
        not first
        and (score < WIDE_BELOW or _changed_apart(ctx, preds, mask))
        and _clock() < deadline
    ):
        wide, wide_score, wide_tried = solve(True, RANKED)
        if _wide_wins(ctx, preds, score, wide, wide_score):
            preds, score, tried, searched_wide = wide, wide_score, wide_tried, True
        if score < DEEP_BELOW and _clock() < deadline:
            deep, deep_score, deep_tried = solve(searched_wide, DEEP_RANKED)
            tried += deep_tried
            if _wide_wins(ctx, preds, score, deep, deep_score):
                preds, score = deep, deep_score
    elif WIDE_ON_GROUND and _grounded(preds) and not first:
        # each part standing on the ground placed again last, the ground searched wherever
        # the picture changed (1% more CPU time a step on our pictures; the whole step solved
        # again so, 15%)
        entry_type = {t.entry: i for i, t in enumerate(types)}
        for g, p in enumerate(list(preds)):
            if not (p.placed and p.attach == "ground") or _clock() >= deadline:
                continue
            prefix = [
                (entry_type[q.entry], int(q.yaw), tuple(q.t))  # type: ignore[arg-type,misc]
                for x, q in enumerate(preds)
                if x != g and q.placed
            ]
            moved, _, _ = _greedy(
                ctx, types, time_limit_s, picture, tone, prefix, True, None, deadline, drawn
            )
            if len(moved) < len(preds) or not all(q.placed for q in moved):
                continue
            moved_score = _scored(scores, ctx, moved, mask, picture, tone, edges, behind)
            tried.append((moved_score, moved))
            if _wide_wins(ctx, preds, score, moved, moved_score):
                preds, score = moved, moved_score
    said: dict[str, Any] = {}
    if _clock() >= deadline:
        said["over_budget"] = True
    if ties := _ties(ctx, preds, score, tried):
        said["ties"] = ties
    if said:
        preds = [dataclasses.replace(p, extra={**p.extra, **said}) for p in preds]
    return preds


#: Other solutions of a step explaining its picture within this much of the kept one
#: (:func:`_explained`) are its ties: the picture cannot tell them apart (a part hidden under
#: the step's others; a side stud facing away: the same pixels, the same score), a later step
#: may (``extra["ties"]``). Near ties are not kept: on other renderers' pictures many
#: solutions come within 0.001, and predicting later steps again on each cost 0.2-0.4 s a step
#: for no gain.
TIE = 1e-9
#: ... except solutions within this much that are drawn alike (:func:`_alike`; a part turned
#: about itself whose difference the picture barely shows: a side stud peeking out by a few
#: pixels, which another renderer's picture then scores a little apart either way; a part
#: hidden behind the others either way, a sliver of it in view).
NEAR_TIE = 0.05
#: Two drawings differing in at most this share of the image's pixels are drawn alike (32
#: pixels of 256 x 256: 13 of a side stud peeking out past its brick, 67 of one in view).
ALIKE_SHARE = 32 / 256**2
#: ... and solutions within this much of the kept one's score are ties when drawn within
#: :data:`CLOSE_ALIKE_SHARE`: the picture scores them the same though our drawings of them
#: differ more (LeoCAD's picture of F20y manual 7 step 10: a 1x1 brick mostly hidden, a sliver
#: of one face in view, 0.0002 below the kept place a plate lower and two cells over, drawn 86
#: pixels apart by us as LeoCAD shades its faces otherwise; step 14's plate stands on it).
CLOSE_TIE = 0.002
#: The share of the image's pixels two drawings within :data:`CLOSE_TIE` may differ in (128
#: pixels of 256 x 256).
CLOSE_ALIKE_SHARE = 128 / 256**2
#: Two drawings differ at a pixel where a colour channel differs by more than this (0-255).
DRAWN_LEVEL = 24
#: Whether a near tie must also fill the same boxes as the kept solution (as before stop 54:
#: LeoCAD's picture of F20n manual 0 step 7 scores a 1x1 brick hidden far off 0.009 above the
#: true place, hidden too, drawn 17 pixels apart; kept, step 10's picture settles it).
NEAR_TIE_BOXES = False
#: Ties kept per step, best first.
MAX_TIES = 3


def _placements(preds: list[Prediction]) -> list[tuple[int, int, tuple[int, int, int]]]:
    """The placed predictions as (entry, yaw, translation)."""
    return [(p.entry, int(p.yaw), tuple(p.t)) for p in preds if p.placed]  # type: ignore[arg-type,misc]


def _ties(
    ctx: StepContext,
    preds: list[Prediction],
    score: float,
    tried: list[tuple[float, list[Prediction]]],
) -> list[list[tuple[int, int, tuple[int, int, int]]]]:
    """The complete solutions in ``tried`` that explain the picture within :data:`TIE` of
    ``preds``' ``score`` and place some part otherwise (a symmetric part's equal yaws are one
    placement), at most :data:`MAX_TIES`, best first: each as (entry, yaw, translation) per
    instance."""

    def same(a: list[Prediction], b: list[Prediction]) -> bool:
        left = [p for p in b if p.placed]
        for p in a:
            comp = ctx.components[p.component]
            hit = next(
                (
                    q
                    for q in left
                    if q.entry == p.entry and comp.same_placement(p.yaw, p.t, q.yaw, q.t)
                ),
                None,
            )
            if hit is None:
                return False
            left.remove(hit)
        return not left

    def boxes(a: list[Prediction]) -> list[Any]:
        return sorted(placement_box(ctx.components[p.component], p.yaw, p.t) for p in a)  # type: ignore[arg-type]

    w, h = ctx.image_size
    kept: tuple[list[Any], np.ndarray] | None = None  # the kept solution's boxes and drawing
    out: list[list[Prediction]] = []
    for s, alt in sorted(tried, key=lambda x: -x[0]):
        if len(out) == MAX_TIES or s < score - NEAR_TIE:
            break
        if not all(p.placed for p in alt) or len(alt) != len(preds):
            continue
        if same(alt, preds) or any(same(alt, o) for o in out):
            continue
        if s < score - TIE:  # a near tie: drawn alike
            if kept is None:
                kept = (boxes(preds), _drawing(ctx, preds))
            share = CLOSE_ALIKE_SHARE if s >= score - CLOSE_TIE else ALIKE_SHARE
            if (NEAR_TIE_BOXES and boxes(alt) != kept[0]) or not _alike(
                _drawing(ctx, alt), kept[1], w * h, share
            ):
                continue
        out.append(alt)
    return [_placements(alt) for alt in out]


def _with_parts(ctx: StepContext, preds: list[Prediction]) -> _bg.Assembly:
    """A copy of the base with the placed ``preds`` added, in their callout colours."""
    asm = ctx.base.copy()
    for p in preds:
        if p.placed:
            asm.add(ctx.components[p.component], p.yaw, p.t, ctx.colour(p.entry))  # type: ignore[arg-type]
    return asm


def _drawing(ctx: StepContext, preds: list[Prediction]) -> np.ndarray:
    """The base with ``preds`` placed, drawn with the step's camera ((H, W, 3) uint8)."""
    w, h = ctx.image_size
    return _bg.render(_with_parts(ctx, preds), ctx.camera, w, h).rgb


def _alike(a: np.ndarray, b: np.ndarray, size: int, share: float | None = None) -> bool:
    """Whether two drawings ((..., 3) uint8) of a picture of ``size`` pixels differ in at most
    ``share`` of them (None: :data:`ALIKE_SHARE`)."""
    return int(drawn_differ(a, b).sum()) <= (ALIKE_SHARE if share is None else share) * size


def drawn_differ(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Where two drawings ((..., 3) uint8) differ: a channel by more than :data:`DRAWN_LEVEL`."""
    return np.abs(a.astype(np.int16) - b).max(axis=-1) > DRAWN_LEVEL


#: CPU seconds (:func:`_clock`) one step's synthesis may take before it stops revisiting
#: decisions (:func:`synthesize`): the median step takes well under one, the slowest of our
#: own pictures about 18; a wrong camera hypothesis on another renderer's picture took 10-30
#: minutes without it.
STEP_BUDGET_S = 30.0


def _clock() -> float:
    """The budget's clock: this process's CPU seconds (every thread's), so that how much a step
    may do does not depend on what else the machine runs (wall-clock budgets cut 12 steps of
    one evaluation short with three evaluations sharing two cores). Each placement search's own
    limit is wall-clock (``abys_ranked``); what is left of the budget is handed to it as that."""
    return time.process_time()


#: A placement search's least time limit once the step's budget is spent.
MIN_SEARCH_S = 0.25


#: A step explained worse than this (:func:`_explained`) is solved again with the ground
#: searched wherever the picture changed, not only right beside the base shape (a part a stud
#: away from it is outside that search). (0.8 until stop 43: S20 manual 7 step 7, a tile
#: standing apart put where a jumper plate belongs and the jumper hidden, explained 0.82; the
#: parts moved one at a time (:data:`WIDE_ON_GROUND`) never move both.)
WIDE_BELOW = 0.85
#: A step explained worse than this even so is solved once more with each round scoring
#: :data:`DEEP_RANKED` placements instead of :data:`RANKED`, kept on the same terms as the
#: ground searched wherever the picture changed (:func:`_wide_wins`). Another renderer's
#: picture of a part on a base of its colour changes only along a few outlines: the part's
#: true place covers them less than places the change map's stray lines fill (LeoCAD's LF20f
#: manual 7 step 14, a dark grey slope on a dark grey brick, 13th to 24th by mask IoU and first
#: by :func:`_explained`). (0.3 at first; 0.85, every step the wide search is tried on, also
#: finds LF20c manual 19 step 7 and LF20g manual 0 step 3 and manual 7 step 15, all explained
#: 0.60-0.72, for 12.6% more CPU time on 40 random LeoCAD steps and 2.6% on 30 of ours.)
DEEP_BELOW = 0.85
DEEP_RANKED = 24
#: Whether a step explained better, whose solution stands a part on the ground, has each such
#: part placed again last with the ground searched wherever the picture changed.
WIDE_ON_GROUND = True
#: ... and that solution is taken when it explains the picture better: by any amount when it
#: only moves parts along the ground, not apart from the base (:func:`_apart`), else by this
#: much (seen along the camera's rays, a part far behind the shape can mimic one fixed onto
#: it; a part put on the ground beside the base explains another renderer's poorly fitting
#: picture a little better as often as it is right).
WIDE_MARGIN = 0.1
#: ... and when each of its parts standing on the ground apart from the base shape (outside its
#: footprint's box) shows at least this share of itself in front of the base: an instruction
#: picture shows a new part standing apart; one mostly hidden behind the model only mimics a
#: change mask that missed part of the true placement (another renderer's part drawn in the
#: colour of the part under it). (Parts standing beside or under the base are often partly
#: hidden by it, and the step's own new parts may hide any: the bottom of a stack.)
WIDE_VISIBLE = 0.8
#: ... unless the solution wins by more than this many times :data:`WIDE_MARGIN`: a part half
#: hidden behind the model that explains the picture far better is there (F20t manual 9 step
#: 4: a 2x2 plate standing behind the model, partly hidden, 0.9989 against 0.62; refused for
#: its hiding, the step was only right because a move along the view ray found it another way,
#: which :data:`RAY_APART` now holds to the wide search's terms).
WIDE_CLEAR = 2.0
#: ... a part whose footprint comes within this many lattice cells (half studs) of the base's
#: footprint box stands beside it, not apart: a brick half a stud behind the model is as
#: hidden by it as one touching it (the misread this guards against stood 15 studs behind).
WIDE_BESIDE = 2
#: Whether a part the wider search stands apart from the base is judged as new (the margin,
#: the share it shows) only when the solution it would replace stands no part of its callout
#: entry apart elsewhere: moving a part that already stood apart puts no new one there, and the
#: two solutions are compared by how well they explain the picture (LeoCAD's LF20q manual 13
#: step 10: a blue slope standing behind the model, its top in view, the narrow solution's
#: turned the wrong way three studs off, explaining 0.78 against the truth's 0.82).
APART_MOVED = True


#: A change the solution draws nothing near: at least this many changed pixels ...
APART_PX = 20
#: ... more than this many pixels from anything the base and the solution draw (a part
#: standing on its own, apart from the model, that the solution put elsewhere: F20p manual 17
#: step 5, a round plate on the ground beside the model drawn in plain view, hidden inside the
#: model by a solution explaining the picture 0.88, over :data:`WIDE_BELOW`) ...
APART_GAP = 3


def _changed_apart(ctx: StepContext, preds: list[Prediction], mask: np.ndarray) -> bool:
    """Whether the step's changed pixels (``mask``) leave at least :data:`APART_PX` more than
    :data:`APART_GAP` pixels from anything the base with ``preds`` draws: the step is solved
    again with the ground searched wherever the picture changed (:func:`synthesize`)."""
    w, h = ctx.image_size
    near = _bg.render(_with_parts(ctx, preds), ctx.camera, w, h).ids >= 0
    for _ in range(APART_GAP):
        near = grown_4(near)
    return int((mask & ~near).sum()) >= APART_PX


def _wide_wins(
    ctx: StepContext,
    preds: list[Prediction],
    score: float,
    wide: list[Prediction],
    wide_score: float,
) -> bool:
    """Whether the solution ``wide`` (the ground searched wherever the picture changed) is
    taken over ``preds``: it explains the picture better (by any amount when it stands no more
    parts on the ground and none apart from the base; else by :data:`WIDE_MARGIN`, and each
    part it stands apart shows itself, :func:`_hidden_on_ground`, unless it wins by
    :data:`WIDE_CLEAR` times that margin)."""
    if wide_score <= score + 1e-6:  # most calls (each move along the view ray): no box work
        return False
    near = _grounded(wide) <= _grounded(preds) and not _apart(ctx, wide, preds)
    margin = 0.0 if near else WIDE_MARGIN
    if wide_score <= score + margin + 1e-6:
        return False
    return wide_score > score + WIDE_CLEAR * WIDE_MARGIN or not _hidden_on_ground(ctx, wide, preds)


def _grounded(preds: list[Prediction]) -> int:
    """How many of ``preds`` stand on the ground."""
    return sum(1 for p in preds if p.placed and p.attach == "ground")


def _ground_gap(ctx: StepContext, p: Prediction) -> int | None:
    """How many empty lattice cells (half studs) lie between a part of ``p`` standing on the
    ground and the base's footprint box (0: within it or touching it); None: not on the
    ground, or no base."""
    box = ctx.base.bounds()
    if not (p.placed and p.attach == "ground") or box is None:
        return None
    (lo, hi), (plo, phi) = box, placement_box(ctx.components[p.component], p.yaw, p.t)  # type: ignore[arg-type]
    return max(0, *(max(lo[a] - phi[a], plo[a] - hi[a]) - 1 for a in (0, 2)))


def _apart(
    ctx: StepContext, preds: list[Prediction], before: Sequence[Prediction] = ()
) -> list[Prediction]:
    """The parts of ``preds`` standing on the ground apart from the base (more than
    :data:`WIDE_BESIDE` cells outside its footprint box) and not placed so in ``before``;
    where ``before`` stands parts of a callout entry apart elsewhere (:data:`APART_MOVED`),
    as many of the entry's parts apart in ``preds`` are moved, not new, and left out too."""

    def away(ps: Sequence[Prediction]) -> list[Prediction]:
        return [p for p in ps if (_ground_gap(ctx, p) or 0) > WIDE_BESIDE]

    known = {(q.component, q.yaw, q.t) for q in before if q.placed}
    new = [p for p in away(preds) if (p.component, p.yaw, p.t) not in known]
    if not APART_MOVED:
        return new
    kept = {(p.component, p.yaw, p.t) for p in preds if p.placed}
    moved = Counter(q.entry for q in away(before) if (q.component, q.yaw, q.t) not in kept)
    out = []
    for p in new:
        if moved[p.entry] > 0:
            moved[p.entry] -= 1
        else:
            out.append(p)
    return out


def _hidden_on_ground(
    ctx: StepContext, preds: list[Prediction], before: Sequence[Prediction] = ()
) -> bool:
    """Whether a part of ``preds`` standing on the ground apart from the base (:func:`_apart`:
    more than :data:`WIDE_BESIDE` cells outside its footprint box), and not placed so in
    ``before``, shows less than :data:`WIDE_VISIBLE` of itself drawn with the base."""
    w, h = ctx.image_size
    n0 = len(ctx.base)
    for p in _apart(ctx, preds, before):
        comp = ctx.components[p.component]
        alone = _bg.Assembly()
        alone.add(comp, p.yaw, p.t, 0)  # type: ignore[arg-type]
        full = int((_bg.render(alone, ctx.camera, w, h).ids >= 0).sum())
        asm = ctx.base.copy()
        asm.add(comp, p.yaw, p.t, 0)  # type: ignore[arg-type]
        shown = int((_bg.render(asm, ctx.camera, w, h).ids == n0).sum())
        if full and shown < WIDE_VISIBLE * full:
            return True
    return False


def _solve(
    ctx: StepContext,
    types: list[SynthesisType],
    time_limit_s: float,
    picture: np.ndarray | None,
    tone: Tone,
    wide: bool,
    mask: np.ndarray,
    picture_edges: np.ndarray | None,
    deadline: float = float("inf"),
    ranked: int = RANKED,
    base_colours: np.ndarray | None = None,
    scores: dict[tuple[Any, ...], float] | None = None,
    drawn: dict[First, _Drawn] | None = None,
) -> tuple[list[Prediction], float, list[tuple[float, list[Prediction]]]]:
    """:func:`synthesize`'s greedy with its revisits, the ground searched beside the base or
    (``wide``) wherever the picture changed, no revisit begun after ``deadline``
    (:func:`_clock`); ``mask``, ``picture_edges``: what :func:`_explained` weighs (the types'
    masks together, the picture's :func:`edge_map`); ``ranked``: the placements each of the
    greedy's rounds scores; ``base_colours``: :func:`_explained`'s. ``scores``: each complete
    solution's score by :func:`_solution_key`, and ``drawn``: each candidate drawn alone, shared
    by the solves of one step (the same mask, picture and camera). Returns the predictions, how
    well they explain the picture, and every complete solution tried with its score."""
    w, h = ctx.image_size
    memo: dict[frozenset[First], tuple[Any, list[tuple[float, First]]]] = {}
    drawn = {} if drawn is None else drawn
    scores = {} if scores is None else scores

    total = sum(t.count for t in types)

    tried: list[tuple[float, list[Prediction]]] = []  # every complete solution and its score

    def attempt(prefix: list[First]) -> tuple[list[Prediction], list[First], Any, float]:
        """The greedy with its first decisions forced to ``prefix``, and how well it explains;
        a greedy cut short by a forced decision that does not fit (a pair taken again whose
        other parts stood on it, a column or a shift) explains nothing (``-inf``): its parts
        left out would otherwise cost nothing, and a step's wrong part dropped explains the
        picture better than placed."""
        p, t, o = _greedy(
            ctx, types, time_limit_s, picture, tone, prefix, wide, memo, deadline, drawn, ranked
        )
        if len(p) < total:
            return p, t, o, float("-inf")
        score = _scored(scores, ctx, p, mask, picture, tone, picture_edges, base_colours)
        tried.append((score, p))
        return p, t, o, score

    def attempt_kept(
        head: list[First], kept: list[First], replace: bool = True
    ) -> tuple[list[Prediction], list[First], Any, float]:
        """:func:`attempt` with ``head`` then ``kept`` forced; where ``kept`` does not fit
        beside ``head`` (``replace``), with ``head`` alone, the rest placed again."""
        out = attempt([*head, *kept])
        if out[3] == float("-inf") and replace and kept and _clock() < deadline:
            out = attempt(head)
        return out

    def each_part(moves: Callable[[First], list[First]]) -> None:
        """Each decision in turn replaced by each of its ``moves`` (the others kept, or placed
        again after it: :data:`MOVES_REPLACE`), while the step is explained worse than
        :data:`CLOSE` and time is left; a better solution is kept."""
        nonlocal preds, score, taken
        for level in range(len(taken)):
            if score >= CLOSE or _clock() >= deadline:
                break
            for g in moves(taken[level]):
                alt_preds, alt_taken, _, alt_score = attempt_kept(
                    [*taken[:level], g], taken[level + 1 :], MOVES_REPLACE
                )
                if alt_score > score + 1e-6:
                    preds, score, taken = alt_preds, alt_score, alt_taken

    preds, taken, options, score = attempt([])
    # a later decision taken first: a part that shows little until what stands on it is
    # placed (the bottom brick of a stack, hidden by the top one) is never among the first
    # choices, and the top one is not valid before it
    led: set[First] = set(taken[:1])  # the decisions tried first on their own
    for later in list(taken[1:]) if LATER_FIRST else []:
        if score >= WELL_EXPLAINED or _clock() >= deadline:
            break
        led.add(later)
        alt_preds, alt_taken, alt_options, alt_score = attempt([later])
        if alt_score > score + 1e-6:
            preds, score, taken, options = alt_preds, alt_score, alt_taken, alt_options
    # each decision in turn: the next best choices there, the rest greedy again
    level = 0
    # (a step of one part up to :data:`CLOSE`: its choices are placements scored, no greedy)
    revisit_below = CLOSE if LONE_CHOICES and total == 1 else WELL_EXPLAINED
    while score < revisit_below and level < len(taken) and _clock() < deadline:
        choices = _choices(options[level], LEAD_CHOICES if level == 0 else FIRST_CHOICES, level)
        for alt in choices[1:]:
            if _clock() >= deadline:
                break
            if alt == taken[level]:
                continue
            if level == 0:
                led.add(alt)
            alt_preds, alt_taken, alt_options, alt_score = attempt([*taken[:level], alt])
            if alt_score > score + 1e-6:
                preds, score, taken = alt_preds, alt_score, alt_taken
                options = options[: level + 1] + alt_options[level + 1 :]
        level += 1
    # the later decisions of what the revisits found, taken first too (:data:`LATER_FIRST_AGAIN`):
    # of two slopes side by side, one turned across the middle of both ranks first; a revisit
    # puts one slope right after it, and that slope taken first finds the other
    while LATER_FIRST_AGAIN and score < WELL_EXPLAINED and _clock() < deadline:
        fresh = [f for f in taken[1:] if f not in led]
        if not fresh:
            break
        led.add(fresh[0])
        alt_preds, alt_taken, alt_options, alt_score = attempt([fresh[0]])
        if alt_score > score + 1e-6:
            preds, score, taken, options = alt_preds, alt_score, alt_taken, alt_options
    # each pair of decisions taken again in the context of all the others: two parts each at
    # the other's place (the greedy placed the first where the second belongs, and the second
    # fitted what was left) are no single decision's next choice
    n = len(taken)
    pairs = [(a, b) for a in range(n) for b in range(a + 1, n)] if PAIRS and n > 2 else []
    for a, b in pairs * PAIR_PASSES:
        if score >= WELL_EXPLAINED or _clock() >= deadline or len(taken) != n:
            break
        prefix = [f for x, f in enumerate(taken) if x not in (a, b)]
        first = attempt(prefix)
        # and the next best choices of the round that places the first of the two
        alts = first[2][len(prefix)][1:PAIR_CHOICES] if len(first[2]) > len(prefix) else []
        for alt in [None, *alts]:
            if alt is not None and _clock() >= deadline:
                break
            alt_preds, alt_taken, alt_options, alt_score = (
                first if alt is None else attempt([*prefix, alt])
            )
            if alt_score > score + 1e-6:
                preds, score, taken, options = alt_preds, alt_score, alt_taken, alt_options
    # a part put at another type's place: the greedy placed one part where another belongs
    # (where the detector finds the types about as likely, as on other renderers' pictures,
    # every type's mask is the step's whole change, and the part's colour did not outweigh the
    # other's place fitting its shape better), the other fitted what was left; taking the pair
    # again ranks the same wrong place first (:data:`SWAPS`)
    swapped: set[First] = set()
    while SWAPS and len(taken) == total >= 2 and score < WELL_EXPLAINED and _clock() < deadline:
        trials = [
            (a, g)
            for a, fa in enumerate(taken)
            for fb in taken
            if fa[0] != fb[0]
            for g in _in_place_of(types[fa[0]].component, types[fb[0]].component, fb[1], fb[2])
            if (fa[0], *g) not in swapped
        ]
        better = False
        for a, g in trials:
            if _clock() >= deadline:
                break
            head = (taken[a][0], *g)
            swapped.add(head)
            rest = [f for x, f in enumerate(taken) if x != a and not _overlaps(types, f, head)]
            alt_preds, alt_taken, _, alt_score = attempt_kept([head], rest)
            if alt_score > score + 1e-6:
                preds, score, taken = alt_preds, alt_score, alt_taken
                better = True
                break
        if not better:
            break
    # identical parts stacked straight up: the lower ones show little until the ones above
    # them are placed, and the upper ones are not valid before them, so a column of them is
    # searched whole (its placements ranked as one component) and the rest solved greedily;
    # last, with the time left, and kept only when it explains clearly more: a column hides
    # its lower parts, so a picture that barely tells placements apart (dark parts on a dark
    # base) is explained a little better by stacking parts out of sight
    # (the margin at most a share of what the step leaves unexplained: a column that explains
    # a step exactly wins over a greedy a few hundredths short)
    columns = _columns(ctx, types, taken, time_limit_s, wide, deadline) if score < CLOSE else []
    for column in columns if COLUMNS else []:
        if score >= CLOSE or _clock() >= deadline:
            break
        # the step's other parts kept where they are (the greedy after a column may place
        # them worse than it did before), else placed again around it
        kept = [f for f in taken if f[0] != column[0][0]]
        alt_preds, alt_taken, _, alt_score = attempt_kept(column, kept)
        if alt_score > score + min(COLUMN_MARGIN, COLUMN_SHARE * (1.0 - score)):
            preds, score, taken = alt_preds, alt_score, alt_taken
    # a part the picture shows little or nothing of, while changed pixels stay unexplained:
    # placed again where those pixels are (a part mostly hidden behind the step's others that
    # no detection marked is put anywhere it hides; no shift or turn of it reaches its place);
    # before the shifts and turns, which then polish what it moved
    relocations = (
        _relocations(ctx, types, taken, mask, picture_edges, time_limit_s, wide, deadline)
        if RELOCATE and score < CLOSE and len(taken) == total
        else []
    )
    for prefix in relocations:
        if score >= CLOSE or _clock() >= deadline:
            break
        alt_preds, alt_taken, _, alt_score = attempt(prefix)
        if alt_score > score + 1e-6:
            preds, score, taken = alt_preds, alt_score, alt_taken
    # the step's parts moved together: placed one at a time, each fits what the ones before it
    # left, so a row of parts can end up a cell off as a whole (every part a little off the
    # picture, none better alone)
    for dx, dz in SHIFTS if len(taken) == total and total >= SHIFT_MIN_PARTS else ():
        if score >= CLOSE or _clock() >= deadline:
            break
        moved = [(i, yaw, (t[0] + dx, t[1], t[2] + dz)) for i, yaw, t in taken]
        alt_preds, alt_taken, _, alt_score = attempt(moved)
        if alt_score > score + 1e-6:
            preds, score, taken = alt_preds, alt_score, alt_taken

    # each part moved a cell on its own, the others where they are: of two bricks side by side,
    # the greedy's rounds rank a cell off the true one first for each (the detector's mask
    # and keypoint favour it), the second fits what the first left, and a whole-step shift
    # moves both; and a cell along both axes (:data:`CELL_DIAGONALS`)
    def cell_moves(f: First) -> list[First]:
        i, yaw, (x, y, z) = f
        return [(i, yaw, (x + dx, y, z + dz)) for dx, dz in (*SHIFTS[:4], *CELL_DIAGONALS)]

    if PART_SHIFTS and len(taken) == total >= 2:
        each_part(cell_moves)
    # each part turned about itself, filling the same cells (a slope or a panel facing the
    # other way, a corner plate's corner, a side stud): a decision whose next choices all lay
    # elsewhere never tries it
    if TURNS and len(taken) == total:
        before = score
        each_part(lambda f: [(f[0], *t) for t in _turns(types[f[0]].component, f[1], f[2], True)])
        # ... and after a turn, each part a cell off again (a turned slope's row shifted)
        if PART_SHIFTS and score > before and len(taken) == total >= 2:
            each_part(cell_moves)
    # each part moved along the view ray: drawn at (nearly) the same pixels, mostly hidden, so
    # only what it hides or is hidden by tells; the change map has nothing of the true place,
    # so no round ranks it
    rays = _ray_shifts(ctx.camera, w, h) if RAY_SHIFTS and len(taken) == total else []
    for level in range(len(taken)) if rays else ():
        if score >= CLOSE or _clock() >= deadline:
            break
        i, yaw, tr = taken[level]
        others = [*taken[:level], *taken[level + 1 :]]
        for d in rays:
            there = (tr[0] + d[0], tr[1] + d[1], tr[2] + d[2])
            # last: moved up, it may stand on a part placed after it
            alt_preds, alt_taken, _, alt_score = attempt([*others, (i, yaw, there)])
            # on the terms of the ground searched wide (:data:`RAY_APART`): a part moved back
            # along the ray onto the ground apart from the model draws the same pixels, and
            # another renderer's picture may favour it by a little
            if (
                _wide_wins(ctx, preds, score, alt_preds, alt_score)
                if RAY_APART
                else alt_score > score + 1e-6
            ):
                preds, score, taken = alt_preds, alt_score, alt_taken
                # ... and there turned about itself (:data:`RAY_TURNS`): at its new place it
                # shows other faces
                for y, t2 in (
                    _turns(types[i].component, yaw, there, True, True) if RAY_TURNS else ()
                ):
                    if _clock() >= deadline:
                        break
                    alt_preds, alt_taken, _, alt_score = attempt([*others, (i, y, t2)])
                    if alt_score > score + 1e-6:
                        preds, score, taken = alt_preds, alt_score, alt_taken
    # the step's parts turned together about the middle of the box they fill, where turned
    # they fill the same box (two 1x2 bricks side by side make a 2x2 column either way round:
    # only the seam between them tells)
    for turned in _step_turns(types, taken) if STEP_TURNS and len(taken) == total > 1 else ():
        if score >= CLOSE or _clock() >= deadline:
            break
        alt_preds, alt_taken, _, alt_score = attempt(turned)
        if alt_score > score + 1e-6:
            preds, score, taken = alt_preds, alt_score, alt_taken
    # ... and each group of them that touch (:func:`_groups`) turned the same way, the others
    # kept: two jumper plates side by side turned across, beside parts placed elsewhere
    groups = _groups(types, taken) if GROUP_TURNS and len(taken) == total > 2 else []
    if PAIR_TURNS and len(taken) == total > 2:
        groups += [g for g in _touching_pairs(types, taken) if g not in groups]
    for group in groups:
        for turned in _step_turns(types, [taken[k] for k in group]):
            if score >= CLOSE or _clock() >= deadline:
                break
            prefix = list(taken)
            for k, f in zip(group, turned, strict=True):
                prefix[k] = f
            alt_preds, alt_taken, _, alt_score = attempt(prefix)
            if alt_score > score + 1e-6:
                preds, score, taken = alt_preds, alt_score, alt_taken
    # a round's next choices drawn exactly like its decision on the shape it was taken on (a
    # side stud facing away, a part under others): a well explained step revisits nothing, so
    # these solutions are tried here, for the step's ties (:func:`_ties`) that a later picture
    # may tell apart
    for level, (f, alts) in enumerate(zip(taken, options, strict=False)) if TIE_CHOICES > 1 else ():
        near = [a for a in alts[1:TIE_CHOICES] if a != f and a in drawn]
        if not near or f not in drawn or _clock() >= deadline:
            continue
        shape = ctx.base.copy()
        for i, yaw, tr in taken[:level]:
            shape.add(types[i].component, yaw, tr, 0)
        depth = _bg.render(shape, ctx.camera, w, h, line_px=0.0).depth
        for a in near:
            if _seen_alike(drawn[f], drawn[a], depth):
                alt_preds, alt_taken, _, alt_score = attempt([*taken[:level], a])
                if alt_score > score + 1e-6:
                    preds, score, taken = alt_preds, alt_score, alt_taken
    return preds, score, tried


def _turns(
    comp: _bg.Component,
    yaw: int,
    t: tuple[int, int, int],
    in_place: bool = False,
    corners: bool = False,
) -> list[tuple[int, tuple[int, int, int]]]:
    """The other placements of ``comp`` filling the same box as at ``(yaw, t)``: each other
    yaw, moved so that its box is the same, unless it is the same placement (symmetry);
    ``in_place`` (:data:`TURNS_IN_PLACE`): then each other yaw about ``t`` itself too (a slope
    in a row turned to face the way of its neighbours, its box moved); ``corners``: and each
    other yaw about each corner of the box, that corner kept (a plate pivoted on its end
    stud)."""

    lo, hi = placement_box(comp, yaw, t)
    out: list[tuple[int, tuple[int, int, int]]] = []

    def add(y: int, t2: tuple[int, int, int]) -> None:
        if not comp.same_placement(yaw, t, y, t2) and not any(
            comp.same_placement(y, t2, *o) for o in out
        ):
            out.append((y, t2))

    for y in range(4):
        if y == yaw:
            continue
        lo2, hi2 = placement_box(comp, y, t)  # a yaw turns about the vertical: as high
        d = tuple(a - b for a, b in zip(lo, lo2, strict=True))
        if tuple(a - b for a, b in zip(hi, hi2, strict=True)) != d:
            continue  # turned, it fills other cells
        add(y, (t[0] + d[0], t[1] + d[1], t[2] + d[2]))
    for y in range(4) if in_place and TURNS_IN_PLACE else ():
        if y != yaw:
            add(y, t)
    for y in range(4) if corners else ():
        if y == yaw:
            continue
        lo2, hi2 = placement_box(comp, y, t)
        for x_end in (0, 1):
            for z_end in (0, 1):  # the corner of the box kept: low or high end along x, z
                dx = (lo, hi)[x_end][0] - (lo2, hi2)[x_end][0]
                dz = (lo, hi)[z_end][2] - (lo2, hi2)[z_end][2]
                add(y, (t[0] + dx, t[1] + lo[1] - lo2[1], t[2] + dz))
    return out


def _ray_shifts(camera: _bg.Camera, w: int, h: int) -> list[tuple[int, int, int]]:
    """Lattice moves (within :data:`RAY_REACH`) that the camera draws within :data:`RAY_PX` of a
    stud's width of where they start: a part moved by one lies along the view ray, at (nearly)
    the same pixels; the :data:`RAY_SHIFT_COUNT` shortest on the picture, shortest first."""
    m = np.asarray(camera.pixel_matrix(w, h), dtype=float)[:, :3]
    stud = min(float(np.hypot(*(m[:, a] * 2.0 * LDU_PER_CELL[a]))) for a in (0, 2))
    across, up = range(-RAY_REACH[0], RAY_REACH[0] + 1), range(-RAY_REACH[1], RAY_REACH[1] + 1)
    moves = np.array([(dx, dy, dz) for dx in across for dy in up for dz in across])
    moves = moves[np.any(moves != 0, axis=1)]
    px = np.hypot(*(m @ (moves * LDU_PER_CELL).T))
    order = [i for i in np.argsort(px, kind="stable") if px[i] <= RAY_PX * stud]
    return [tuple(int(v) for v in moves[i]) for i in order[:RAY_SHIFT_COUNT]]  # type: ignore[misc]


def _step_turns(types: list[SynthesisType], taken: list[First]) -> list[list[First]]:
    """A step's decisions turned together by each other quarter turn about the vertical,
    moved back into the box they filled; those that fill another box left out."""

    def box(decisions: list[First]) -> tuple[tuple[int, ...], tuple[int, ...]]:
        boxes = [placement_box(types[i].component, yaw, t) for i, yaw, t in decisions]
        return tuple(min(b[0][a] for b in boxes) for a in range(3)), tuple(
            max(b[1][a] for b in boxes) for a in range(3)
        )

    lo, hi = box(taken)
    out: list[list[First]] = []
    for r in (1, 2, 3):
        turned = [(i, (yaw + r) % 4, rotate_lattice(t, r)) for i, yaw, t in taken]
        lo2, hi2 = box(turned)
        d = tuple(a - b for a, b in zip(lo, lo2, strict=True))
        if tuple(a - b for a, b in zip(hi, hi2, strict=True)) != d:
            continue  # turned, the parts fill a box of another shape
        out.append([(i, yaw, (t[0] + d[0], t[1] + d[1], t[2] + d[2])) for i, yaw, t in turned])
    return out


_Box = tuple[tuple[int, int, int], tuple[int, int, int]]


def _boxes_meet(a: _Box, b: _Box, gap: int) -> bool:
    """Whether two lattice boxes (lowest and highest cells) come within ``gap`` cells of each
    other along every axis (0: they overlap; 1: they overlap or meet, corners included)."""
    (la, ha), (lb, hb) = a, b
    return all(la[x] <= hb[x] + gap and lb[x] <= ha[x] + gap for x in range(3))


def _meeting(types: list[SynthesisType], taken: list[First]) -> list[tuple[int, int]]:
    """Each two of the step's decisions whose boxes overlap or meet (corners included), as
    indices into ``taken``, the first lower."""
    boxes = [placement_box(types[i].component, yaw, t) for i, yaw, t in taken]
    return [
        (a, b)
        for a in range(len(taken))
        for b in range(a + 1, len(taken))
        if _boxes_meet(boxes[a], boxes[b], 1)
    ]


def _groups(types: list[SynthesisType], taken: list[First]) -> list[list[int]]:
    """The step's decisions in groups that touch (:func:`_meeting`), as indices into
    ``taken``, those of two or more parts and not the whole step."""
    group = list(range(len(taken)))

    def root(a: int) -> int:
        while group[a] != a:
            a = group[a]
        return a

    for a, b in _meeting(types, taken):
        group[root(b)] = root(a)
    out: dict[int, list[int]] = {}
    for a in range(len(taken)):
        out.setdefault(root(a), []).append(a)
    return [g for g in out.values() if 1 < len(g) < len(taken)]


def _touching_pairs(types: list[SynthesisType], taken: list[First]) -> list[list[int]]:
    """Each two of the step's decisions of one type that touch (:func:`_meeting`), as indices
    into ``taken``."""
    return [[a, b] for a, b in _meeting(types, taken) if taken[a][0] == taken[b][0]]


def _in_place_of(
    comp: _bg.Component, other: _bg.Component, yaw: int, t: tuple[int, int, int]
) -> list[tuple[int, tuple[int, int, int]]]:
    """The placements of ``comp`` standing where ``other`` stands at ``(yaw, t)``: each yaw,
    its box's bottom on the other's, its footprint inside the other's or holding it (a 1x1
    brick in each cell of a 1x2 slope's place), nearest the other's centre first, at most
    :data:`SWAP_PLACES`."""
    lo, hi = placement_box(other, yaw, t)
    out: list[tuple[float, int, tuple[int, int, int]]] = []
    for y in range(4):
        lo2, hi2 = component_box(comp, y)
        spans = []
        for a in (0, 2):
            size, room = hi2[a] - lo2[a], hi[a] - lo[a]
            first, last = (lo[a], hi[a] - size) if size <= room else (hi[a] - size, lo[a])
            spans.append(range(first, last + 1))
        for x0 in spans[0]:
            for z0 in spans[1]:
                t2 = (x0 - lo2[0], lo[1] - lo2[1], z0 - lo2[2])
                if any(comp.same_placement(y, t2, yy, tt) for _, yy, tt in out):
                    continue
                centre = abs(2 * x0 + hi2[0] - lo2[0] - lo[0] - hi[0]) + abs(
                    2 * z0 + hi2[2] - lo2[2] - lo[2] - hi[2]
                )
                out.append((centre, y, t2))
    out.sort(key=lambda c: c[0])
    return [(y, t2) for _, y, t2 in out[:SWAP_PLACES]]


def _overlaps(types: list[SynthesisType], f: First, g: First) -> bool:
    """Whether the boxes of two decisions overlap."""
    a, b = (placement_box(types[d[0]].component, d[1], d[2]) for d in (f, g))
    return _boxes_meet(a, b, 0)


def _seen_alike(a: _Drawn, b: _Drawn, depth: np.ndarray) -> bool:
    """Whether two candidates drawn alone (:func:`_draw_alone`) show alike (:func:`_alike`) in
    front of a shape drawn at ``depth`` (the whole image's), compared over both their boxes (a
    side stud turned away sticks out of the box drawn alone, hidden behind the shape)."""
    drawn = [d for d in (a, b) if d.own.size]
    if not drawn:
        return True
    r0, r1 = min(d.box[0].start for d in drawn), max(d.box[0].stop for d in drawn)
    c0, c1 = min(d.box[1].start for d in drawn), max(d.box[1].stop for d in drawn)

    def seen(d: _Drawn) -> np.ndarray:
        out = np.zeros((r1 - r0, c1 - c0, 3), d.rgb.dtype)
        if d.own.size:
            mine = d.own & (d.depth < depth[d.box])
            rows, cols = d.box
            out[rows.start - r0 : rows.stop - r0, cols.start - c0 : cols.stop - c0][mine] = d.rgb[
                mine
            ]
        return out

    return _alike(seen(a), seen(b), depth.size)


#: A step explained worse than this (:func:`_explained`; 1: exactly) is tried again with its
#: parts as a whole moved (:data:`SHIFTS`), each turned about itself (:data:`TURNS`), all
#: turned together (:data:`STEP_TURNS`) and its equal parts stacked (:data:`COLUMNS`): a few
#: solutions each, kept only when they explain the picture better; the searches over the
#: greedy's decisions stop at :data:`WELL_EXPLAINED`.
CLOSE = 0.99
#: Whether a step explained worse than :data:`CLOSE` has each of its parts turned about itself
#: (another yaw, the same cells: :func:`_turns`) (:func:`_solve`).
TURNS = True
#: Whether a step explained worse than :data:`CLOSE` has each of its parts moved along the view
#: ray (:func:`_ray_shifts`) (:func:`_solve`): a part drawn at the same pixels nearer or farther
#: (the upper of two equal parts stacked, put low down behind the model instead).
RAY_SHIFTS = True
#: Whether a move along the view ray is kept on the terms the ground searched wide is
#: (:func:`_wide_wins`): by any margin unless it stands a part on the ground apart from the base,
#: then by :data:`WIDE_MARGIN` and only if that part shows itself. (LeoCAD's LF20t manual 1 step
#: 4: a 1x2 grille brick hung under a plate, moved back along the ray onto the ground beside
#: nothing, 0.52 against the truth's 0.45: LeoCAD draws the grille's grooves, ours does not, and
#: far back its top hides behind the plate's edge. On its own predictions the manual lost eight
#: components after it.)
RAY_APART = True
#: A move drawn within this share of a stud's width on the picture lies along the view ray.
RAY_PX = 0.35
#: Whether a part a move along the view ray placed better is also turned there (:func:`_turns`,
#: in its box, about its own position and about each corner of its box: F20s manual 16 step
#: 10, three 1x2 plates stacked; the top one, placed low behind the model, moved up onto the
#: two, lay across them over one stud: the truth, pivoted on that stud, explains the picture
#: exactly, the placement 0.97).
RAY_TURNS = True
#: The farthest move looked at (lattice units: half-studs across, plates up or down), and how
#: many of the moves drawn shortest are tried.
RAY_REACH = (6, 12)
RAY_SHIFT_COUNT = 4
#: ... and all its parts turned together about the box they fill, where they fill it turned
#: (:func:`_step_turns`).
STEP_TURNS = True
#: Choices of each of a step's rounds (its decision included) looked at for placements drawn
#: like the decision (:func:`_solve`'s last pass; 1: none).
TIE_CHOICES = 3
#: Whether a step explained worse than :data:`CLOSE` has each group of its parts that touch
#: (:func:`_groups`) turned together (:func:`_step_turns`), the others kept (:func:`_solve`).
GROUP_TURNS = True
#: Whether each two touching parts of one type (:func:`_touching_pairs`) are turned together
#: too, the others kept, in a step of three or more parts: F20r manual 13 step 13, four 1x2
#: grille bricks in a row, two of them placed across the row side by side; the four touch, so
#: the only group is the whole row.
PAIR_TURNS = True
#: Whether a step of a single part explained worse than :data:`CLOSE` (not only than
#: :data:`WELL_EXPLAINED`) has its round's next choices tried (:func:`_solve`): each is one
#: placement scored, no greedy run after it.
LONE_CHOICES = True
#: Whether a part's move that does not fit with the step's later decisions kept (a turned
#: part in a neighbour's cells) is tried again with those placed anew by the greedy
#: (:func:`_solve`'s ``each_part``).
MOVES_REPLACE = True
#: Whether :data:`TURNS` also turns each part about its own position (other cells), not only
#: within the box it fills (:func:`_turns`).
TURNS_IN_PLACE = True
#: Whether a forced decision of :func:`_greedy`'s ``prefix`` that does not fit yet waits for
#: the others (a column hung under a plate, given bottom first); else the greedy stops there.
DEFER_FORCED = True
#: A multi-instance step whose parts explain the changed pixels at least this well
#: (:func:`_explained`) is kept as the greedy solved it. (0.95 until stop 43: scoring the
#: pixels a part draws in the picture's own colour as no evidence, :data:`QUIET_LEVEL`, lifts
#: wrong solutions too, and S20 manuals 15 step 7 and 16 step 8 stopped short of the revisits
#: that found their truth; 0.97: 4-5% more CPU a step.)
WELL_EXPLAINED = 0.97
#: Whether a multi-instance step explained worse is also solved with each later decision of
#: the greedy taken first (:func:`_solve`).
LATER_FIRST = True
#: ... and the later decisions of the solution the revisits found too (each decision tried
#: first on its own once).
LATER_FIRST_AGAIN = True
#: Choices tried at each decision of a multi-instance step explained worse (the greedy's own
#: included).
FIRST_CHOICES = 3
#: ... and at its first decision, which all the others are taken in the light of (two equal
#: bricks side by side: the greedy's first puts one across the middle of both, the true left
#: one is its fourth choice).
LEAD_CHOICES = 4

#: A decision of :func:`_greedy`: (type index, yaw, translation).
First = tuple[int, int, tuple[int, int, int]]

#: Whether a decision forced first (:data:`LATER_FIRST`, a revisit's prefix) keeps its round's
#: ranking, so that a revisit can try its next choices (:func:`_greedy`).
REVISIT_FORCED = True
#: Whether the first decision of a multi-type step explained worse also tries each other
#: type's best placement of its round (:func:`_choices`): its best choices may all be one
#: type's (the slope on top of a first step, in six places), while the part under it, which
#: must go first, ranks further down.
TYPE_LEADS = True


def _choices(options: list[First], n: int, level: int) -> list[First]:
    """The choices a revisit tries at a decision: the round's ``n`` best (``options``, best
    first: the greedy's own first), and at the first decision (``level`` 0, with
    :data:`TYPE_LEADS`) each other type's best after them."""
    out = list(options[:n])
    if TYPE_LEADS and level == 0:
        seen = {f[0] for f in out}
        for f in options[n:]:
            if f[0] not in seen:
                seen.add(f[0])
                out.append(f)
    return out


#: Whether a step of three or more instances explained worse than :data:`WELL_EXPLAINED` is
#: also solved with each pair of its decisions taken again last (:func:`_solve`).
PAIRS = True
#: Choices tried for the first of a pair taken again (its greedy's own included).
PAIR_CHOICES = 4
#: Passes over the pairs (a pair taken again may leave another pair to mend).
PAIR_PASSES = 2
#: Whether a step of two or more parts explained worse than :data:`WELL_EXPLAINED` also has
#: each part put at the place of each part of another type, the others kept but the one
#: there, which is placed again (:func:`_in_place_of`).
SWAPS = True
#: Placements tried for a part at another's place (per yaw and cell of the other's footprint).
SWAP_PLACES = 4
#: Whether a step adding several identical parts explained worse than :data:`CLOSE`
#: is also solved with them stacked in one column (:func:`_columns`).
COLUMNS = True
#: Column placements tried per type.
COLUMN_CHOICES = 3
#: Moves (lattice cells along x and z) of all a step's parts together tried when the step is
#: explained worse than :data:`CLOSE` (:func:`_solve`).
SHIFTS = ((1, 0), (-1, 0), (0, 1), (0, -1), (2, 0), (-2, 0), (0, 2), (0, -2))
#: ... for a step of at least this many parts. 1 (a single part moved too) mends S22 manual 6
#: step 13, a slope whose best-ranked placements all lie a cell off the drawn one, but on the
#: fresh set LF20c it moved 2 single parts that were right a cell off, and mended none of
#: F20c's (stop 45): a lone part's shift wins on noise more often than on evidence.
SHIFT_MIN_PARTS = 2
#: Whether each part of a step of two or more is also moved a cell (:data:`SHIFTS`' first four,
#: and :data:`CELL_DIAGONALS`) on its own, the others kept (:func:`_solve`).
PART_SHIFTS = True
#: The moves of each part on its own (:data:`PART_SHIFTS`) beyond a cell along x or z: a cell
#: along both (LeoCAD's LF20n manual 11 step 9: a 2x2 round plate hung under the model,
#: mostly hidden, placed a cell off along both; no single move along one axis explains more).
CELL_DIAGONALS: tuple[tuple[int, int], ...] = ((1, 1), (1, -1), (-1, 1), (-1, -1))
#: How much better (:func:`_explained`) a step solved with a column must explain its picture
#: than the step solved without one ...
COLUMN_MARGIN = 0.03
#: ... or this share of what that leaves unexplained, if less (S20 manual 19 step 1: a column
#: explaining a first step exactly, 1.0 against the greedy's 0.97).
COLUMN_SHARE = 0.5


#: Whether a step explained worse than :data:`CLOSE` has its least seen parts placed again
#: where its changed pixels are left unexplained (:func:`_relocations`).
RELOCATE = True
#: ... when at least this many changed pixels are drawn by none of the step's parts ...
RELOCATE_PX = 20
#: ... of the step's parts showing less than this share of themselves ...
RELOCATE_SEEN = 0.5
#: ... the parts tried, least seen first; the placements tried for each: the best by the IoU
#: with those pixels, and as many showing most of them (of :data:`RELOCATE_RANKED` by IoU).
RELOCATE_PARTS = 2
RELOCATE_CHOICES = 3
#: Whether each placement a part is relocated to is also tried turned (:func:`_turns`).
RELOCATE_TURNS = True
RELOCATE_RANKED = 16


def _relocations(
    ctx: StepContext,
    types: list[SynthesisType],
    taken: list[First],
    mask: np.ndarray,
    picture_edges: np.ndarray | None,
    time_limit_s: float,
    wide: bool,
    deadline: float,
) -> list[list[First]]:
    """The step's decisions with one of its least seen parts (fewest pixels drawn in the shape
    with all of them) taken out and placed last where it best explains what the step's parts
    leave unexplained, with its own pixels: the changed pixels (``mask``) none of them draws
    and the picture's edges (``picture_edges``) the shape draws nowhere
    (:func:`_edge_maps`: a new part in front of one of its own colour changes the picture
    little but draws its outline); ``abys_ranked`` on the shape without it. None when fewer
    than :data:`RELOCATE_PX` such pixels are left."""
    w, h = ctx.image_size
    n0 = len(ctx.base)
    shape = ctx.base.copy()
    for i, yaw, tr in taken:
        shape.add(types[i].component, yaw, tr, ctx.colour(types[i].entry))
    r = _bg.render(shape, ctx.camera, w, h, unlined=picture_edges is not None)
    ids = r.ids
    unexplained = mask & (ids < n0)
    if picture_edges is not None:
        box, _, undrawn = _edge_maps(r, ids >= n0, mask, picture_edges)
        unexplained[box] |= undrawn
    if int(unexplained.sum()) < RELOCATE_PX:
        return []
    seen = np.bincount(ids[ids >= n0] - n0, minlength=len(taken))
    out: list[list[First]] = []
    for k in [int(k) for k in np.argsort(seen, kind="stable")[:RELOCATE_PARTS]]:
        i, yaw_k, t_k = taken[k]
        comp = types[i].component
        alone = _draw_alone(comp, yaw_k, t_k, 0, ctx.camera, w, h)
        if seen[k] >= RELOCATE_SEEN * int(alone.own.sum()):
            continue  # the picture shows it: its place is evidenced
        rest = [d for j, d in enumerate(taken) if j != k]
        without = ctx.base.copy()
        for j, yaw, tr in rest:
            without.add(types[j].component, yaw, tr, 0)
        limit = min(time_limit_s, max(deadline - _clock(), MIN_SEARCH_S))
        target = unexplained | (ids == n0 + k)
        ranked, _ = _bg.abys_ranked(
            without, ctx.camera, w, h, comp, target, RELOCATE_RANKED, limit, wide_ground=wide
        )
        # the best by IoU, and the best by how many of those pixels each shows: the IoU prefers
        # a part hidden but for a sliver over one whose face the picture draws in the colour of
        # the part behind it (unchanged, so outside the mask, but no evidence against it)
        depth = _bg.render(without, ctx.camera, w, h, line_px=0.0).depth
        shown = []
        for yaw, tr, iou in ranked:
            f = (i, int(yaw), (int(tr[0]), int(tr[1]), int(tr[2])))
            if f == taken[k]:
                continue
            d = _draw_alone(comp, f[1], f[2], 0, ctx.camera, w, h)
            seen_px = d.own & (d.depth < depth[d.box])
            shown.append((int((seen_px & target[d.box]).sum()), float(iou), f))
        by_iou = [f for _, _, f in shown[:RELOCATE_CHOICES]]
        shown.sort(key=lambda x: (-x[0], -x[1]))
        by_shown = [f for _, _, f in shown[:RELOCATE_CHOICES] if f not in by_iou]
        # each also turned (:func:`_turns`, about itself too): a part shown by a sliver ranks
        # its yaws there alike, and the true one may not be among the first
        tried: list[First] = []
        for f in by_iou + by_shown:
            turned = (
                [(i, y, t) for y, t in _turns(comp, f[1], f[2], True)] if RELOCATE_TURNS else []
            )
            for g in [f, *turned]:
                if g != taken[k] and not any(
                    comp.same_placement(g[1], g[2], e[1], e[2]) for e in tried
                ):
                    tried.append(g)
        out.extend([*rest, f] for f in tried)
    return out


def _columns(
    ctx: StepContext,
    types: list[SynthesisType],
    taken: list[First],
    time_limit_s: float,
    wide: bool,
    deadline: float,
) -> list[list[First]]:
    """For each type of two or more instances of one part, the best placements of all of them
    stacked straight up (each on the one below, same yaw), as decisions for :func:`_greedy`,
    bottom first: the column is ranked as one component (``abys_ranked`` on the type's mask
    less the pixels the other types' parts in ``taken`` draw: on a build's first step every
    type's mask is the whole picture)."""
    w, h = ctx.image_size
    out: list[list[First]] = []
    ids = None
    for i, t in enumerate(types):
        comp = t.component
        if t.count < 2 or comp.is_submodule or not t.mask.any():
            continue
        if ids is None:
            shape = ctx.base.copy()
            for j, yaw, tr in taken:
                shape.add(types[j].component, yaw, tr, 0)
            ids = _bg.render(shape, ctx.camera, w, h, line_px=0.0).ids
        n0 = len(ctx.base)
        others = [n0 + x for x, (j, _, _) in enumerate(taken) if j != i]
        mask = t.mask & ~np.isin(ids, others)
        if not mask.any():
            continue
        height = int(np.ptp(comp.voxels[:, 1])) + 1
        poses = np.array([[0, 0, k * height, 0] for k in range(t.count)], np.int64)
        try:
            column = _bg.Component.from_bricks("column", [comp.name] * t.count, poses)
        except BrickGeomError:
            continue
        limit = min(time_limit_s, max(deadline - _clock(), MIN_SEARCH_S))
        ranked, _ = _bg.abys_ranked(
            ctx.base, ctx.camera, w, h, column, mask, COLUMN_CHOICES, limit, wide_ground=wide
        )
        for yaw, tr, _ in ranked:
            t0 = (int(tr[0]), int(tr[1]), int(tr[2]))
            out.append(
                [(i, (yaw + b) % 4, rotate_lattice(bt, yaw, t0)) for _, b, bt, _ in column.bricks]
            )
    return out


def edge_map(rgb: np.ndarray) -> np.ndarray:
    """(H, W) bool: where ``rgb`` ((H, W, 3) floats in [0, 1]) changes colour: a channel's
    Sobel gradient magnitude reaches :data:`EDGE_THRESHOLD`."""
    p = np.pad(rgb, ((1, 1), (1, 1), (0, 0)), mode="edge")
    gx = (p[:-2, 2:] + 2 * p[1:-1, 2:] + p[2:, 2:]) - (p[:-2, :-2] + 2 * p[1:-1, :-2] + p[2:, :-2])
    gy = (p[2:, :-2] + 2 * p[2:, 1:-1] + p[2:, 2:]) - (p[:-2, :-2] + 2 * p[:-2, 1:-1] + p[:-2, 2:])
    return (gx * gx + gy * gy).max(axis=2) >= EDGE_THRESHOLD**2


def _edge_disagreement(
    drawn: _bg.Rendering, new: np.ndarray, mask: np.ndarray, picture_edges: np.ndarray
) -> tuple[int, int]:
    """The edges a shape (the base and the step's parts, drawn ``new``; ``drawn``: its render
    with ``unlined=True``) shows without outlines where the picture (its :func:`edge_map`
    ``picture_edges``) has none within a pixel, and the picture's edges it draws neither so nor
    with outlines within a pixel, counted within 2 pixels of the parts and where the picture
    changed (``mask``): a renderer shows every face's outline as a change of colour, and may or
    may not draw lines. Returns the two counts (shown, not drawn)."""
    _, unseen, undrawn = _edge_maps(drawn, new, mask, picture_edges)
    return int(unseen.sum()), int(undrawn.sum())


def _edge_maps(
    drawn: _bg.Rendering, new: np.ndarray, mask: np.ndarray, picture_edges: np.ndarray
) -> tuple[tuple[slice, slice], np.ndarray, np.ndarray]:
    """:func:`_edge_disagreement`'s pixels: the box it looks in, and within it the edges shown
    where the picture has none and the picture's edges drawn in neither drawing."""
    lined, unlined = drawn.rgb, drawn.rgb_unlined
    assert unlined is not None, "the shape is drawn with unlined=True"
    h, w = new.shape
    near = new | mask
    rows, cols = np.nonzero(near.any(axis=1))[0], np.nonzero(near.any(axis=0))[0]
    box = (
        slice(max(int(rows[0]) - 4, 0), min(int(rows[-1]) + 5, h)),
        slice(max(int(cols[0]) - 4, 0), min(int(cols[-1]) + 5, w)),
    )
    near = _max_filter(new[box], 2) | mask[box]
    plain = edge_map(unlined[box] / 255.0) & near
    seen = picture_edges[box] & near
    unseen = plain & ~_max_filter(seen, 1)  # shown, the picture shows none
    undrawn = seen & ~_max_filter(plain | edge_map(lined[box] / 255.0), 1)  # in neither drawing
    return box, unseen, undrawn


#: Whether a renderer that casts shadows (:class:`Tone`) may draw a part darker, hue kept
#: (:func:`_colour_off`).
SHADOW_RESIDUAL = True
#: ... at this cost (largest channel, in [0, 1]) over the darkened colour's residual: drawn in
#: shadow is a little less likely than drawn lit.
SHADOW_COST = 0.03


def _colour_off(
    picture: np.ndarray, rgb: np.ndarray, tone: Tone, colour: np.ndarray | None = None
) -> np.ndarray:
    """Per pixel ((N, 3): the picture's colours in [0, 1] and mepnet's rendered ones, uint8) the
    largest channel difference after the tone fit; where the renderer casts shadows, no more
    than the colour darkened by a factor in :data:`mepnet.state.SHADOW_FACTORS` differs, plus
    :data:`SHADOW_COST`."""
    drawn = rgb / 255.0
    if tone.factors is not None and colour is not None:
        drawn = np.minimum(drawn * tone.factors[_shade_level(rgb, colour)][:, None], 1.0)
    expected = drawn * tone.gain + tone.bias
    off = np.abs(picture - expected).max(axis=1)
    if tone.shadows and SHADOW_RESIDUAL:
        f = np.clip(darkening(picture, expected, axis=1), *SHADOW_FACTORS)
        dark = np.abs(picture - f[:, None] * expected).max(axis=1) + SHADOW_COST
        off = np.minimum(off, dark)
    return off


#: A step's part drawn where the picture did not change and within this much (largest channel,
#: in [0, 1], after the tone fit) of the picture's colour counts neither for nor against it in
#: :func:`_explained`'s IoU (0: counts against).
QUIET_LEVEL = 0.1
#: Whether a step's part drawn where the picture did not change, in front of a part of the
#: base of its own colour, counts neither for nor against it either, whatever colour the
#: picture draws there (:func:`_base_colours`).
QUIET_BEHIND = True


def _base_colours(ctx: StepContext) -> np.ndarray:
    """(H, W): the LDraw colour of the base's part drawn at each pixel with the step's camera
    (-1: none)."""
    w, h = ctx.image_size
    ids = _bg.render(ctx.base, ctx.camera, w, h, line_px=0.0).ids
    colours = np.array([ctx.base.colour(i) for i in range(len(ctx.base))] + [-1], np.int64)
    return colours[ids]  # the page (-1) indexes the last


#: A step's part placed where nothing of it is drawn (hidden behind the base or the step's other
#: parts) costs this share of :func:`_explained`'s score, as a part not placed does: a manual
#: shows what each step adds, so a placement the picture cannot show is no explanation of it.
HIDDEN_COST = 0.5


def _solution_key(preds: list[Prediction]) -> tuple[Any, ...]:
    """What :func:`_explained` scores of a step's solution: its placements by callout entry,
    in any order (the greedy's revisits reach one solution by many orders)."""
    return tuple(
        sorted(
            (p.entry, -1 if p.yaw is None else int(p.yaw), () if p.t is None else tuple(p.t))
            for p in preds
        )
    )


def _scored(
    scores: dict[tuple[Any, ...], float],
    ctx: StepContext,
    preds: list[Prediction],
    *explained: Any,
) -> float:
    """:func:`_explained` of ``preds`` (its further arguments ``explained``), from ``scores``
    (by :func:`_solution_key`) when the solution was scored before, else scored and kept there."""
    key = _solution_key(preds)
    if key not in scores:
        scores[key] = _explained(ctx, preds, *explained)
    return scores[key]


def _explained(
    ctx: StepContext,
    preds: list[Prediction],
    mask: np.ndarray,
    picture: np.ndarray | None,
    tone: Tone,
    picture_edges: np.ndarray | None = None,
    base_colours: np.ndarray | None = None,
) -> float:
    """How well a step's predicted parts together explain its picture: the IoU of their
    visible pixels with the changed pixels ``mask``, less the colour residual over them, less
    the edge disagreement (:func:`_edge_disagreement`, :data:`EDGE_WEIGHT`,
    :data:`SHOWN_EDGE_WEIGHT`; ``picture_edges``: the picture's :func:`edge_map`, None: not
    weighed). ``base_colours``: :func:`_base_colours` of the step when the caller has them
    (else drawn here when :data:`QUIET_BEHIND` needs them)."""
    w, h = ctx.image_size
    n0 = len(ctx.base)
    asm = _with_parts(ctx, preds)
    weigh_edges = picture_edges is not None and EDGE_WEIGHT != 0
    r = _bg.render(asm, ctx.camera, w, h, unlined=weigh_edges)
    new = r.ids >= n0
    union = int((new | mask).sum())
    off = None  # per pixel the parts draw: the largest channel difference from the picture
    if picture is not None and new.any():
        off = _colour_off(picture[new], r.rgb[new], tone, _part_colours(asm, n0)[r.ids[new] - n0])
        if QUIET_LEVEL > 0:
            # a part drawn in the picture's own colour where the picture did not change (in
            # front of a part of its colour) is no evidence against it: out of the IoU
            quiet = (off < QUIET_LEVEL) & ~mask[new]
            if QUIET_BEHIND:
                # ... nor where it stands in front of a part of the base of its own colour,
                # however the manual's renderer shades that colour
                behind = _base_colours(ctx) if base_colours is None else base_colours
                part = np.array([asm.colour(i) for i in range(n0, len(asm))], np.int64)
                quiet |= ~mask[new] & (behind[new] == part[r.ids[new] - n0])
            union -= int(quiet.sum())
    score = float((new & mask).sum() / union) if union else 0.0
    if off is not None:
        score -= COLOUR_WEIGHT * float(off.mean())
    if picture_edges is not None and weigh_edges and union:
        unseen, undrawn = _edge_disagreement(r, new, mask, picture_edges)
        score -= (EDGE_WEIGHT * undrawn + SHOWN_EDGE_WEIGHT * unseen) / union
    cost = 0.5 * sum(1 for p in preds if not p.placed)
    if HIDDEN_COST:
        cost += HIDDEN_COST * (len(asm) - n0 - len(np.unique(r.ids[new])))
    return score - cost / max(len(preds), 1)


@dataclass(frozen=True)
class _Drawn:
    """A candidate placement drawn alone (:func:`_draw_alone`), cropped to the box it covers."""

    box: tuple[slice, slice]
    #: its pixels, its depth and its colours within ``box``
    own: np.ndarray
    depth: np.ndarray
    rgb: np.ndarray


def _part_colours(asm: _bg.Assembly, n0: int) -> np.ndarray:
    """(N, 3): the rgb of each of ``asm``'s instances from the ``n0``-th on (a step's parts on
    its base), in order."""
    return np.array(
        [_bg.colour_rgb(asm.colour(i)) for i in range(n0, len(asm))], np.float64
    ).reshape(-1, 3)


def _draw_alone(
    comp: _bg.Component,
    yaw: int,
    t: tuple[int, int, int],
    colour: int,
    cam: _bg.Camera,
    w: int,
    h: int,
) -> _Drawn:
    """``comp`` at ``(yaw, t)`` in ``colour`` drawn alone with ``cam``, cropped to its pixels."""
    alone = _bg.Assembly()
    alone.add(comp, yaw, t, colour)
    r = _bg.render(alone, cam, w, h)
    own = r.ids == 0
    rows, cols = np.nonzero(own.any(axis=1))[0], np.nonzero(own.any(axis=0))[0]
    box = (
        (slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1))
        if len(rows)
        else (slice(0, 0), slice(0, 0))
    )
    return _Drawn(box, own[box], r.depth[box], r.rgb[box])


#: On a build's first step (no base: no tone fitted, :func:`step_change`) a placed part's
#: pixels are compared with the picture after a gain per channel fitted on them
#: (:func:`_own_gain_off`), not as drawn: LeoCAD draws magenta (5) half again as bright as we
#: do, and unfitted, 63% of a 1x8 brick's pixels on F20y manual 12's first picture stayed
#: unexplained, so the grille brick beside it was searched for over the brick's face.
FIRST_CLAIM_GAIN = True
#: The gains :func:`_own_gain_off` may fit (a part of another colour in front of the placed
#: one, most of its pixels, fits none).
CLAIM_GAINS = (0.6, 1.6)


def _own_gain_off(picture: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """Per pixel ((N, 3): the picture's colours in [0, 1], mepnet's rendered ones, uint8) the
    largest channel difference once each channel of the drawing is scaled by the median ratio
    of picture to drawing over the pixels (within :data:`CLAIM_GAINS`)."""
    drawn = rgb / 255.0
    gain = np.median((picture + 0.02) / (drawn + 0.02), axis=0)
    gain = np.clip(gain, *CLAIM_GAINS)
    return np.abs(picture - np.minimum(drawn * gain, 1.0)).max(axis=1)


#: A placed part explains the changed pixels it is drawn in front at for the greedy's later
#: rounds only where it draws them within this much of the picture's colour (largest channel,
#: in [0, 1], after the tone fit; inf: wherever it is drawn): a part placed first may stand
#: behind one of a later round, which the picture shows in front of it in another colour.
CLAIM_OFF = 0.3


def _greedy(
    ctx: StepContext,
    types: list[SynthesisType],
    time_limit_s: float,
    picture: np.ndarray | None,
    tone: Tone,
    prefix: list[First],
    wide: bool = False,
    memo: dict[frozenset[First], tuple[Any, list[tuple[float, First]]]] | None = None,
    deadline: float = float("inf"),
    drawn: dict[First, _Drawn] | None = None,
    ranked: int = RANKED,
) -> tuple[list[Prediction], list[First], list[list[First]]]:
    """The greedy of :func:`synthesize`, its first decisions forced to ``prefix``, the ground
    searched wherever the picture changed when ``wide``, each placement search limited to
    ``time_limit_s`` and to what is left before ``deadline`` (at least :data:`MIN_SEARCH_S`).
    Returns the
    predictions, the decision taken at each round and each unforced round's candidates, best
    first (distinct placements: a symmetric part's equal yaws once).

    ``memo``: a round's ranking by the set of placements made before it, shared by the greedy
    runs of one solve (what a round sees -- the shape, the pixels left to explain, the
    instances left -- depends only on that set, not on the order it was placed in).
    ``drawn``: each candidate drawn alone (:func:`_draw_alone`), shared the same way.
    ``ranked``: the distinct placements each round scores (:data:`RANKED`)."""
    w, h = ctx.image_size
    drawn = {} if drawn is None else drawn
    asm = ctx.base.copy()
    n0 = len(asm)
    cam = ctx.camera
    left = [t.count for t in types]
    unexplained = np.ones((h, w), dtype=bool)
    colours = [ctx.colour(t.entry) for t in types]
    rgb_of = [np.asarray(_bg.colour_rgb(c), np.float64) for c in colours]

    def alone(f: First) -> _Drawn:
        """The placement ``f`` drawn alone, from ``drawn`` or drawn now and kept there."""
        if f not in drawn:
            i, yaw, tr = f
            drawn[f] = _draw_alone(types[i].component, yaw, tr, colours[i], cam, w, h)
        return drawn[f]

    preds: list[Prediction] = []
    taken: list[First] = []
    options: list[list[First]] = []
    waiting = list(prefix)  # the forced decisions not yet placed
    shape_depth: np.ndarray | None = None  # of asm, rendered when first needed
    # the first instance id placed since the shape was last drawn: drawn again only when a
    # round searches (forced and remembered rounds, and the last, need no drawing)
    pending: int | None = None
    while any(left):
        best: tuple[float, int, tuple[int, tuple[int, int, int]], dict[str, Any]] | None = None
        ranked_here: list[tuple[float, First]] = []
        forced = bool(waiting)
        key = frozenset(taken)
        cached = not forced and memo is not None and key in memo
        if forced:
            # the first forced decision that fits now (:data:`DEFER_FORCED`: one that does not
            # waits for the others, a part hung under one placed after it in ``prefix``)
            for k, (i, yaw, tr) in enumerate(waiting if DEFER_FORCED else waiting[:1]):
                try:
                    new_id, attach = asm.add_checked(types[i].component, yaw, tr)
                except BrickGeomError:
                    continue
                del waiting[k]
                break
            else:
                return preds, taken, options  # no forced decision fits
            best = (0.0, i, (yaw, tr), {"forced": True})
            if REVISIT_FORCED and memo is not None and key in memo:
                # the round's own ranking, as an unforced greedy found it: the choices a
                # revisit of this decision tries
                ranked_here = memo[key][1]
        elif cached:
            best, ranked_here = memo[key]  # type: ignore[index]
        elif pending is not None:
            # what the parts placed since explain: the pixels one of them is drawn in front
            # (every pixel a part was in front of when placed stays one of theirs)
            shape = _bg.render(asm, cam, w, h, line_px=0.0)
            claimed = shape.ids >= pending
            if CLAIM_OFF < float("inf") and picture is not None:
                # ... where it draws about the picture's colour: a part in front of it that
                # the picture shows (drawn there in its own colour) may still explain the rest
                for k in range(pending, len(asm)):
                    f = taken[k - n0]
                    d = alone(f)
                    mine = (shape.ids[d.box] == k) & d.own
                    if mine.any():
                        seen = picture[d.box][mine]
                        if n0 == 0 and FIRST_CLAIM_GAIN:
                            off = _own_gain_off(seen, d.rgb[mine])
                        else:
                            off = _colour_off(seen, d.rgb[mine], tone, rgb_of[f[0]])
                        claimed[d.box][mine] = off <= CLAIM_OFF  # a view: written through
            unexplained &= ~claimed
            shape_depth = shape.depth  # this round's candidates are drawn against it
            pending = None
        for i, t in enumerate(types):
            if forced or cached or not left[i]:
                continue
            m = t.mask & unexplained
            if not m.any():
                continue
            limit = min(time_limit_s, max(deadline - _clock(), MIN_SEARCH_S))
            found, timed_out = _bg.abys_ranked(
                asm, cam, w, h, t.component, m, 4 * ranked, limit, wide_ground=wide
            )
            distinct: list[tuple[int, tuple[int, int, int], float]] = []
            for yaw, tr, iou in found:
                if not any(t.component.same_placement(y, u, yaw, tr) for y, u, _ in distinct):
                    distinct.append((yaw, tuple(tr), iou))  # type: ignore[arg-type]
                if len(distinct) == ranked:
                    break
            if shape_depth is None:
                shape_depth = _bg.render(asm, cam, w, h, line_px=0.0).depth
            for yaw, tr, iou in distinct:
                score = iou
                # the candidate drawn alone, its visible pixels those in front of the shape
                # (all within the box it is drawn in)
                d = alone((i, yaw, tr))
                box = d.box
                vis = d.own & (d.depth < shape_depth[box])
                if vis.any() and TYPE_WEIGHT and t.belief is not None:
                    score += TYPE_WEIGHT * float(t.belief[box][vis].mean())
                if KEYPOINT_WEIGHT and t.heat is not None:
                    x, y = _keypoint_px(t.component, yaw, tr, cam, w, h)
                    if 0 <= x < w and 0 <= y < h:
                        score += KEYPOINT_WEIGHT * float(t.heat[int(y), int(x)])
                if vis.any() and picture is not None:
                    diff = _colour_off(picture[box][vis], d.rgb[vis], tone, rgb_of[i])
                    score -= COLOUR_WEIGHT * float(diff.mean())
                ranked_here.append((score, (i, yaw, tr)))
                if best is None or score > best[0]:
                    best = (score, i, (yaw, tr), {"iou": iou, "timed_out": timed_out})
        if memo is not None and not forced and not cached:
            memo[key] = (best, ranked_here)
        if best is None:
            for i, t in enumerate(types):
                ref = ctx.step.components[t.entry].component
                preds += [
                    Prediction(t.entry, ref, None, None, failure="no placement fits its mask")
                    for _ in range(left[i])
                ]
                left[i] = 0
            break
        _, i, (yaw, tr), extra = best
        if not forced:
            try:
                new_id, attach = asm.add_checked(types[i].component, yaw, tr)
            except BrickGeomError:  # a ranked placement is valid: kept as a guard
                return preds, taken, options
        taken.append((i, yaw, tr))
        options.append([f for _, f in sorted(ranked_here, key=lambda x: -x[0])])
        if pending is None:
            pending = new_id
        left[i] -= 1
        entry = types[i].entry
        ref = ctx.step.components[entry].component
        preds.append(Prediction(entry, ref, yaw, tr, attach=attach, extra=extra))
    return preds, taken, options


class SynthesisPredictor(Predictor):
    """Stage 2 by synthesis alone, no detector: every type may be anywhere the picture changed
    (the ablation that shows what the detector's beliefs add)."""

    name = "synthesis"

    def __init__(self, time_limit_s: float = 10.0):
        self.time_limit_s = time_limit_s

    def predict(self, ctx: StepContext) -> list[Prediction]:
        picture = step_picture(ctx)
        change, tone = step_change(ctx, picture)
        support = change > CHANGE_THRESHOLD
        types = [
            SynthesisType(k, ctx.components[sc.component], sc.count, support)
            for k, sc in enumerate(ctx.step.components)
        ]
        return synthesize(ctx, types, self.time_limit_s, picture, tone)
