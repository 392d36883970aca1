"""Cameras estimated from the pictures (DESIGN §4): a manual in the wild never states its camera,
so mepnet fits each step's weak-perspective camera to the step's picture from what it knows.

The fine fit is brickgeom's (:func:`mepnet._brickgeom.fit_camera`): a known shape is rendered
with the current camera, and the camera moves until the picture shows the rendered colours where
each rendered surface point projects (robust Gauss-Newton over blurred copies, coarse to fine;
pixels that something new hides drop out as outliers). What shape, which picture and where to
start is decided here, per build, step after step (:class:`BuildCameras`):

- **A later step** (a base shape exists). The previous picture shows exactly the base (the
  shape after the previous step), so the previous step's camera is first fitted again to the
  base there, all six parameters (the *anchor*). Its orientation is carried to this step, where
  only zoom and pan change: scale and translation start from a sweep (the base's coarse
  silhouette at a range of scales, each placed by FFT cross-correlation with this picture's
  foreground so that it lies inside it) and are fitted to the base in this picture, the new
  parts hiding some of it. If the base does not fit (the manual turned the model round), the
  three quarter turns of the azimuth are tried the same way. Without a usable previous camera
  the orientation is searched over the whole view sphere (coarse silhouettes, then fits).
- **The first step** (nothing built yet): no picture can fix the world frame (any quarter turn
  and lattice shift of the whole build looks the same), so it is fixed by convention: the
  azimuth lies in the canonical quarter [180, 270). A step adding one component: the orientation
  is searched and fitted with that component standing at the origin. Several: each component
  in turn (the largest first, at most :data:`FIRST_PARTS`) is searched for inside the drawing
  and its fits are hypotheses, best first, and the prior view (elevation 27.5, azimuth 225)
  framed to the foreground is the last; the plan loop predicts the step with each in turn until
  one explains the picture (a round part fits many views equally: the next component decides),
  fitting the camera to the predicted shape and predicting again each time.
- **Failure.** A blank picture, or a best fit that explains the picture badly (the known shape's
  silhouette off the drawing, or its colours not where the camera puts them): the step gets
  :attr:`CameraEstimate.failure` and the plan loop fails its components with that reason.

Estimation reads the page only (pictures, callouts) and the shapes the plan loop hands it
(the base: the predicted shape, or the true one under teacher forcing); never a camera, pose or
instance map from the answers.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.frames import IDENTITY, Motion, candidate_motions, matches, placement_key, symmetries
from mepnet.geom import LDU_PER_CELL, bounds_corners
from mepnet.manual import ComponentRef, Step
from mepnet.threads import one_thread

__all__ = [
    "CameraEstimate",
    "BuildCameras",
    "camera_dict",
    "drop_cameras",
]

#: A first step of several components: the components searched for inside the drawing, each
#: one's fits a camera hypothesis (the largest first).
FIRST_PARTS = 3
#: The first step's convention: elevation, and the canonical quarter of azimuths [180, 270).
FIRST_ELEVATION = 27.5
FIRST_AZIMUTH = 225.0
#: The views instruction tools use (front-left / front-right three-quarter): preferred among
#: orientations that fit equally well (a symmetric shape).
FRONT_AZIMUTHS = (315.0, 45.0)
#: Foreground: page-colour distance (0..255) and the smallest kept speck (pixels).
FG_THRESHOLD = 20.0
FG_MIN_AREA = 16
#: A picture with less drawing than this share of its pixels is blank.
MIN_DRAWING = 0.001
#: Side of the reduced foreground the scale sweep and the orientation search work at (pixels).
WORK_PX = 64
#: Elevations and azimuths of the orientation search (degrees).
SEARCH_ELEVATIONS = (12.5, 17.5, 22.5, 27.5, 32.5, 37.5, 42.5)
SEARCH_AZIMUTHS = tuple(float(a) for a in range(0, 360, 10))
#: Edge orientation: histogram bins over 180 degrees, the elevations searched, grid step.
EDGE_BINS = 360
EDGE_ELEVATIONS = (5.0, 60.0)
EDGE_STEP = 0.25
#: Edges within this many degrees of vertical are left out of :func:`edge_orientation`.
EDGE_VERTICAL_DEG = 4.0
#: Two orientations closer than this (degrees of elevation, or of azimuth modulo a quarter
#: turn) are the same as far as edges can tell.
ORIENTATION_TOL = 1.5
#: Fit levels (box-blur radii, coarse to fine) from a rough start and from a close one.
LEVELS_ROUGH = (4, 1, 0)
LEVELS_CLOSE = (1, 0)
#: Fit levels from a sweep's start, and of the check after prediction.
LEVELS_INSIDE = (4, 1, 0)
LEVELS_CHECK = (1, 0)
#: A fit from a sweep's start renders the shape again before a level only when the camera
#: moved this much (pixels) since the last render (the last level always renders).
INSIDE_RERENDER_PX = 1.5
#: A fit to a picture that shows exactly the shape is good when this share of the shape's
#: pixels agree in colour and the silhouettes overlap this much.
FULL_AGREE, FULL_IOU = 0.6, 0.5
#: A fit to a picture that shows the shape with new parts on it is good when this share of
#: the shape's silhouette lies on the drawing and this share of its pixels agree.
PART_INSIDE, PART_AGREE = 0.93, 0.45
#: The last picture with a camera, found again in this one, carries its camera over when this
#: share of it lies on the drawing in the same colours.
REGISTER_AGREE = 0.15
#: Below this agreement a fit is no hypothesis at all (a base mostly hidden still shows this).
MIN_AGREE = 0.15
#: A fit of the base this good leaves no doubt (no other hypotheses are tried).
CONFIDENT_INSIDE, CONFIDENT_AGREE = 0.97, 0.8
#: A base of at most this many components may say little about the view: its orientation is
#: checked against the picture's edges.
SMALL_BASE = 2
#: Fits whose scores differ by less than this are ties (broken by the front-view prior).
TIE = 0.05
#: Wholes (base and the step's placed components) fitted when the base alone is unsure.
JOINT_STARTS = 3
#: Placements (and orientations) ranked by coarse silhouettes whose renders are then matched
#: with the picture's colours, for the :data:`JOINT_STARTS` fitted.
JOINT_RANKED = 24
#: Placements the boxes pre-select for the joint search's rendered silhouettes, in units of
#: :data:`JOINT_RANKED`.
JOINT_BOXES = 8
#: Azimuths (degrees from the anchor's) the joint search also looks from over a small base.
JOINT_AZIMUTH_OFFSETS = (-40.0, -30.0, -20.0, -10.0, 10.0, 20.0, 30.0, 40.0)
#: The joint search covers steps adding at most this many component instances; with two, the
#: second component's best placements kept for each of the first's.
JOINT_PARTS, JOINT_PAIR_SECOND = 2, 2
#: A joint fit whose colours agree this well is offered before the base's own fits; rougher
#: ones after them.
JOINT_STRONG = 0.85
#: Pixels of the known shape (and of the page around it) a fit samples at most.
FIT_SAMPLES = 3000
#: A check that overlaps the drawing this well tells the manual's style (:class:`PageStyle`) by
#: its colour agreement; the last this many such checks count.
STYLE_IOU, STYLE_RECENT = 0.95, 8
#: Take the outer half of wide outlines off the drawing before fitting (:func:`outline_stripped`).
STRIP_OUTLINES = True
#: The fit's template outlines, as a share of the renderer's own (0: faces only).
FIT_LINES = 1.0
#: Gauss-Newton iterations per fit level.
FIT_ITERATIONS = 5
#: Scale sweep: weight of a pixel's squared colour difference against +1 for lying on the
#: drawing (a brown brick is not where the picture is blue, however well it fits inside).
SWEEP_COLOUR = 4.0
#: Scale sweep by colour kernel: each reference pixel scores SWEEP_MATCH times its colour's
#: likeness to the picture's there (Gaussian, SWEEP_SIGMA), less SWEEP_ON on the drawing and 2 off
#: it: a pixel hidden by a new part costs a little, not its squared colour difference.
SWEEP_KERNEL = True
SWEEP_MATCH, SWEEP_ON, SWEEP_SIGMA = 2.0, 0.25, 0.2
#: Scale sweep: the zoom a step usually changes by (ratio to the previous scale): the best
#: start within it is tried first.
SWEEP_PRIOR = (0.55, 1.8)
#: Scale sweep: ratios to the previous scale (coarse), then finer around the best.
SWEEP_RATIOS = tuple(float(r) for r in np.geomspace(0.25, 4.0, 13))


def camera_dict(cam: _bg.Camera) -> dict[str, Any]:
    """A camera as a manual step writes it (keys of :data:`mepnet.manual.page.CAMERA_KEYS`)."""
    return {
        "elevation": float(cam.elevation),
        "azimuth": float(cam.azimuth),
        "roll": float(cam.roll),
        "scale": float(cam.scale),
        "translation": [float(v) for v in cam.translation],
    }


@dataclass(frozen=True)
class CameraEstimate:
    """The camera a step was predicted with and where it came from."""

    #: None when it could not be estimated.
    camera: _bg.Camera | None
    #: ``"given"`` (the manual states it) or ``"estimated"``.
    source: str
    #: How well the camera explains the picture: the share of the known shape's pixels whose
    #: colour the picture shows where the camera puts them (None for a given camera, and for a
    #: first step's prior view until the plan loop fitted it to the predicted step).
    fit: float | None = None
    #: How it was found: ``given``, ``first step``, ``carried`` (the previous orientation),
    #: ``turned`` (a quarter turn of it), ``joint`` (with the placement of the step's one
    #: component), ``searched`` (the whole view sphere), ``registered`` (the last picture with a
    #: camera found again in this one: the shape built so far does not fit); ``(weak)`` added
    #: when the known shape hardly agrees with the picture (hidden by new parts).
    how: str = "given"
    #: Why there is no camera (the step's components fail with this reason).
    failure: str | None = None
    #: Wall time of the estimation (seconds), refits after prediction included.
    seconds: float = 0.0
    #: ``"convention"`` when fixed by the first step's convention (the base was empty), else
    #: ``"base"`` (in the frame of the shape it was fitted to).
    frame: str = "base"

    @classmethod
    def given(cls, step: Step) -> CameraEstimate:
        """The camera the page states."""
        return cls(step.camera_object(), "given")

    def step_camera(self) -> dict[str, Any]:
        """The camera as a page step's ``camera`` dict (for a copy of the step)."""
        assert self.camera is not None
        return camera_dict(self.camera)

    def to_json(self) -> dict[str, Any]:
        """``camera``, ``camera_source``, ``camera_fit`` (and ``camera_failure``) for plan.json."""
        out: dict[str, Any] = {
            "camera": None if self.camera is None else camera_dict(self.camera),
            "camera_source": self.source,
            "camera_fit": None if self.fit is None else round(float(self.fit), 4),
        }
        if self.source == "estimated":
            out["camera_how"] = self.how
        if self.failure is not None:
            out["camera_failure"] = self.failure
        return out


