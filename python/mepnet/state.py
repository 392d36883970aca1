"""The base shape as the manual's camera sees it, without torch: the first-hit projection of
its voxels, rendered state maps, and the change map between a step's picture and the picture
of the shape before the step (used by the detector's inputs and by stage 2's synthesis)."""

from __future__ import annotations

from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.geom import LDU_PER_CELL
from mepnet.manual.page import make_camera

__all__ = [
    "CHANGE_THRESHOLD",
    "STATE_MAPS",
    "change_map",
    "fit_gain_bias",
    "fit_tone",
    "outline_of",
    "previous_change",
    "same_view",
    "shade_classes",
    "shade_tones",
    "state_projection",
    "state_render",
    "warp_previous",
]

#: A pixel of the change map above this is part of something new.
CHANGE_THRESHOLD = 0.15
#: Channels of the rendered state maps (see :func:`state_projection` and :func:`change_map`).
STATE_MAPS = 10


def outline_of(ids: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of an instance map (background -1) with a 4-neighbour of another
    instance or of the background -- both sides of every part and silhouette edge."""
    pad = np.pad(ids, 1, mode="edge")
    return (
        (pad[1:-1, 1:-1] != pad[:-2, 1:-1])
        | (pad[1:-1, 1:-1] != pad[2:, 1:-1])
        | (pad[1:-1, 1:-1] != pad[1:-1, :-2])
        | (pad[1:-1, 1:-1] != pad[1:-1, 2:])
    )


def state_render(
    asm: _bg.Assembly, camera: dict[str, Any], size: int
) -> tuple[np.ndarray, np.ndarray]:
    """The base shape rendered in the manual's style, (3, size, size) RGB in [0, 1] on white
    paper (what the step's picture would look like without the step), and the outlines of its
    parts, (size, size) bool (:func:`outline_of`)."""
    if len(asm) == 0:
        return np.ones((3, size, size), np.float32), np.zeros((size, size), bool)
    r = _bg.render(asm, make_camera(camera), size, size)
    return r.rgb.transpose(2, 0, 1).astype(np.float32) / 255.0, outline_of(r.ids)


def state_projection(
    asm: _bg.Assembly, camera: dict[str, Any], size: int, grid: tuple[int, int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """The first-hit projection of the base shape into the camera frame, at ``size`` pixels.

    brickgeom rasterizes the base shape (its real meshes, studs included) and gives the depth
    of the first surface each pixel's ray hits; the hit point is lifted back to the world and
    walked a little further along the ray to the first occupied voxel of the config's window.
    Returns the flat index of that voxel in the (Z, Y, X) window per pixel (-1 where the ray
    hits nothing) -- the network gathers its 3D features there -- and ``STATE_MAPS`` maps: hit,
    depth (relative to the nearest hit, /100 LDU), the outlines of the base's parts, and the
    hit point's world coordinates (/100 LDU), and the base shape rendered in the manual's style
    (RGB in [0, 1], white background): what the picture would look like without the step, so
    the new components are what differs (analysis-by-synthesis as an input)."""
    gx, gy, gz = grid
    maps = np.zeros((STATE_MAPS, size, size), np.float32)
    maps[6:9] = 1.0  # white paper
    index = np.full((size, size), -1, np.int64)
    if len(asm) == 0:
        return index, maps
    cam = make_camera(camera)
    r = _bg.render(asm, cam, size, size)
    maps[6:9] = r.rgb.transpose(2, 0, 1) / 255.0  # as state_render, from the same render
    depth, ids = r.depth, r.ids
    hit = np.isfinite(depth)
    if not hit.any():
        return index, maps
    rows, cols = np.nonzero(hit)
    ndc_x = (cols + 0.5) / size * 2 - 1
    ndc_y = 1 - (rows + 0.5) / size * 2
    tx, ty = camera["translation"]
    u = (ndc_x - tx) / camera["scale"]
    v = (ndc_y - ty) / camera["scale"]
    rot = cam.rotation()
    d = depth[rows, cols].astype(np.float64)
    surface = u[:, None] * rot[0] + v[:, None] * rot[1] + d[:, None] * rot[2]  # (n, 3) LDU
    occ, _ = asm.occupancy((-gx // 2, 0, -gz // 2), (gx // 2 - 1, gy - 1, gz // 2 - 1))
    lo = np.array([-gx // 2, 0, -gz // 2])
    found = np.full(len(d), -1, np.int64)
    # studs stand 4 LDU above their voxel and the surface sits on a cell boundary: step into
    # the solid along the ray until an occupied voxel turns up (or give up after 16 LDU)
    for step in np.arange(0.5, 16.0, 2.0):
        todo = found < 0
        if not todo.any():
            break
        cell = np.floor((surface[todo] + step * rot[2]) / LDU_PER_CELL).astype(np.int64) - lo
        inside = np.all((cell >= 0) & (cell < np.array(grid)), axis=1)
        ok = np.zeros(len(cell), bool)
        c = cell[inside]
        ok[inside] = occ[c[:, 0], c[:, 1], c[:, 2]] > 0
        flat = (cell[:, 2] * gy + cell[:, 1]) * gx + cell[:, 0]
        idx = np.nonzero(todo)[0]
        found[idx[ok]] = flat[ok]
    index[rows, cols] = found
    maps[0][hit] = 1.0
    maps[1][hit] = (d - d.min()) / 100.0
    maps[2][outline_of(ids)] = 1.0
    maps[3:6][:, rows, cols] = (surface / 100.0).T
    return index, maps


def fit_gain_bias(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """The gain and bias mapping most of ``x`` (the state render) onto ``y`` (the picture):
    two starts, the least-squares line over all pixels and the identity shifted by the median
    difference; the one more pixels follow within 0.1 is refitted on those pixels, twice. (The
    least-squares start alone fails when large new parts cover a light background: pulled by
    them, it leaves even the background unexplained.)"""
    starts = [(1.0, float(np.median(y - x)))]
    if x.size >= 16 and x.var() >= 1e-4:
        g = float(((x - x.mean()) * (y - y.mean())).mean() / x.var())
        starts.append((g, float(y.mean() - g * x.mean())))
    gain, bias = max(starts, key=lambda s: int((np.abs(y - (s[0] * x + s[1])) < 0.1).sum()))
    for _ in range(2):  # refit on the pixels the fit explains (not the new parts)
        keep = np.abs(y - (gain * x + bias)) < 0.1
        xk, yk = x[keep], y[keep]
        if xk.size < 16 or xk.var() < 1e-4:
            break  # (nearly) blank paper: only a brightness shift to find
        gain = float(((xk - xk.mean()) * (yk - yk.mean())).mean() / xk.var())
        bias = float(yk.mean() - gain * xk.mean())
    return gain, bias


def fit_tone(image: np.ndarray, state: np.ndarray) -> np.ndarray:
    """(2, 3): per channel, the gain (row 0) and bias (row 1) mapping the state render onto the
    image (both (3, H, W)), fitted to the pixels that did not change (:func:`fit_gain_bias`).

    A blank state render (a build's first step: nothing built, only the page) has only a
    brightness shift to find, and the page is what surrounds the drawing: the shift is the
    picture's border against the render's, not most of the picture's pixels (a first part
    drawn large covers most of them; the border's median, as ``foreground_mask`` finds the
    page)."""
    if all(float(state[c].var()) < 1e-4 for c in range(3)):
        border = np.concatenate(
            [image[:, 0, :], image[:, -1, :], image[:, :, 0], image[:, :, -1]], axis=1
        )
        return np.array(
            [[1.0, float(np.median(border[c]) - np.median(state[c]))] for c in range(3)]
        ).T
    return _channel_tones(image.reshape(3, -1), state.reshape(3, -1))


def _channel_tones(image: np.ndarray, state: np.ndarray) -> np.ndarray:
    """(2, 3): per channel the gain and bias (:func:`fit_gain_bias`) mapping ``state`` onto
    ``image``, both (3, N) pixels."""
    return np.array(
        [fit_gain_bias(state[c].astype(np.float64), image[c].astype(np.float64)) for c in range(3)]
    ).T


def change_map(
    image: np.ndarray,
    state: np.ndarray,
    tone: np.ndarray | None = None,
    shades: tuple[np.ndarray, dict[int, np.ndarray]] | None = None,
) -> np.ndarray:
    """Where the manual image differs from the rendered base shape, (H, W) in [0, 1]: per
    channel, the state render is first mapped onto the image by its tone fit (``tone``, else
    :func:`fit_tone`), so a manual printed in other colours or brightness still compares; then
    the largest absolute residual over the channels. ``shades``: the state render's shade
    classes (:func:`shade_classes`) and a tone per class (:func:`shade_tones`), used instead
    of ``tone`` on the pixels of those classes (a renderer that lights faces its own way)."""
    out = np.abs(image - expected_colours(image, state, tone, shades)).max(axis=0)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def expected_colours(
    image: np.ndarray,
    state: np.ndarray,
    tone: np.ndarray | None = None,
    shades: tuple[np.ndarray, dict[int, np.ndarray]] | None = None,
) -> np.ndarray:
    """The state render (3, H, W) mapped onto the manual ``image``'s tones as
    :func:`change_map` compares them: per channel the tone fit's gain and bias (``tone``, else
    :func:`fit_tone`), a shade class's own (``shades``) on that class's pixels."""
    if tone is None:
        tone = fit_tone(image, state)
    # per pixel and channel the gain and bias: the tone's, or its shade class's
    gain = np.broadcast_to(tone[0][:, None, None], state.shape).astype(state.dtype)
    bias = np.broadcast_to(tone[1][:, None, None], state.shape).astype(state.dtype)
    if shades is not None:
        classes, tones = shades
        for k, t in tones.items():
            sel = classes == k
            gain[:, sel] = t[0][:, None]
            bias[:, sel] = t[1][:, None]
    return gain * state + bias


#: A pixel drawn darker than expected by a factor in this range, hue kept (:func:`shadowed`),
#: may be in a cast shadow.
SHADOW_FACTORS = (0.4, 0.85)
#: ... the darkened colour within this much (largest channel, in [0, 1]) of the picture's.
SHADOW_FIT = 0.06


def shadowed(
    image: np.ndarray, expected: np.ndarray, factors: tuple[float, float] = SHADOW_FACTORS
) -> np.ndarray:
    """(H, W) bool: where ``image`` ((3, H, W) in [0, 1]) shows the ``expected`` colour
    ((3, H, W), or (3, 1, 1): one colour) darkened by a factor in ``factors``, as a cast shadow
    darkens a face: the least-squares factor within the range and the darkened colour within
    :data:`SHADOW_FIT` of the picture in every channel."""
    f = darkening(image, expected, axis=0)
    fit = np.abs(image - f[None] * expected).max(axis=0) < SHADOW_FIT
    return fit & (f >= factors[0]) & (f <= factors[1])


def darkening(image: np.ndarray, expected: np.ndarray, axis: int) -> np.ndarray:
    """Per pixel the factor that, applied to the ``expected`` colour, comes closest to
    ``image``'s (least squares over the colour channels, along ``axis``)."""
    return (image * expected).sum(axis=axis) / np.maximum(
        (expected * expected).sum(axis=axis), 1e-6
    )


#: Brightness levels the shade classes of :func:`shade_classes` are told apart at.
SHADE_LEVELS = 20
#: A shade class gets its own tone (:func:`shade_tones`) from at least this many pixels.
SHADE_MIN_PX = 100


def shade_classes(asm: _bg.Assembly, camera: dict[str, Any], size: int) -> np.ndarray:
    """Per pixel of ``asm`` drawn with ``camera``, how mepnet's renderer lights it: the shape
    drawn all white, its brightness in :data:`SHADE_LEVELS` levels (faces facing one way share a
    level; outlines the darkest); -1 on the page. (size, size) int."""
    out = np.full((size, size), -1, np.int32)
    if len(asm) == 0:
        return out
    white = _bg.Assembly()
    for _, comp, yaw, t in asm.instances():
        white.add(comp, yaw, t, 15)
    r = _bg.render(white, make_camera(camera), size, size)
    level = np.rint(r.rgb.mean(axis=2) / 255.0 * SHADE_LEVELS).astype(np.int32)
    return np.where(r.ids >= 0, level, out)


def shade_tones(image: np.ndarray, state: np.ndarray, classes: np.ndarray) -> dict[int, np.ndarray]:
    """Per shade class (:func:`shade_classes`) of at least :data:`SHADE_MIN_PX` pixels, the tone
    ((2, 3) gain and bias per channel, :func:`fit_gain_bias`) mapping the state render onto
    ``image`` (both (3, H, W)): fitted on a picture that shows exactly the shape rendered (the
    previous step's, which shows the base of this one), so no new part pulls it; another
    renderer lights faces its own way (LeoCAD draws the faces mepnet shades at 0.62 at 1.0)."""
    out = {}
    for k in np.unique(classes[classes >= 0]):
        sel = classes == k
        if sel.sum() < SHADE_MIN_PX:
            continue
        out[int(k)] = _channel_tones(image[:, sel], state[:, sel])
    return out


#: The range of a shade class's factor (:func:`shade_factors`): another renderer's lighting of a
#: face, not the freedom to turn one colour into another.
SHADE_FACTOR_RANGE = (0.55, 1.8)
#: A shade class whose pixels (gain times colour, per channel) square to less than this on
#: average is too dark to show a factor (:func:`shade_factors`).
SHADE_FACTOR_MIN_SQUARE = 0.003


def shade_factors(
    image: np.ndarray, state: np.ndarray, classes: np.ndarray, tone: np.ndarray
) -> np.ndarray:
    """Per shade level (:func:`shade_classes`, ``SHADE_LEVELS + 1`` entries) the factor by which
    the picture ``image`` (3, H, W) draws faces of that level brighter or darker than mepnet's
    ``state`` render (3, H, W) once the page's ``tone`` ((2, 3): gain, bias) is applied:
    ``image ~ gain * factor * state + bias``; one number per level for every colour (where
    :func:`shade_tones` fits a gain and bias per channel to the few colours the base has, which
    says nothing of a new part's colour). Robust least squares over the level's pixels and
    channels (refitted twice on those within 0.1); 1 for levels of fewer than
    :data:`SHADE_MIN_PX` pixels or too dark to tell (:data:`SHADE_FACTOR_MIN_SQUARE`)."""
    out = np.ones(SHADE_LEVELS + 1)
    gain, bias = tone[0][:, None], tone[1][:, None]
    for k in np.unique(classes[classes >= 0]):
        sel = classes == k
        if sel.sum() < SHADE_MIN_PX or not 0 <= k <= SHADE_LEVELS:
            continue
        x = (gain * state[:, sel]).ravel().astype(np.float64)
        y = (image[:, sel] - bias).ravel().astype(np.float64)
        if float((x * x).mean()) < SHADE_FACTOR_MIN_SQUARE:
            continue
        f = 1.0
        keep = np.ones(x.size, bool)
        for _ in range(3):
            xk, yk = x[keep], y[keep]
            if xk.size < SHADE_MIN_PX:
                break
            f = float(np.clip((xk * yk).sum() / max((xk * xk).sum(), 1e-9), *SHADE_FACTOR_RANGE))
            keep = np.abs(y - f * x) < 0.1
        out[int(k)] = f
    return out


#: Largest difference (degrees) of elevation, azimuth or roll for which two cameras count as
#: one view (:func:`same_view`): estimated cameras wobble by hundredths of a degree.
SAME_VIEW_DEG = 0.25


def same_view(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Whether two step cameras look from the same direction (they may zoom and pan): then,
    the projection being orthographic, one picture maps onto the other by a scale and a shift."""

    def off(x: float, y: float) -> float:
        return abs((x - y + 180.0) % 360.0 - 180.0)

    return all(
        off(float(a[k]), float(b[k])) <= SAME_VIEW_DEG for k in ("elevation", "azimuth", "roll")
    )


def warp_previous(
    picture: np.ndarray, camera: dict[str, Any], to_camera: dict[str, Any], size: int
) -> np.ndarray | None:
    """The previous step's ``picture`` ((3, H, W) floats in [0, 1]), drawn with ``camera``,
    seen with ``to_camera`` at ``size`` px: the base shape drawn by the manual's own renderer,
    in its own style, where the step's picture shows it (bilinear; what the previous picture did
    not show is filled with its page colour, the median of its border). None when the two
    cameras do not share a view (:func:`same_view`): the model was turned between the steps."""
    if not same_view(camera, to_camera):
        return None
    _, h, w = picture.shape
    k = float(camera["scale"]) / float(to_camera["scale"])
    (t1x, t1y), (t2x, t2y) = camera["translation"], to_camera["translation"]
    # NDC of the output pixel centres -> NDC in the previous picture -> its pixel coordinates
    n = (np.arange(size) + 0.5) / size * 2 - 1
    x = ((k * (n - t2x) + t1x) + 1) / 2 * w - 0.5
    y = (1 - (k * (-n - t2y) + t1y)) / 2 * h - 0.5  # rows: NDC y = 1 - 2 (row + 0.5) / size
    border = np.concatenate(
        [picture[:, 0], picture[:, -1], picture[:, :, 0], picture[:, :, -1]], axis=1
    )
    page = np.median(border, axis=1).astype(np.float32)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx = (x - x0).astype(np.float32)[None, :]
    fy = (y - y0).astype(np.float32)[:, None]
    out = np.empty((3, size, size), np.float32)
    for c in range(3):
        padded = np.pad(picture[c].astype(np.float32), 1, constant_values=page[c])
        xi = np.clip(x0 + 1, 0, w + 1)  # indices into the padded picture
        yi = np.clip(y0 + 1, 0, h + 1)
        xj = np.clip(x0 + 2, 0, w + 1)
        yj = np.clip(y0 + 2, 0, h + 1)
        a = padded[yi[:, None], xi[None, :]]
        b = padded[yi[:, None], xj[None, :]]
        cc = padded[yj[:, None], xi[None, :]]
        d = padded[yj[:, None], xj[None, :]]
        out[c] = (a * (1 - fx) + b * fx) * (1 - fy) + (cc * (1 - fx) + d * fx) * fy
        # far outside the previous picture: its page
        outside = (y[:, None] < -1) | (y[:, None] > h) | (x[None, :] < -1) | (x[None, :] > w)
        out[c][outside] = page[c]
    return out


#: How far (pixels) :func:`previous_change` looks for the previous picture's colour: that
#: picture, zoomed and panned onto this step's view by bilinear resampling, draws its lines and
#: anti-aliased edges up to a pixel away and blurred (0: compared pixel for pixel).
PREVIOUS_REACH = 1
#: ... where the step's picture differs by more than this (largest channel) within that reach.
PREVIOUS_EDGE = 0.15
#: ... and not at a pixel next to one that differs from every colour within reach: a new
#: part's own outline (off: the reach there too, which costs right steps their confidence).
PREVIOUS_KEEP_EDGE = True


def grown_4(mask: np.ndarray) -> np.ndarray:
    """``mask`` (H, W) bool grown by one pixel to its 4-neighbours."""
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    return out


def previous_change(
    image: np.ndarray, previous: np.ndarray, reach: int | None = None
) -> np.ndarray:
    """Where the step's ``image`` differs from the previous picture seen with its camera
    (:func:`warp_previous`; both (3, H, W) in [0, 1]), (H, W): the largest absolute channel
    difference, after a tone fit as :func:`change_map` (a manual's renderer is consistent
    within the manual, so this is usually the identity), from the closest of the previous
    picture's pixels within ``reach`` (default :data:`PREVIOUS_REACH`) of it: a new part
    changes its whole area, a resampled line only where it lies."""
    reach = PREVIOUS_REACH if reach is None else reach
    expected = expected_colours(image, previous)
    out = np.abs(image - expected).max(axis=0)
    if reach > 0:
        h, w = out.shape
        pad = np.pad(expected, ((0, 0), (reach, reach), (reach, reach)), mode="edge")
        own = np.pad(image, ((0, 0), (reach, reach), (reach, reach)), mode="edge")
        near = out.copy()
        contrast = np.zeros_like(out)
        for dy in range(-reach, reach + 1):
            for dx in range(-reach, reach + 1):
                if dy or dx:
                    rows, cols = (
                        slice(reach + dy, reach + dy + h),
                        slice(reach + dx, reach + dx + w),
                    )
                    np.minimum(near, np.abs(image - pad[:, rows, cols]).max(axis=0), out=near)
                    np.maximum(
                        contrast, np.abs(image - own[:, rows, cols]).max(axis=0), out=contrast
                    )
        # only where the step's picture itself has an edge or a line: inside a flat face the
        # resampling is exact, and a new part's face beside an old edge stays changed; and not
        # next to what changed even so: a new part's own outline is no resampled line
        moved = contrast > PREVIOUS_EDGE
        if PREVIOUS_KEEP_EDGE:
            moved &= ~grown_4(near > CHANGE_THRESHOLD)
        out = np.where(moved, near, out)
    return np.clip(out, 0.0, 1.0).astype(np.float32)