def drop_cameras(manual: Any) -> Any:
    """A copy of a manual whose steps state no camera (the answers are kept for scoring)."""

    def build(b: Any) -> Any:
        return dataclasses.replace(b, steps=[dataclasses.replace(s, camera=None) for s in b.steps])

    return dataclasses.replace(
        manual, main=build(manual.main), submodules=[build(b) for b in manual.submodules]
    )


@dataclass
class _Picture:
    """A step picture as the estimator uses it."""

    rgb: np.ndarray  # (H, W, 3) uint8
    fg: np.ndarray  # (H, W) bool: the drawing
    small: np.ndarray  # (h, w) float32: the drawing reduced to WORK_PX a side (coverage)
    small_rgb: np.ndarray  # (h, w, 3) float32 in [0, 1]: the picture reduced alike
    fit: _bg.FitPicture  # the picture as the fit samples it (blurred copies kept)
    _edges: tuple[float, float] | None = None
    _box: tuple[np.ndarray, tuple[float, float, float, float] | None] | None = None
    _spectra: tuple[np.ndarray, np.ndarray] | None = None
    _kernel: tuple[bytes, np.ndarray, np.ndarray] | None = None
    _pad: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def blank(self) -> bool:
        return float(self.fg.mean()) < MIN_DRAWING

    def drawing_box(self) -> tuple[np.ndarray, tuple[float, float, float, float] | None]:
        """The reduced drawing (bool) and its box in NDC (:func:`_ndc_box`; None if empty)."""
        if self._box is None:
            fg = self.small > 0.5
            self._box = (fg, _ndc_box(fg) if fg.any() else None)
        return self._box

    def _padded(self) -> tuple[np.ndarray, np.ndarray]:
        """The reduced drawing and colours at twice the size, beyond the picture page (its
        median colour off the drawing; made once, both sweeps' spectra start from it)."""
        if self._pad is not None:
            return self._pad
        h, w = self.small.shape
        off = self.small < 0.5
        page = np.median(self.small_rgb[off], axis=0) if off.any() else np.ones(3)
        colours = np.empty((2 * h, 2 * w, 3), dtype=np.float32)
        colours[...] = page
        colours[:h, :w] = self.small_rgb
        drawing = np.zeros((2 * h, 2 * w), dtype=np.float32)
        drawing[:h, :w] = self.small
        self._pad = (drawing, colours)
        return self._pad

    def sweep_spectra(self) -> tuple[np.ndarray, np.ndarray]:
        """The scale sweep's view of the reduced picture (:meth:`BuildCameras._match`), as
        spectra at twice its size: the weight per pixel of the reference (+1 on the drawing,
        -2 off it, less :data:`SWEEP_COLOUR` times its squared colour), and the three colour
        channels (3, ...). Beyond the picture is page (its median colour off the drawing): a
        reference placed partly or wholly outside scores there as off the drawing, not as on a
        black page that costs nothing (which drew dark parts out of the picture)."""
        if self._spectra is None:
            drawing, colours = self._padded()
            weight = drawing - 2.0 * (1.0 - drawing) - SWEEP_COLOUR * (colours**2).sum(axis=2)
            planes = np.concatenate([weight[None], colours.transpose(2, 0, 1)])
            spectra = _rfft2(planes)
            self._spectra = (spectra[0], spectra[1:])
        return self._spectra

    def kernel_spectra(self, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The kernel sweep's view of the reduced picture: the weight per pixel (-:data:`SWEEP_ON`
        on the drawing, -2 off it) and the picture's colour features (:func:`_colour_features`
        for ``centres``), as spectra at twice its size, beyond the picture page."""
        key = centres.tobytes()
        if self._kernel is None or self._kernel[0] != key:
            drawing, colours = self._padded()
            weight = -SWEEP_ON * drawing - 2.0 * (1.0 - drawing)
            feats = _colour_features(colours, centres)
            spectra = _rfft2(np.concatenate([weight[None], feats.transpose(2, 0, 1)]))
            self._kernel = (key, spectra[0], spectra[1:])
        return self._kernel[1], self._kernel[2]

    def edge_view(self) -> tuple[float, float]:
        """The orientation its edges suggest: (elevation, azimuth in [180, 270))."""
        if self._edges is None:
            self._edges = edge_orientation(self.rgb)
        return self._edges


def _rfft2(planes: np.ndarray) -> np.ndarray:
    """The 2D real FFTs of ``planes`` (..., H, W) float32, batched (torch's: several times
    numpy's speed on the sweep's many small planes), complex64."""
    import torch

    with one_thread():
        x = torch.from_numpy(np.ascontiguousarray(planes, np.float32))
        return torch.fft.rfft2(x).numpy()


def _correlations(
    planes: np.ndarray, f_weight: np.ndarray, f_colour: np.ndarray, gain: float
) -> np.ndarray:
    """The sweep's scores at every offset, per scale: ``planes`` (S, 1 + K, h, w) the
    reference's silhouette and K values at each of S scales; ``f_weight`` (2h, w + 1) and
    ``f_colour`` (K, 2h, w + 1) the picture's spectra at twice its size (:func:`_rfft2`).
    Returns (S, 2h, 2w) float32: the weight's correlation with the silhouette plus ``gain``
    times the colours' with the values."""
    import torch

    two_h = f_weight.shape[0]
    size = (two_h, 2 * (f_weight.shape[1] - 1))
    with one_thread():
        ref = torch.fft.rfft2(torch.from_numpy(np.ascontiguousarray(planes, np.float32)), s=size)
        spec = torch.from_numpy(f_weight) * ref[:, 0].conj()
        f_c = torch.from_numpy(np.ascontiguousarray(f_colour))
        spec += gain * (f_c * ref[:, 1:].conj()).sum(1)
        return torch.fft.irfft2(spec, s=size).numpy()


def _colour_centres(colours: np.ndarray, k: int = 6, iterations: int = 6) -> np.ndarray:
    """Up to ``k`` colours that stand for ``colours`` (N, 3) in [0, 1] (k-means from spread
    starts)."""
    if len(colours) == 0:
        return np.ones((1, 3), dtype=np.float32)
    pts = colours[:: max(1, len(colours) // 1000)].astype(np.float32)
    lum = pts.sum(axis=1)
    centres = pts[np.argsort(lum)[np.linspace(0, len(pts) - 1, k).astype(int)]]
    for _ in range(iterations):
        near = (pts @ centres.T * -2.0 + (centres**2).sum(axis=1)).argmin(axis=1)
        counts = np.bincount(near, minlength=k)[:, None]
        sums = np.stack([np.bincount(near, pts[:, c], minlength=k) for c in range(3)], axis=1)
        centres = np.where(counts > 0, sums / np.maximum(counts, 1), centres).astype(np.float32)
    keep = [0]
    for j in range(1, k):
        if all(np.abs(centres[j] - centres[i]).max() > 0.04 for i in keep):
            keep.append(j)
    return centres[keep].astype(np.float32)


def _colour_features(colours: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Soft membership (..., K) of each colour (..., 3) in each centre's colour."""
    c = np.asarray(colours, dtype=np.float32)
    d2 = (c**2).sum(axis=-1)[..., None] - 2.0 * (c @ centres.T) + (centres**2).sum(axis=1)
    return np.exp(np.minimum(d2, 50.0) * np.float32(-0.5 / SWEEP_SIGMA**2)).astype(np.float32)


def _rings(fg: np.ndarray, n: int) -> list[np.ndarray]:
    """The drawing's outermost ``n`` rings of pixels (4-neighbour erosion), outside first."""
    rings, m = [], fg
    for _ in range(n):
        e = m.copy()
        e[1:] &= m[:-1]
        e[:-1] &= m[1:]
        e[:, 1:] &= m[:, :-1]
        e[:, :-1] &= m[:, 1:]
        rings.append(m & ~e)
        m = e
    return rings


def outline_stripped(rgb: np.ndarray, fg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The picture with the outer half of a wide outline taken off its silhouette.

    Some tools draw outlines wider than a pixel centred on the parts' edges: the drawing's
    silhouette then grows by half the line, and a camera fitted to it by as much (the fit's
    template draws its lines inside the parts, as mepnet's renderer does). Recognised by its
    rings: past an anti-aliased halo, an outermost ring of one dark colour (ink on the page),
    followed by rings darker than the drawing's inside (ink over the parts); the band is the
    first ring and the darker ones, and its outer half (with the halo) becomes page. A one-
    pixel outline (mepnet's, LeoCAD's) is left alone."""
    rings = [r for r in _rings(fg, 8) if r.sum() >= 16]
    if len(rings) < 6:
        return rgb, fg  # too thin to tell a band from the parts
    page = _median_u8(rgb[~fg]) if (~fg).any() else np.full(3, 255.0)
    lum_page = float(page.mean())
    if lum_page <= 0.0:
        return rgb, fg  # a black page: no ink to tell from it
    med = [_median_u8(rgb[r]) for r in rings]
    lum = [float(m.mean()) / lum_page for m in med]
    start = 1 if lum[0] > 0.6 else 0  # a halo: pixels the page mostly covers
    ring = rgb[rings[start]].astype(np.float32)  # only the ring: not the whole picture
    spread = float(np.median(np.abs(ring - med[start]).max(axis=1))) / lum_page
    if spread > 0.06 or lum[start] > 0.5:
        return rgb, fg  # no outline of one colour around the drawing
    inside = float(np.median(lum[start + 4 :] or lum[-1:]))
    width = 1
    while width < min(4, len(rings) - start - 1) and lum[start + width] < 0.8 * inside:
        width += 1
    strip = width // 2
    if strip == 0:
        return rgb, fg
    gone = np.zeros_like(fg)
    for r in rings[: start + strip]:
        gone |= r
    out = rgb.copy()
    out[gone] = np.clip(np.round(page), 0, 255).astype(rgb.dtype)
    return np.ascontiguousarray(out), fg & ~gone


def _edge_grid() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Elevations, azimuths (the canonical quarter) and, per pair, the histogram bins of the
    directions the lattice's x and z axes take in the picture (roll 0)."""
    els = np.arange(EDGE_ELEVATIONS[0], EDGE_ELEVATIONS[1] + 1e-9, EDGE_STEP)
    azs = np.arange(180.0, 270.0, EDGE_STEP)
    e, a = np.meshgrid(np.radians(els), np.radians(azs), indexing="ij")
    # projected axes (u right, v up): x -> (cos az, -sin az sin el), z -> (-sin az, -cos az sin el)
    dir_x = np.degrees(np.arctan2(-np.sin(a) * np.sin(e), np.cos(a))) % 180.0
    dir_z = np.degrees(np.arctan2(-np.cos(a) * np.sin(e), -np.sin(a))) % 180.0
    to_bin = EDGE_BINS / 180.0
    return (
        els,
        azs,
        (dir_x * to_bin).astype(np.int64) % EDGE_BINS,
        (dir_z * to_bin).astype(np.int64) % EDGE_BINS,
    )


_EDGE_GRID: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None


def edge_orientation(rgb: np.ndarray) -> tuple[float, float]:
    """The camera orientation (elevation, azimuth in the canonical quarter [180, 270); roll 0)
    under which the lattice's x and z axes run along the picture's strongest edge directions
    (:func:`mepnet._brickgeom.edge_directions`): what the drawing's straight edges say about
    the view, whatever the parts. Right within a degree or two for most pictures of bricks;
    meaningless for round parts alone."""
    global _EDGE_GRID
    if _EDGE_GRID is None:
        _EDGE_GRID = _edge_grid()
    els, azs, bin_x, bin_z = _EDGE_GRID
    hist = np.asarray(_bg.edge_directions(rgb, EDGE_BINS), dtype=np.float64).copy()
    # vertical edges are the lattice's y axis from every view with roll 0: they say nothing
    # about the view, and counted they pull towards views with x or z drawn upright (a round
    # brick's sides made the edges of its top plate lose to them)
    v = int(EDGE_VERTICAL_DEG * EDGE_BINS / 180.0)
    hist[EDGE_BINS // 2 - v : EDGE_BINS // 2 + v + 1] = 0.0
    r = 12
    kernel = np.exp(-0.5 * (np.arange(-r, r + 1) / 3.0) ** 2)
    smooth = np.convolve(np.concatenate([hist[-r:], hist, hist[:r]]), kernel, mode="valid")
    # both axes must be drawn: one strong direction (a cylinder's horizontal tangents) alone
    # does not make a view
    score = np.sqrt(smooth[bin_x] * smooth[bin_z])
    i, j = np.unravel_index(int(np.argmax(score)), score.shape)
    return float(els[i]), float(azs[j])


def _reduce(image: np.ndarray, side: int) -> np.ndarray:
    """An image ((H, W) mask or (H, W, C)) reduced (area average) so its longer side is at
    most ``side``, as float32 (edge cells padded with the border)."""
    h, w = image.shape[:2]
    f = max(1, math.ceil(max(h, w) / side))
    hp, wp = math.ceil(h / f) * f, math.ceil(w / f) * f
    if (hp, wp) != (h, w):
        pad = [(0, hp - h), (0, wp - w)] + [(0, 0)] * (image.ndim - 2)
        image = np.pad(image, pad, mode="edge")
    # integer sums over the f x f cells, added row of cells by row (numpy's strided
    # reduction over two axes with a cast is ten times slower)
    cells = image.astype(np.int32).reshape(hp // f, f, wp // f, f, *image.shape[2:])
    rows = cells[:, 0].copy()
    for k in range(1, f):
        rows += cells[:, k]
    sums = rows[:, :, 0].copy()
    for k in range(1, f):
        sums += rows[:, :, k]
    return sums.astype(np.float32) / (f * f)


def _median_u8(values: np.ndarray) -> np.ndarray:
    """Per column of ``values`` (N, C) uint8, N >= 1: the median as ``np.median`` gives it for
    the values as float32 (the mean of the two middle ones when N is even), from a histogram."""
    n = len(values)
    out = np.empty(values.shape[1], dtype=np.float32)
    for c in range(values.shape[1]):
        cum = np.cumsum(np.bincount(values[:, c], minlength=256))
        lo = int(np.searchsorted(cum, (n - 1) // 2, side="right"))
        hi = int(np.searchsorted(cum, n // 2, side="right"))
        out[c] = (np.float32(lo) + np.float32(hi)) / np.float32(2.0)
    return out


def _distinct(fits: list[tuple[float, _bg.Camera]], n: int) -> list[tuple[float, _bg.Camera]]:
    """The best ``n`` hypotheses that differ by more than 15 degrees of azimuth or 7.5 of
    elevation from every better one."""
    out: list[tuple[float, _bg.Camera]] = []
    for score, cam in sorted(fits, key=lambda f: -f[0]):
        if _differs(cam, [c for _, c in out]):
            out.append((score, cam))
            if len(out) == n:
                break
    return out


def _differs(cam: _bg.Camera, others: list[_bg.Camera]) -> bool:
    """Whether ``cam`` differs by more than 15 degrees of azimuth or 7.5 of elevation from every
    camera of ``others``."""
    return all(
        abs(_angle(cam.azimuth - c.azimuth)) > 15 or abs(cam.elevation - c.elevation) > 7.5
        for c in others
    )


def _angle(d: float) -> float:
    """An angle difference in (-180, 180]."""
    return -((-d + 180.0) % 360.0 - 180.0)


def _front_distance(azimuth: float) -> float:
    """Degrees from the nearest front three-quarter view."""
    return min(abs(_angle(azimuth - a)) for a in FRONT_AZIMUTHS)


def _with(cam: _bg.Camera, **kw: Any) -> _bg.Camera:
    d = {
        "elevation": cam.elevation,
        "azimuth": cam.azimuth,
        "roll": cam.roll,
        "scale": cam.scale,
        "translation": tuple(cam.translation),
    }
    d.update(kw)
    return _bg.Camera(**d)


def canonical(cam: _bg.Camera) -> _bg.Camera:
    """The camera with its azimuth turned by quarter turns into [180, 270) (the world turned
    with it about the vertical axis through the origin)."""
    return _with(cam, azimuth=180.0 + float(cam.azimuth) % 90.0)


def placements(asm: _bg.Assembly) -> list[tuple[_bg.Component, int, tuple[int, int, int], int]]:
    """An assembly's placed components ``(component, yaw, t, colour)``."""
    return [(c, int(y), tuple(int(v) for v in t), asm.colour(i)) for i, c, y, t in asm.instances()]  # type: ignore[misc]


def moved_camera(cam: _bg.Camera, motion: Motion) -> _bg.Camera:
    """The camera that sees the world moved by ``motion`` as ``cam`` saw it unmoved: for every
    point p, it projects ``motion(p)`` where ``cam`` projected p."""
    back = motion.inverse()
    shift = np.asarray(back.shift, dtype=np.float64) * LDU_PER_CELL
    offset = cam.scale * (np.asarray(cam.rotation()) @ shift)[:2]
    return _with(
        cam,
        azimuth=float(cam.azimuth) - 90.0 * back.turn,
        translation=(float(cam.translation[0] + offset[0]), float(cam.translation[1] + offset[1])),
    )


def frame_motions(shape: _bg.Assembly, base: _bg.Assembly) -> list[Motion]:
    """The rigid lattice motions that map ``shape`` onto ``base`` exactly (every placed
    component; several when the base is symmetric): how the first step's convention frame sits
    in the frame of a base handed over from elsewhere (the true shape, under teacher forcing)."""
    mine, theirs = placements(shape), placements(base)
    if not mine or len(mine) != len(theirs):
        return []
    return [m for m in candidate_motions(mine, theirs) if matches(mine, theirs, m) == len(theirs)]


@dataclass
class PageStyle:
    """How far a manual's drawing style lets a right camera and shape agree with mepnet's
    drawing of them: the colour agreement of the checks that explained a step's silhouette
    (IoU >= :data:`STYLE_IOU`), so far. mepnet's own pictures agree all but fully; another
    tool's shading, lines and studs cap it (LeoCAD's: median 0.80 with the true camera and
    shape), and a threshold made for the former would call no step of the latter explained."""

    agrees: list[float] = dataclasses.field(default_factory=list)

    def explained(self, agree: float, margin: float) -> float:
        """The agreement that explains a step: ``agree``, or less in a style whose recent
        checks (:data:`STYLE_RECENT`, at least two) agreed less: their median less ``margin``."""
        if len(self.agrees) < 2:
            return agree
        return min(agree, float(np.median(self.agrees[-STYLE_RECENT:])) - margin)


class BuildCameras:
    """The camera estimator of one build, called step after step by the plan loop
    (:func:`mepnet.plan.run_build`): :meth:`hypotheses` before a step is predicted,
    :meth:`check` after (how well the camera and the predicted shape explain the picture),
    :meth:`accept` for the camera the step keeps (the next step's anchor). Keeps the pictures
    it read last (a step's picture is the next step's anchor)."""

    def __init__(self, image_size: tuple[int, int], style: PageStyle | None = None):
        # the sweep's FFTs are torch's (:func:`_rfft2`): imported here, once, so that no
        # step's estimate counts the import
        import torch  # noqa: F401

        self.image_size = image_size
        #: how well the manual's drawings can agree with mepnet's (shared by its builds)
        self.style = PageStyle() if style is None else style
        self._pictures: dict[str, _Picture] = {}
        #: the previous step, the camera it kept, whether a fit verified that camera with the
        #: shape after the step (then it is the anchor as it stands), and that shape
        self._previous: tuple[Step, CameraEstimate, bool, _bg.Assembly | None] | None = None
        #: the latest step that kept a camera, and that camera
        self._last_good: tuple[Step, _bg.Camera] | None = None

    # -- pictures ------------------------------------------------------------------------------

    def picture(self, step: Step) -> _Picture:
        """The step's picture, foreground and reduced foreground (cached: the last three)."""
        key = str(step.image_path)
        pic = self._pictures.get(key)
        if pic is None:
            rgb = np.ascontiguousarray(step.image())
            fg, _ = _bg.foreground_mask(rgb, FG_THRESHOLD, FG_MIN_AREA)
            if STRIP_OUTLINES:
                rgb, fg = outline_stripped(rgb, fg)
            pic = _Picture(
                rgb, fg, _reduce(fg, WORK_PX), _reduce(rgb, WORK_PX) / 255.0, _bg.FitPicture(rgb)
            )
            if len(self._pictures) >= 3:
                self._pictures.pop(next(iter(self._pictures)))
            self._pictures[key] = pic
        return pic

    # -- the plan loop's calls -----------------------------------------------------------------

    def hypotheses(
        self,
        step: Step,
        base: _bg.Assembly,
        components: dict[ComponentRef, _bg.Component],
        teacher_forced: bool,
    ) -> Iterator[CameraEstimate]:
        """Cameras for a step without one, most likely first, each made when it is asked for
        (the plan loop stops at the first that explains the picture); a single failed estimate
        when none fits. ``base``: the shape before the step. Each estimate's ``seconds`` are
        those spent making it (not the caller's between two)."""
        if len(base) == 0:
            return _timed(self._first(step, components))
        previous = None
        same_frame = True
        verified = False
        if self._previous is not None:
            prev_step, prev, verified, shape = self._previous
            previous = (prev_step, prev)
            if teacher_forced and prev.frame == "convention" and prev.camera is not None:
                # the base is the true shape, the first step's camera in the convention's
                # frame: carried over by the motion that maps the predicted first step onto
                # the base (when it was predicted right; else searched)
                moved = (
                    [moved_camera(prev.camera, m) for m in frame_motions(shape, base)]
                    if shape
                    else []
                )
                if not moved:
                    same_frame = False
                else:  # a symmetric base: the view instruction tools use
                    cam = min(moved, key=lambda c: _front_distance(c.azimuth))
                    prev = dataclasses.replace(prev, camera=cam)
                    previous = (prev_step, prev)
        return _timed(
            self._next(step, base, components, previous, same_frame, verified and same_frame)
        )

    def check(self, step: Step, shape: _bg.Assembly, est: CameraEstimate) -> _bg.CameraFit | None:
        """The camera fitted again (close, all six parameters) to the shape after the step (base
        and predicted components), which the step's picture shows: how well both explain it
        (``agree``, ``iou``), and the refined camera. None when nothing is placed."""
        if est.camera is None or len(shape) == 0:
            return None
        return self._fit(
            shape, self.picture(step), est.camera, LEVELS_CHECK, rerender_px=INSIDE_RERENDER_PX
        )

    def accept(
        self,
        step: Step,
        est: CameraEstimate,
        fit: _bg.CameraFit | None,
        shape: _bg.Assembly | None = None,
    ) -> None:
        """The camera the step was predicted with; ``fit``: its :meth:`check` (a good one
        becomes the next step's anchor as it stands); ``shape``: the shape after the step as
        predicted."""
        if est.source == "given":
            self._previous = (step, est, True, shape)
        elif fit is not None and _full_ok(fit):
            if fit.iou >= STYLE_IOU:
                self.style.agrees.append(fit.agree)
            kept = dataclasses.replace(est, camera=fit.camera, fit=fit.agree)
            self._previous = (step, kept, True, shape)
        else:
            self._previous = (step, est, False, shape)
        if self._previous[1].camera is not None:
            self._last_good = (step, self._previous[1].camera)

    # -- fits ----------------------------------------------------------------------------------

    def _fit(
        self,
        shape: _bg.Assembly,
        pic: _Picture,
        init: _bg.Camera,
        levels: tuple[int, ...],
        free: tuple[bool, ...] = (True,) * 6,
        rerender_px: float = 0.0,
    ) -> _bg.CameraFit:
        return _bg.fit_camera(
            shape,
            pic.fit,
            pic.fg,
            init,
            free=free,
            levels=list(levels),
            rerender_px=rerender_px,
            lines=FIT_LINES,
            iterations=FIT_ITERATIONS,
            samples=FIT_SAMPLES,
        )

    def _search_full(
        self, shape: _bg.Assembly, pic: _Picture, n: int = 3, views: list[_Picture] | None = None
    ) -> _bg.CameraFit | None:
        """The best fit of ``shape`` to a picture that shows exactly it, over the view sphere:
        the orientations the edges of ``views`` (default: the picture) suggest, each quarter
        turn, and a coarse grid, ranked by the shape's rendered silhouette framed to the
        drawing (a coarse box silhouette makes a round part a box); the best ``n - 1`` and the
        best of the edges' are fitted. Among fits that agree equally well, the one nearest a
        front three-quarter view wins."""
        edge = [
            (el, az + 90.0 * k, 0.0)
            for el, az in {v.edge_view() for v in (views or [pic])}
            for k in range(4)
        ]
        grid = [(e, a, 0.0) for e in SEARCH_ELEVATIONS for a in SEARCH_AZIMUTHS]

        def ranked(cands: list[tuple[float, float, float]]) -> list[tuple[float, _bg.Camera]]:
            return [
                _framed_silhouette(shape, _bg.Camera(e, a, r, 1.0, (0.0, 0.0)), pic)
                for e, a, r in cands
            ]

        by_edges = _distinct(ranked(edge), 1)
        starts = _distinct(ranked(grid) + by_edges, n - 1)
        starts += [s for s in by_edges if all(s[1] is not c for _, c in starts)]
        fits = [self._fit(shape, pic, cam, LEVELS_ROUGH) for _, cam in starts]
        if not fits:
            return None
        return _prefer_front([(f, "") for f in fits], lambda f: f.agree)[0][0]

    def _sweep(
        self, shape: _bg.Assembly, pic: _Picture, cam: _bg.Camera, wide: bool = True
    ) -> list[_bg.Camera]:
        """Scale and translation for ``cam``'s orientation that put the shape where the picture
        shows it (:meth:`_match` of the shape rendered once). The cameras of the three best
        distinct starts, the best within the usual zoom of ``cam``'s scale first (``wide``
        False: only scales within it)."""
        return [c for _, c in self._sweep_scored(shape, pic, cam, wide)]

    def _sweep_scored(
        self,
        shape: _bg.Assembly,
        pic: _Picture,
        cam: _bg.Camera,
        wide: bool = True,
        both: bool = False,
        kernel: bool | None = None,
    ) -> list[tuple[float, _bg.Camera]]:
        """:meth:`_sweep` with each start's :meth:`_match` score (each scoring's own);
        ``kernel``: the scoring (:data:`SWEEP_KERNEL` by default); ``both``: the colour
        kernel's starts, then the distinct ones the squared colour difference ranks best (a new
        part much like the base in colour draws the kernel's starts onto it)."""
        kernel = SWEEP_KERNEL if kernel is None else kernel
        n = 2 * WORK_PX
        ref = _with(cam, scale=1.0, translation=(0.0, 0.0)).fitted(
            np.asarray(bounds_corners(shape), dtype=np.float64), 0.9
        )
        render = _bg.render(shape, ref, n, n)
        rgb = render.rgb.astype(np.float32) / 255.0
        # the usual zoom is relative to the scale ``cam`` brings (the previous step's), not to
        # the reference's (the shape framed to fill the picture)
        prior = float(cam.scale)
        out = self._match(render.ids >= 0, rgb, ref, pic, wide=wide, kernel=kernel, prior=prior)
        if both and kernel:
            w = pic.small.shape[1]
            for sc, c in self._match(
                render.ids >= 0, rgb, ref, pic, wide=wide, kernel=False, prior=prior
            ):
                if all(_start_distance(c, o, w) > 2.0 for _, o in out):
                    out.append((sc, c))
        return out

    def _register(
        self, prev_pic: _Picture, prev_cam: _bg.Camera, pic: _Picture
    ) -> tuple[float, _bg.Camera] | None:
        """The previous picture's drawing found again in this one (zoom and pan, whatever the
        shapes built): the camera carried over, and the share of that drawing's pixels (at the
        match) that lie on this drawing in the same colour. None when nothing matches."""
        ref_rgb = prev_pic.rgb.astype(np.float32) / 255.0
        found = self._match(prev_pic.fg, ref_rgb, prev_cam, pic, starts=1)
        if not found:
            return None
        cam = found[0][1]
        sil, tpl = self._resampled(prev_pic.fg, ref_rgb, prev_cam, cam, pic.small.shape)
        # the match's offset (NDC) from the reference's centre, to pixels of the reduced picture
        tx, ty = _offset(prev_cam, cam)
        h, w = pic.small.shape
        shift = (round(-ty * h / 2.0), round(tx * w / 2.0))
        moved_sil = np.roll(sil, shift, axis=(0, 1))
        moved_tpl = np.roll(tpl, shift, axis=(0, 1))
        on = moved_sil > 0
        if not on.any():
            return None
        same = np.abs(pic.small_rgb - moved_tpl).max(axis=2) < 0.15
        agree = float((same & (pic.small > 0.5))[on].mean())
        return agree, cam

    @staticmethod
    def _resampled(
        sil_ref: np.ndarray,
        rgb_ref: np.ndarray,
        ref: _bg.Camera,
        cam: _bg.Camera,
        shape: tuple[int, int],
    ) -> tuple[np.ndarray, np.ndarray]:
        """A reference silhouette and colours (seen by camera ``ref``) at ``cam``'s scale (same
        orientation), on a grid of ``shape`` (nearest) centred where the reference's is: a
        camera that puts the reference's centre at the grid's centre has the translation
        :func:`_centred` gives, and an offset from there moves the reference by that offset."""
        h, w = shape
        ny, nx = sil_ref.shape
        k = ref.scale / cam.scale  # work NDC (from the centre) -> reference NDC
        ndc_x = (np.arange(w) + 0.5) / w * 2 - 1
        ndc_y = 1 - (np.arange(h) + 0.5) / h * 2
        cols = np.floor((k * ndc_x + 1) / 2 * nx).astype(np.int64)
        rows = np.floor((1 - k * ndc_y) / 2 * ny).astype(np.int64)
        ok = np.outer((rows >= 0) & (rows < ny), (cols >= 0) & (cols < nx))
        rows, cols = np.clip(rows, 0, ny - 1), np.clip(cols, 0, nx - 1)
        # rows, then columns (numpy's take is several times faster than an open mesh index)
        sil = (sil_ref.take(rows, axis=0).take(cols, axis=1) & ok).astype(np.float32)
        return sil, rgb_ref.take(rows, axis=0).take(cols, axis=1) * sil[..., None]

    def _match(
        self,
        sil_ref: np.ndarray,
        rgb_ref: np.ndarray,
        ref: _bg.Camera,
        pic: _Picture,
        starts: int = 3,
        wide: bool = True,
        kernel: bool | None = None,
        prior: float | None = None,
    ) -> list[tuple[float, _bg.Camera]]:
        """Scale and translation, for the orientation of ``ref``, that put a reference (a
        silhouette and its colours as camera ``ref`` sees them) where the picture shows it: the
        reference resampled at scales around ``ref.scale`` (``wide``: :data:`SWEEP_RATIOS` of
        it; else only those within :data:`SWEEP_PRIOR` of the ``prior`` scale, by default
        ``ref.scale``; coarse, then finer around the best overall and the best within
        :data:`SWEEP_PRIOR` of ``prior``),
        each placed by FFT cross-correlation with the reduced picture. ``kernel`` (default
        :data:`SWEEP_KERNEL`): every pixel of the reference scores :data:`SWEEP_MATCH` times its
        colour's likeness to the picture's there, less :data:`SWEEP_ON` on the drawing and 2 off
        it; else +1 on the drawing, -2 off it, less :data:`SWEEP_COLOUR` times its squared colour
        difference (so the reference is as large as the drawing allows, where its colours are).
        The best ``starts`` distinct placements: the best within :data:`SWEEP_PRIOR` first, then
        the best overall."""
        h, w = pic.small.shape
        pad = (2 * h, 2 * w)
        kernel = SWEEP_KERNEL if kernel is None else kernel
        if kernel:
            centres = _colour_centres(rgb_ref[sil_ref])
            f_weight, f_colour = pic.kernel_spectra(centres)
            # the reference's colour features, resampled with its silhouette at each scale
            values = _colour_features(rgb_ref, centres)
            gain = SWEEP_MATCH
        else:
            f_weight, f_colour = pic.sweep_spectra()
            values = rgb_ref
            gain = 2.0 * SWEEP_COLOUR  # the cross term of the squared difference

        def place(scales: list[float]) -> list[tuple[float, _bg.Camera]]:
            # per pixel of the reference at offset tau: W(x+tau) + MATCH sum_k F_k(P(x+tau)) F_k(T(x))
            # (kernel), or W(x+tau) - COLOUR sum_c (P_c(x+tau) - T_c(x))^2; every scale's
            # planes transformed together
            placed = []
            for scale in scales:
                c = _with(ref, scale=scale, translation=(0.0, 0.0))
                sil, tpl = self._resampled(sil_ref, values, ref, c, (h, w))
                if sil.any():
                    placed.append((c, np.concatenate([sil[None], tpl.transpose(2, 0, 1)])))
            if not placed:
                return []
            corrs = _correlations(
                np.stack([planes for _, planes in placed]), f_weight, f_colour, gain
            )
            out = []
            for (c, planes), corr in zip(placed, corrs, strict=True):
                if not kernel:  # the squared difference's template term
                    corr -= SWEEP_COLOUR * float((planes[1:] ** 2).sum())
                cx, cy = _centred(ref, c.scale)
                for _ in range(2):  # the two best offsets, apart
                    dy, dx = np.unravel_index(int(np.argmax(corr)), corr.shape)
                    score = float(corr[dy, dx])
                    corr[max(dy - 3, 0) : dy + 4, max(dx - 3, 0) : dx + 4] = -np.inf
                    dy = dy - pad[0] if dy >= h else dy
                    dx = dx - pad[1] if dx >= w else dx
                    out.append(
                        (score, _with(c, translation=(cx + 2.0 * dx / w, cy - 2.0 * dy / h)))
                    )
            return out

        usual = float(ref.scale) if prior is None else prior

        def near_ratio(r: float) -> bool:
            return SWEEP_PRIOR[0] <= r <= SWEEP_PRIOR[1]

        if wide:
            coarse = place([ref.scale * r for r in SWEEP_RATIOS])
        else:
            coarse = place([usual * r for r in SWEEP_RATIOS if near_ratio(r)])
        if not coarse:
            return []
        step = SWEEP_RATIOS[1] / SWEEP_RATIOS[0]

        def near(c: _bg.Camera) -> bool:  # within the zoom a step usually changes by
            return near_ratio(c.scale / usual)

        # refined around the best overall and the best within the usual zoom (a base mostly
        # hidden by new parts of other colours scores best shrunk into one of its own faces)
        fine = list(coarse)
        pools = (coarse, [x for x in coarse if near(x[1])])
        bests = dict.fromkeys(max(p, key=lambda s: s[0])[1].scale for p in pools if p)
        fine += place([b * step**k for b in bests for k in (-2 / 3, -1 / 3, 1 / 3, 2 / 3)])
        fine.sort(key=lambda s: -s[0])
        out: list[tuple[float, _bg.Camera]] = []
        for group in ([x for x in fine if near(x[1])][:1], fine):
            for score, c in group:
                if len(out) < starts and all(_start_distance(c, o, w) > 2.0 for _, o in out):
                    out.append((score, c))
        return out

    def _fit_inside(self, shape: _bg.Assembly, pic: _Picture, start: _bg.Camera) -> _bg.CameraFit:
        """Scale and translation of ``start``'s orientation fitted to a picture that shows
        ``shape`` with new parts on it."""
        return self._fit(
            shape,
            pic,
            start,
            LEVELS_INSIDE,
            free=(False, False, False, True, True, True),
            rerender_px=INSIDE_RERENDER_PX,
        )

    # -- the steps -----------------------------------------------------------------------------

    def _first(
        self, step: Step, components: dict[ComponentRef, _bg.Component]
    ) -> Iterator[CameraEstimate]:
        """Cameras for a build's first step (nothing built yet), by the frame convention (see
        the module docs), most likely first, each made when it is asked for."""
        pic = self.picture(step)
        if pic.blank:
            yield _failed("the picture is blank")
            return
        entries = [c for c in step.components if c.component in components]
        if not entries:
            yield _failed("the step adds nothing mepnet can place")
            return

        def first(cam: _bg.Camera, fit_score: float | None = None) -> CameraEstimate:
            return CameraEstimate(cam, "estimated", fit_score, "first step", frame="convention")

        if len(entries) == 1 and entries[0].count == 1:
            fit = self._search_full(_alone(components, entries[0]), pic, n=4)
            if fit is not None and _full_ok(fit):
                yield first(canonical(fit.camera), fit.agree)
            else:  # the plan loop fits it to the predicted step, and judges
                yield first(self._prior_view(pic, entries, components))
            return
        # several components: each must lie inside the drawing; the plan loop fits the camera
        # to the whole predicted step and predicts again. The largest's best fit first, then
        # every other fit of it and of the next largest, best first
        by_size = sorted(entries, key=lambda e: -len(np.asarray(components[e.component].voxels)))
        first_of: dict[ComponentRef, Any] = {}  # one entry per component (its first colour)
        for e in by_size:
            first_of.setdefault(e.component, e)
        parts = list(first_of.values())[:FIRST_PARTS]

        def fits_of(e: Any) -> list[_bg.CameraFit]:
            found = [f for f in self._search_inside(_alone(components, e), pic) if _part_ok(f)]
            return sorted(found, key=_part_score, reverse=True)

        rest = fits_of(parts[0])
        seen: list[_bg.Camera] = []
        if rest:
            seen.append(canonical(rest.pop(0).camera))
            yield first(seen[0])
        for e in parts[1:]:
            rest += fits_of(e)
        for fit in sorted(rest, key=_part_score, reverse=True):
            cam = canonical(fit.camera)
            if all(_differs(cam, [c]) or abs(math.log(cam.scale / c.scale)) > 0.15 for c in seen):
                seen.append(cam)
                yield first(cam)
        yield first(self._prior_view(pic, entries, components))

    def _prior_view(
        self, pic: _Picture, entries: list[Any], components: dict[ComponentRef, _bg.Component]
    ) -> _bg.Camera:
        """The convention's view framed to the drawing: its area over the components' projected
        box areas gives the scale, its centroid the translation."""
        unit = _bg.Camera(FIRST_ELEVATION, FIRST_AZIMUTH, 0.0, 1.0, (0.0, 0.0))
        view = np.abs(unit.rotation()[2])
        area = 0.0  # LDU^2
        for e in entries:
            vox = np.asarray(components[e.component].voxels)
            size = (vox.max(axis=0) - vox.min(axis=0) + 1) * np.array([10.0, 8.0, 10.0])
            a, b, c = size
            area += e.count * (b * c * view[0] + a * c * view[1] + a * b * view[2])
        h, w = pic.fg.shape
        ndc_area = float(pic.fg.sum()) * (2.0 / w) * (2.0 / h)
        scale = math.sqrt(ndc_area / max(area, 1e-6))
        rows, cols = np.nonzero(pic.fg)
        cx = float(((cols + 0.5) / w * 2 - 1).mean())
        cy = float((1 - (rows + 0.5) / h * 2).mean())
        return _with(unit, scale=scale, translation=(cx, cy))

    def _next(
        self,
        step: Step,
        base: _bg.Assembly,
        components: dict[ComponentRef, _bg.Component],
        previous: tuple[Step, CameraEstimate] | None,
        same_frame: bool,
        verified: bool,
    ) -> Iterator[CameraEstimate]:
        """Hypotheses for a step on a non-empty ``base``, most likely first, made as they are
        asked for (see the module docs); a single failed estimate when none fits.
        ``previous``: the previous step and the camera it kept; ``same_frame``: whether that
        camera is in the frame of ``base``; ``verified``: whether it was fitted to ``base``."""
        pic = self.picture(step)
        if pic.blank:
            yield _failed("the picture is blank")
            return
        anchor: _bg.Camera | None = None
        if previous is not None and previous[1].camera is not None:
            prev_step, prev = previous
            prev_pic = self.picture(prev_step)
            anchor_fit: float | None = None
            if verified:
                anchor, anchor_fit = prev.camera, prev.fit
            elif not prev_pic.blank:
                if same_frame:
                    fit = self._fit(base, prev_pic, prev.camera, LEVELS_CLOSE)  # type: ignore[arg-type]
                    if _full_ok(fit):
                        anchor, anchor_fit = fit.camera, fit.agree
                if anchor is None:
                    found = self._search_full(base, prev_pic, views=[prev_pic, pic])
                    if found is not None and _full_ok(found):
                        anchor, anchor_fit = found.camera, found.agree
            if anchor is None and same_frame:
                anchor = prev.camera  # the base may be wrong (built on mistakes)
            elif anchor is not None and not prev_pic.blank and len(base) <= SMALL_BASE:
                anchor = self._edge_check(base, prev_pic, pic, anchor, anchor_fit)
        yielded: list[_bg.Camera] = []

        def offer(
            fits: list[tuple[_bg.CameraFit, str]], ok: Any, weak: bool = False
        ) -> Iterator[CameraEstimate]:
            for f, how in fits:
                if ok(f) and all(_camera_distance(f.camera, c, pic) > 1.0 for c in yielded):
                    yielded.append(f.camera)
                    how = f"{how} (weak)" if weak else how
                    yield CameraEstimate(f.camera, "estimated", f.agree, how)

        first: list[tuple[_bg.CameraFit, str]] = []
        if anchor is not None:
            # the usual zoom first; every scale only when asked for more
            first = [
                (self._fit_inside(base, pic, c), "carried")
                for c in self._sweep(base, pic, anchor, wide=False)[:1]
            ]
            yield from offer(first, _part_ok)
        # the base may be mostly hidden by the new part, or say little about the view: camera
        # and placement together
        joint = self._joint(step, base, components, pic, anchor)
        yield from offer(joint, lambda f: f.agree >= JOINT_STRONG and _full_ok(f))
        more = list(first)
        if anchor is not None:
            # the base may be turned round: other starts and quarter turns
            starts = [c for _, c in self._sweep_scored(base, pic, anchor, both=True)]
            more += [
                (self._fit_inside(base, pic, c), "carried")
                for c in starts
                if all(_camera_distance(c, f.camera, pic) > 2.0 for f, _ in first)
            ]
            for k in (1, 2, 3):
                turned = _with(anchor, azimuth=anchor.azimuth + 90.0 * k)
                for start in self._sweep(base, pic, turned)[:1]:
                    more.append((self._fit_inside(base, pic, start), "turned"))
        more.sort(key=lambda fh: -_part_score(fh[0]))
        yield from offer(more, _part_ok)
        # wholes that explain the picture only roughly: after the base's own fits (a step's
        # parts may stand apart from the base, where the joint search does not look)
        yield from offer(joint, _full_ok)
        if not yielded:
            more += [(f, "searched") for f in self._search_inside(base, pic)]
            more.sort(key=lambda fh: -_part_score(fh[0]))
            yield from offer(more, _part_ok)
        # a base hidden by new parts agrees little: what lies inside the drawing
        yield from offer(
            more, lambda f: f.inside >= PART_INSIDE and f.agree >= MIN_AGREE, weak=True
        )
        if not yielded and self._last_good is not None:
            # the shape built so far is wrong (built on mistakes) or hidden: the last picture
            # with a camera found again in this one, zoomed and panned
            last_step, last_cam = self._last_good
            reg = self._register(self.picture(last_step), last_cam, pic)
            if reg is not None and reg[0] >= REGISTER_AGREE:
                yielded.append(reg[1])
                yield CameraEstimate(reg[1], "estimated", reg[0], "registered")
        if not yielded:
            best = more[0][0] if more else None
            yield _failed(_why("the shape built so far does not fit the picture", best))

    def _joint(
        self,
        step: Step,
        base: _bg.Assembly,
        components: dict[ComponentRef, _bg.Component],
        pic: _Picture,
        anchor: _bg.Camera | None,
    ) -> list[tuple[_bg.CameraFit, str]]:
        """For a step that adds one or two components to a base the picture says little about
        (small, round, hidden behind the new parts): camera and placements together. Every
        valid placement of the first component on the base, seen from the anchor's orientation
        and the edges' (each quarter turn), is framed to the drawing as a coarse silhouette;
        with two, the second's best placements on base and first from the same view (both
        orders). The best few wholes are rendered and placed by their colours and fitted to the
        picture, which shows exactly them. Fits that explain it well, best first."""
        insts = [e for e in step.components for _ in range(e.count)]
        if not 1 <= len(insts) <= JOINT_PARTS or any(e.component not in components for e in insts):
            return []
        el, az = pic.edge_view()
        orients = {(el, az + 90.0 * k, 0.0) for k in range(4)}
        own = None
        if anchor is not None:
            own = (float(anchor.elevation), float(anchor.azimuth), float(anchor.roll))
            orients.add(own)
            if len(base) <= SMALL_BASE and len(insts) == 1:
                # a small base may not fix the azimuth (a round part: the first step's is the
                # convention's); its elevation holds: the anchor's turned both ways (one
                # component: its wholes are ranked by rendered silhouettes; a pair's first
                # part is ranked by boxes, which more views crowd out)
                orients |= {(own[0], own[1] + d, own[2]) for d in JOINT_AZIMUTH_OFFSETS}
        # a base the same after a turn shows the same whole turned from the view turned back
        # (C(az) R_k = C(az - 90k)): counted once, a 2x2 brick's four views do not fill the
        # shortlist
        motions = [
            IDENTITY,
            *symmetries([(c, y, u, base.colour(i)) for i, c, y, u in base.instances()]),
        ]
        size = JOINT_RANKED + JOINT_RANKED // 2
        if len(insts) == 1:
            comp, colour = components[insts[0].component], insts[0].colour
            wholes_box = []
            for yaw, t, cam in self._joint_short(base, comp, pic, orients, own, motions, size):
                whole = base.copy()
                whole.add(comp, yaw, t, colour)
                wholes_box.append((whole, cam))
        else:
            wholes_box = self._joint_pairs(
                base, components, insts, pic, orients, own, motions, size
            )
        # box silhouettes only shortlist: each whole is rendered and placed by its colours
        # (a part mostly hiding a base of another colour: the colours say where); the best
        # few by either are fitted
        wholes: list[tuple[float, _bg.Assembly, _bg.Camera]] = []  # in box order
        for whole, cam in wholes_box:
            # a whole is all the picture shows: every pixel's colour counts in full
            found = self._sweep_scored(whole, pic, cam, wide=False, kernel=False)
            if found:
                wholes.append((found[0][0], whole, found[0][1]))
        by_colour = sorted(range(len(wholes)), key=lambda i: -wholes[i][0])[:JOINT_STARTS]
        by_box = range(min(JOINT_STARTS, len(wholes)))
        fits = []
        for i in dict.fromkeys([*by_colour, *by_box]):
            _, whole, cam = wholes[i]
            fit = self._fit(whole, pic, cam, LEVELS_ROUGH)
            if _full_ok(fit):
                fits.append((fit, "joint"))
        return _prefer_front(fits, lambda f: f.agree + f.iou, anchor)

    def _joint_short(
        self,
        base: _bg.Assembly,
        comp: _bg.Component,
        pic: _Picture,
        orients: set[tuple[float, float, float]],
        own: tuple[float, float, float] | None,
        motions: list[Motion],
        size: int,
        rendered: bool = True,
    ) -> list[tuple[int, tuple[int, int, int], _bg.Camera]]:
        """The ``size`` best distinct (placement, view) of one component on the base by framed
        silhouettes of the whole (``rendered``: boxes pre-select, the rendered wholes rank;
        else boxes only: a whole that still lacks a part the picture shows), in that order; the
        anchor's view (``own``) gets a shortlist of its own (manuals mostly only zoom and
        pan). Distinct: a symmetric part's turns are the same
        placement, and one view of a base with symmetries ``motions`` shows what the turned
        view shows with the placement turned."""
        boxes = (JOINT_BOXES if rendered else 4) * JOINT_RANKED
        ranked = _bg.search_placements(base, comp, pic.fg, sorted(orients), WORK_PX, boxes)
        if own is not None:
            ranked += _bg.search_placements(base, comp, pic.fg, [own], WORK_PX, 2 * JOINT_RANKED)
        if rendered:
            # boxes only pre-select (a slope's box is its whole bounding box): ranked again by
            # the whole's rendered silhouette, framed to the drawing the same way
            scored: dict[tuple[Any, ...], tuple[float, _bg.Camera]] = {}
            for _, yaw, t, cam in ranked:
                key = (
                    yaw,
                    tuple(int(v) for v in t),
                    round(cam.elevation, 4),
                    round(cam.azimuth, 4),
                )
                if key not in scored:
                    whole = base.copy()
                    whole.add(comp, yaw, key[1], 1)
                    scored[key] = _framed_silhouette(whole, cam, pic)
            order = sorted(scored, key=lambda k: (-scored[k][0], k))
            ranked = [(scored[k][0], k[0], k[1], scored[k][1]) for k in order]
        short: list[tuple[int, tuple[int, int, int], _bg.Camera]] = []
        for _, yaw, t, cam in ranked:
            if len(short) == size:
                break
            t = (int(t[0]), int(t[1]), int(t[2]))
            back = [(m.turn, m.inverse().apply(yaw, t)) for m in motions]
            if not any(
                abs(c.elevation - cam.elevation) < 0.01
                and abs(_angle(cam.azimuth - 90.0 * turn - c.azimuth)) < 0.01
                and comp.same_placement(y, u, y2, t2)
                for y, u, c in short
                for turn, (y2, t2) in back
            ):
                short.append((yaw, t, cam))
        return short

    def _joint_pairs(
        self,
        base: _bg.Assembly,
        components: dict[ComponentRef, _bg.Component],
        insts: list[Any],
        pic: _Picture,
        orients: set[tuple[float, float, float]],
        own: tuple[float, float, float] | None,
        motions: list[Motion],
        size: int,
    ) -> list[tuple[_bg.Assembly, _bg.Camera]]:
        """Wholes of a step adding two components, best box silhouette first: the first
        component's shortlist (either may be the first), then the second's best placements
        on base and first from the same view; each whole once."""
        orders = [insts, insts[::-1]] if insts[0] != insts[1] else [insts]
        found: dict[Any, tuple[float, _bg.Assembly, _bg.Camera]] = {}
        for a, b in orders:
            comp_a, comp_b = components[a.component], components[b.component]
            for yaw, t, cam in self._joint_short(
                base, comp_a, pic, orients, own, motions, size // len(orders), rendered=False
            ):
                with_a = base.copy()
                with_a.add(comp_a, yaw, t, a.colour)
                view = (float(cam.elevation), float(cam.azimuth), float(cam.roll))
                kept: list[tuple[int, tuple[int, int, int]]] = []
                for score, yb, tb, cb in _bg.search_placements(
                    with_a, comp_b, pic.fg, [view], WORK_PX, 4 * JOINT_PAIR_SECOND
                ):
                    if len(kept) == JOINT_PAIR_SECOND:
                        break
                    tb = (int(tb[0]), int(tb[1]), int(tb[2]))
                    if any(comp_b.same_placement(y, u, yb, tb) for y, u in kept):
                        continue
                    kept.append((yb, tb))
                    key = (
                        round(view[0], 2),
                        round(view[1] % 360.0, 2),
                        tuple(
                            sorted(
                                placement_key((comp_a, yaw, t, a.colour))
                                + placement_key((comp_b, yb, tb, b.colour))
                            )
                        ),
                    )
                    if key in found and found[key][0] >= score:
                        continue
                    whole = with_a.copy()
                    whole.add(comp_b, yb, tb, b.colour)
                    found[key] = (float(score), whole, cb)
        # the wholes are complete: ranked by their rendered silhouettes
        ranked = [(*_framed_silhouette(whole, cam, pic), whole) for _, whole, cam in found.values()]
        ranked.sort(key=lambda r: -r[0])
        return [(whole, cam) for _, cam, whole in ranked[:size]]

    def _edge_check(
        self,
        base: _bg.Assembly,
        prev_pic: _Picture,
        pic: _Picture,
        anchor: _bg.Camera,
        anchor_fit: float | None,
    ) -> _bg.Camera:
        """The anchor, or the orientation this picture's edges suggest when they disagree with
        it and the base cannot tell the two apart (a round or tiny base says little about the
        azimuth; the new parts' edges do): the base fitted in the previous picture with the
        edges' orientation (turned to the anchor's quarter) explains it as well."""
        el, az = pic.edge_view()
        turn = round((float(anchor.azimuth) - az) / 90.0)
        az += 90.0 * turn
        if (
            abs(el - anchor.elevation) <= ORIENTATION_TOL
            and abs(_angle(az - anchor.azimuth)) <= ORIENTATION_TOL
        ):
            return anchor
        start = _with(anchor, elevation=el, azimuth=az, roll=0.0)
        fit = self._fit(
            base, prev_pic, start, LEVELS_CLOSE, free=(False, False, False, True, True, True)
        )
        if anchor_fit is None:
            anchor_fit = self._fit(base, prev_pic, anchor, (0,), free=(False,) * 6).agree
        return fit.camera if fit.agree >= anchor_fit - 0.01 else anchor

    def _search_inside(self, base: _bg.Assembly, pic: _Picture) -> list[_bg.CameraFit]:
        """Fits of the base to a picture showing it with new parts, over the view sphere:
        orientations ranked by the coarse full-silhouette score, the best few swept (the
        best-scored start: no previous scale to prefer) and fitted."""
        el, az = pic.edge_view()
        views = [_bg.Camera(el, az + 90.0 * k, 0.0, 1.0, (0.0, 0.0)) for k in range(4)]
        cands = [(e, a, 0.0) for e in SEARCH_ELEVATIONS for a in SEARCH_AZIMUTHS]
        ranked = _distinct(_bg.search_orientations(base, pic.fg, cands, WORK_PX), 2)
        starts = views + [cam for _, cam in ranked]
        return [
            self._fit_inside(base, pic, max(found, key=lambda f: f[0])[1])
            for cam in starts
            if (found := self._sweep_scored(base, pic, cam))
        ]


def _framed_silhouette(
    shape: _bg.Assembly, cam: _bg.Camera, pic: _Picture
) -> tuple[float, _bg.Camera]:
    """The IoU of ``shape``'s silhouette, seen from ``cam``'s orientation and framed to the
    drawing's box (scale: the geometric mean of the two sides' ratios; centres aligned), with
    the reduced foreground; and that camera."""
    n = WORK_PX
    ref = _with(cam, scale=1.0, translation=(0.0, 0.0)).fitted(
        np.asarray(bounds_corners(shape), dtype=np.float64), 0.9
    )
    sil = _bg.render(shape, ref, n, n).ids >= 0
    fg, fg_box = pic.drawing_box()
    if not sil.any() or fg_box is None:
        return 0.0, cam
    sx0, sx1, sy0, sy1 = _ndc_box(sil)
    fx0, fx1, fy0, fy1 = fg_box
    s = math.sqrt((fx1 - fx0) / (sx1 - sx0) * (fy1 - fy0) / (sy1 - sy0))
    # the reference's NDC p shows at s * p + offset on the picture
    ox = (fx0 + fx1) / 2.0 - s * (sx0 + sx1) / 2.0
    oy = (fy0 + fy1) / 2.0 - s * (sy0 + sy1) / 2.0
    h, w = fg.shape
    ndc_x = (np.arange(w) + 0.5) / w * 2 - 1
    ndc_y = 1 - (np.arange(h) + 0.5) / h * 2
    cols = np.floor(((ndc_x - ox) / s + 1) / 2 * n).astype(np.int64)
    rows = np.floor((1 - (ndc_y - oy) / s) / 2 * n).astype(np.int64)
    ok = np.outer((rows >= 0) & (rows < n), (cols >= 0) & (cols < n))
    framed = sil[np.ix_(np.clip(rows, 0, n - 1), np.clip(cols, 0, n - 1))] & ok
    inter = float((framed & fg).sum())
    iou = inter / max(float((framed | fg).sum()), 1.0)
    tx, ty = ref.translation
    return iou, _with(ref, scale=ref.scale * s, translation=(s * tx + ox, s * ty + oy))


def _ndc_box(mask: np.ndarray) -> tuple[float, float, float, float]:
    """The box of a non-empty mask's pixels in NDC: x0, x1, y0, y1 (x right, y up)."""
    rows, cols = np.nonzero(mask)
    h, w = mask.shape
    return (
        2.0 * cols.min() / w - 1.0,
        2.0 * (cols.max() + 1) / w - 1.0,
        1.0 - 2.0 * (rows.max() + 1) / h,
        1.0 - 2.0 * rows.min() / h,
    )


def _centred(ref: _bg.Camera, scale: float) -> tuple[float, float]:
    """The translation that, at ``scale`` and ``ref``'s orientation, puts what ``ref`` sees at
    its picture's centre at the picture's centre (NDC scales with the camera's scale)."""
    k = scale / ref.scale
    return (k * ref.translation[0], k * ref.translation[1])


def _offset(ref: _bg.Camera, cam: _bg.Camera) -> tuple[float, float]:
    """How far (NDC) ``cam`` moves the reference of :meth:`BuildCameras._resampled` from the
    grid's centre."""
    cx, cy = _centred(ref, cam.scale)
    return (cam.translation[0] - cx, cam.translation[1] - cy)


def _alone(components: dict[ComponentRef, _bg.Component], entry: Any) -> _bg.Assembly:
    """A callout entry's component alone, standing on the ground at the origin."""
    comp = components[entry.component]
    shape = _bg.Assembly()
    shape.add(comp, 0, (0, -int(np.asarray(comp.voxels)[:, 1].min()), 0), entry.colour)
    return shape


def _start_distance(a: _bg.Camera, b: _bg.Camera, side: int) -> float:
    """How far apart two starts of the same orientation put the shape, roughly, in pixels of
    a ``side``-pixel picture (translation, and scale as a share of a half frame)."""
    dt = math.hypot(a.translation[0] - b.translation[0], a.translation[1] - b.translation[1])
    return side / 2 * (dt + abs(math.log(a.scale / b.scale)))


def _prefer_front(
    fits: list[tuple[_bg.CameraFit, str]], score: Any, anchor: _bg.Camera | None = None
) -> list[tuple[_bg.CameraFit, str]]:
    """Fits best first by ``score``; among those within :data:`TIE` of the best, the one
    nearest a front three-quarter view first (a symmetric or hidden base explains the picture
    as well from the back: the views instruction tools use decide), or, given the previous
    step's ``anchor``, the one nearest its view (manuals mostly only zoom and pan)."""
    fits = sorted(fits, key=lambda fh: -score(fh[0]))
    if len(fits) < 2:
        return fits
    top = score(fits[0][0])
    close = [fh for fh in fits if score(fh[0]) >= top - TIE]
    if anchor is not None:
        first = min(close, key=lambda fh: rotation_error(fh[0].camera, anchor))
    else:
        first = min(close, key=lambda fh: _front_distance(fh[0].camera.azimuth))
    return [first] + [fh for fh in fits if fh is not first]


def _confident(fit: _bg.CameraFit) -> bool:
    """A fit of the base so good that no other hypothesis is worth trying."""
    return fit.inside >= CONFIDENT_INSIDE and fit.agree >= CONFIDENT_AGREE


def _full_ok(fit: _bg.CameraFit | None) -> bool:
    return fit is not None and fit.agree >= FULL_AGREE and fit.iou >= FULL_IOU


def _part_ok(fit: _bg.CameraFit | None) -> bool:
    return fit is not None and fit.inside >= PART_INSIDE and fit.agree >= PART_AGREE


def _part_score(fit: _bg.CameraFit) -> float:
    """How well a fit of the base explains a picture of the base with new parts."""
    return min(fit.inside / PART_INSIDE, 1.0) + fit.agree


def _why(what: str, fit: _bg.CameraFit | None) -> str:
    if fit is None:
        return what
    return (
        f"{what} (best fit: {100 * fit.agree:.0f}% of its pixels agree, "
        f"{100 * fit.inside:.0f}% of its silhouette on the drawing)"
    )


def _timed(estimates: Iterator[CameraEstimate]) -> Iterator[CameraEstimate]:
    """``estimates`` with each one's ``seconds`` the time its own making took: the generator
    runs only while asked for the next (a clock inside it would also count the time the plan
    loop spends predicting the step with the previous one). The only place estimates are
    timed."""
    while True:
        t0 = time.perf_counter()
        est = next(estimates, None)
        if est is None:
            return
        yield dataclasses.replace(est, seconds=time.perf_counter() - t0)


def _failed(why: str) -> CameraEstimate:
    return CameraEstimate(
        None,
        "estimated",
        None,
        "failed",
        failure=f"camera could not be estimated: {why}",
    )


def _camera_distance(a: _bg.Camera, b: _bg.Camera, pic: _Picture) -> float:
    """Mean pixel distance between where two cameras put the corners of a 200 LDU cube at the
    origin, in ``pic``'s pixels (a rough sameness test)."""
    corners = np.array(list(np.ndindex(2, 2, 2)), dtype=np.float64) * 200.0 - 100.0
    h, w = pic.fg.shape
    pa, _ = a.project(corners, w, h)
    pb, _ = b.project(corners, w, h)
    return float(np.linalg.norm(pa - pb, axis=1).mean())


def rotation_error(a: _bg.Camera, b: _bg.Camera) -> float:
    """The angle (degrees) of the rotation between two cameras' orientations."""
    r = np.asarray(a.rotation()) @ np.asarray(b.rotation()).T
    return math.degrees(math.acos(max(-1.0, min(1.0, (float(np.trace(r)) - 1.0) / 2.0))))


def reprojection_error(
    a: _bg.Camera, b: _bg.Camera, points: np.ndarray, size: tuple[int, int]
) -> float:
    """Mean pixel distance between the projections of world ``points`` (N, 3) by two cameras."""
    w, h = size
    pa, _ = a.project(points, w, h)
    pb, _ = b.project(points, w, h)
    return float(np.linalg.norm(pa - pb, axis=1).mean())
