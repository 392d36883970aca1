"""mepnet.state: the previous step's picture as the base drawn in the manual's own style."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import generate_manuals
from mepnet import _brickgeom as _bg
from mepnet.manual import answers_of, iter_manual_dirs, load_manual
from mepnet.manual.page import make_camera
from mepnet.stage2.base import EarlierStep, StepContext
from mepnet.stage2.synthesis import step_change, step_picture
from mepnet.state import CHANGE_THRESHOLD, previous_change, same_view, warp_previous


def _shape() -> _bg.Assembly:
    asm = _bg.Assembly()
    asm.add(_bg.Component.primitive("3001"), 0, (0, 3, 0), 4)
    asm.add(_bg.Component.primitive("3003"), 1, (1, 6, 0), 1)
    return asm


def _picture(asm: _bg.Assembly, cam: dict, size: int = 256) -> np.ndarray:
    return _bg.render(asm, make_camera(cam), size, size).rgb.transpose(2, 0, 1) / 255.0


CAM = {"elevation": 30.0, "azimuth": 315.0, "roll": 0.0, "scale": 0.008, "translation": [0.0, 0.0]}


def test_a_zoomed_and_panned_picture_is_the_previous_one_warped():
    asm = _shape()
    zoomed = dict(CAM, scale=0.011, translation=[0.12, -0.08])
    before, after = _picture(asm, CAM), _picture(asm, zoomed)
    warped = warp_previous(before, CAM, zoomed, 256)
    assert warped is not None
    fg_w, fg_a = warped.min(axis=0) < 0.9, after.min(axis=0) < 0.9
    iou = (fg_w & fg_a).sum() / (fg_w | fg_a).sum()
    assert iou > 0.97
    assert np.median(np.abs(warped - after).max(axis=0)[fg_a]) < 0.05
    # shifted the wrong way, it would not fit
    wrong = warp_previous(before, CAM, dict(zoomed, translation=[-0.12, 0.08]), 256)
    fg_x = wrong.min(axis=0) < 0.9  # type: ignore[union-attr]
    assert (fg_x & fg_a).sum() / (fg_x | fg_a).sum() < 0.8


def test_the_previous_picture_zoomed_differs_only_where_a_part_was_added():
    """The previous picture zoomed and panned onto this step's view draws its lines and edges up
    to a pixel away (bilinear resampling): compared pixel for pixel, those lines read as
    change all over the base; looked for within a pixel, only the new part's area changes."""
    asm = _shape()
    zoomed = dict(CAM, scale=0.0089, translation=[0.031, -0.017])
    before = _picture(asm, CAM)
    warped = warp_previous(before, CAM, zoomed, 256)
    assert warped is not None
    n0 = len(asm)
    asm.add(_bg.Component.primitive("3024"), 0, (-2, 9, 0), 14)  # a yellow 1x1 plate on top
    r = _bg.render(asm, make_camera(zoomed), 256, 256)
    after = r.rgb.transpose(2, 0, 1) / 255.0
    new = r.ids >= n0
    outside = np.pad(~new, 1, constant_values=True)
    inner = new.copy()  # the part's pixels with no 4-neighbour outside it
    for rows, cols in ((slice(2, None), slice(1, -1)), (slice(None, -2), slice(1, -1))) + (
        (slice(1, -1), slice(2, None)),
        (slice(1, -1), slice(None, -2)),
    ):
        inner &= ~outside[rows, cols]
    assert inner.sum() > 30
    exact = previous_change(after, warped, reach=0) > CHANGE_THRESHOLD
    near = previous_change(after, warped) > CHANGE_THRESHOLD
    false_exact, false_near = int((exact & ~new).sum()), int((near & ~new).sum())
    assert false_exact > 100  # the resampled lines
    assert false_near < false_exact / 4
    assert near[inner].mean() > 0.95  # the new part's inside stays changed


def test_another_view_is_not_warped():
    turned = dict(CAM, azimuth=45.0)
    assert not same_view(CAM, turned)
    assert warp_previous(_picture(_shape(), CAM), CAM, turned, 256) is None
    assert same_view(CAM, dict(CAM, azimuth=315.1, scale=0.01))
    assert same_view(dict(CAM, azimuth=359.95), dict(CAM, azimuth=0.05))


@pytest.fixture(scope="module")
def manual_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return next(iter(iter_manual_dirs(generate_manuals(tmp_path_factory.mktemp("st"), 1, 4242))))


def test_a_manual_drawn_unlike_ours_changes_only_where_the_step_adds(manual_dir: Path):
    """Both pictures darkened and tinted alike (another renderer's look): against our render
    the whole base reads as changed; against the previous picture only the new parts do."""
    m = load_manual(manual_dir)
    comps = answers_of(m).components(m)
    ans = m.answers.build(None)  # type: ignore[union-attr]
    steps = m.main.steps
    k = next(i for i in range(1, len(steps)) if same_view(steps[i - 1].camera, steps[i].camera))
    base = _bg.Assembly()
    for i in range(k):
        for inst in ans.truth(i).placed():
            base.add(comps[inst.component], inst.yaw, inst.t, inst.colour)
    styled = {}
    for j in (k - 1, k):  # a consistent other look: per channel gamma and a tint
        img = steps[j].image().astype(np.float32) / 255.0
        img = img ** np.array([2.6, 1.0, 0.4], np.float32) * np.array([0.95, 0.9, 1.0], np.float32)
        path = manual_dir.parent / f"styled_{j}.png"
        from PIL import Image

        Image.fromarray((img * 255).round().astype(np.uint8)).save(path)
        styled[j] = dataclasses.replace(steps[j], image_path=path)
    ids = ans.truth(k).ids()
    new_ids = {i for e in ans.truth(k).instances_of for i in e}
    new = np.isin(ids, list(new_ids))
    old = (ids >= 0) & ~new
    ctx_render = StepContext(styled[k], base, comps, m.image_size)
    ctx_prev = StepContext(
        styled[k], base, comps, m.image_size, (EarlierStep(styled[k - 1], len(base)),)
    )
    pic = step_picture(ctx_render)
    c_render, _ = step_change(ctx_render, pic)
    c_prev, _ = step_change(ctx_prev, pic)
    changed_render = (c_render > CHANGE_THRESHOLD)[old].mean()
    changed_prev = (c_prev > CHANGE_THRESHOLD)[old].mean()
    assert changed_prev < 0.02 and changed_render > 4 * changed_prev
    assert (c_prev > CHANGE_THRESHOLD)[new].mean() > 0.9


def test_the_latest_picture_of_the_same_view_is_used_and_parts_added_since_are_not_trusted(
    manual_dir: Path,
):
    from mepnet.stage2.synthesis import previous_picture

    m = load_manual(manual_dir)
    comps = answers_of(m).components(m)
    ans = m.answers.build(None)  # type: ignore[union-attr]
    steps = m.main.steps
    k = max(i for i in range(2, len(steps)) if same_view(steps[i - 2].camera, steps[i].camera))
    base = _bg.Assembly()
    counts = []
    for i in range(k):
        for inst in ans.truth(i).placed():
            base.add(comps[inst.component], inst.yaw, inst.t, inst.colour)
        counts.append(len(base))
    turned = dataclasses.replace(
        steps[k - 1], camera=dict(steps[k].camera, azimuth=steps[k].camera["azimuth"] + 90)
    )
    earlier = (EarlierStep(steps[k - 2], counts[k - 2]), EarlierStep(turned, counts[k - 1]))
    got = previous_picture(StepContext(steps[k], base, comps, m.image_size, earlier))
    assert got is not None
    warped, trusted = got
    ids = _bg.render(base, make_camera(steps[k].camera), 256, 256, line_px=0.0).ids
    assert np.array_equal(trusted, ids < counts[k - 2])
    assert (~trusted).any() == (counts[k - 1] > counts[k - 2])
    # only a turned earlier view: nothing to compare with
    only_turned = StepContext(steps[k], base, comps, m.image_size, earlier[1:])
    assert previous_picture(only_turned) is None
    assert previous_picture(StepContext(steps[k], base, comps, m.image_size)) is None


def test_a_first_part_drawn_large_is_the_change_not_the_page():
    """A build's first step: nothing built, the state render is the bare page. A first part
    drawn over most of the picture is what changed; the page around it is not (the brightness
    shift comes from the picture's border, not from most of its pixels). A tinted page is
    still the page."""
    from mepnet.state import change_map, fit_tone

    for page in ((1.0, 1.0, 1.0), (0.93, 0.9, 0.8)):
        image = np.empty((3, 64, 64), np.float32)
        image[:] = np.array(page, np.float32)[:, None, None]
        image[:, 6:60, 4:62] = np.array([0.6, 0.05, 0.05], np.float32)[:, None, None]  # 76%
        state = np.ones((3, 64, 64), np.float32)  # the page as mepnet draws it
        change = change_map(image, state, fit_tone(image, state))
        assert (change[6:60, 4:62] > CHANGE_THRESHOLD).all()
        outside = np.ones((64, 64), bool)
        outside[6:60, 4:62] = False
        assert (change[outside] <= CHANGE_THRESHOLD).all()


def _lit_flat(asm: _bg.Assembly, cam: dict, size: int = 256) -> np.ndarray:
    """``asm`` drawn as a renderer lit almost flat draws it (every face at 0.95 of its colour,
    where mepnet shades faces 0.6-0.9): mepnet's drawing divided by its own shading."""
    from mepnet.state import shade_classes

    rgb = _picture(asm, cam, size)
    white = _bg.Assembly()
    for _, comp, yaw, t in asm.instances():
        white.add(comp, yaw, t, 15)
    shade = _picture(white, cam, size).mean(axis=0)
    lit = np.where(shade > 0.3, rgb / np.maximum(shade, 1e-3) * 0.95, rgb)
    assert (shade_classes(asm, cam, size) >= 0).sum() > 1000
    return np.clip(lit, 0.0, 1.0).astype(np.float32)


def test_faces_lit_another_way_are_mapped_by_the_previous_picture():
    """A renderer lighting faces its own way (LeoCAD: nearly flat) with no earlier picture of
    the same view: one gain and bias per channel leaves the base's faces changed; the tone per
    shade class learnt from the previous step's picture (another view: lighting follows the
    camera) maps them, and the new part stays changed."""
    from mepnet.state import change_map, fit_tone, shade_classes, shade_tones, state_render

    base = _shape()
    shape = base.copy()
    shape.add(_bg.Component.primitive("3003"), 0, (-3, 6, 0), 2)
    turned = dict(CAM, azimuth=135.0)
    previous, picture = _lit_flat(base, CAM), _lit_flat(shape, turned)
    seen, _ = state_render(base, CAM, 256)
    tones = shade_tones(previous, seen, shade_classes(base, CAM, 256))
    state, _ = state_render(base, turned, 256)
    ids = _bg.render(shape, make_camera(turned), 256, 256).ids
    old, new = ids >= 0, ids == 2
    plain = change_map(picture, state, fit_tone(picture, state)) > CHANGE_THRESHOLD
    shaded = (
        change_map(
            picture, state, fit_tone(picture, state), (shade_classes(base, turned, 256), tones)
        )
        > CHANGE_THRESHOLD
    )
    kept = old & ~new
    assert plain[kept].mean() > 0.3  # one tone: the base's faces read as changed
    assert shaded[kept].mean() < 0.1
    assert shaded[new].mean() > 0.8


def test_a_new_parts_faces_are_compared_as_the_manuals_renderer_lights_them():
    """Per shade level one factor, learnt from the previous picture of the base (a renderer
    lighting faces almost flat), maps a new part of another colour onto the picture: its
    colour residual in stage 2 falls to a few hundredths, where one tone for all faces leaves
    it off by a tenth or more."""
    from mepnet.stage2.synthesis import Tone, _colour_off
    from mepnet.state import fit_tone, shade_classes, shade_factors, state_render

    base = _shape()
    shape = base.copy()
    shape.add(_bg.Component.primitive("3003"), 0, (-3, 6, 0), 25)  # orange: not in the base
    previous = _lit_flat(base, CAM)
    seen, _ = state_render(base, CAM, 256)
    classes = shade_classes(base, CAM, 256)
    tone = fit_tone(previous, seen)
    factors = shade_factors(previous, seen, classes, tone)
    assert (factors != 1.0).sum() >= 2  # faces mepnet shades darker are drawn lighter
    picture = _lit_flat(shape, CAM)
    r = _bg.render(shape, make_camera(CAM), 256, 256)
    new = r.ids == 2
    px = picture.transpose(1, 2, 0)[new]
    colour = np.asarray(_bg.colour_rgb(25), np.float64)
    shaded = _colour_off(px, r.rgb[new], Tone(tone[0], tone[1], False, factors), colour).mean()
    plain = _colour_off(px, r.rgb[new], Tone(tone[0], tone[1], False)).mean()
    assert shaded < 0.05
    assert plain > 0.1


def test_lines_drawn_on_the_bases_stud_rims_are_not_changes():
    """A renderer drawing every edge of the base thick (stud rims too, as LeoCAD outlines
    them): within a pixel of the edges of mepnet's drawing of the base a change is kept only
    where a change outside that band or one thicker than a line reaches it, so the rims go and
    a new part drawn over the base's edges stays whole."""
    from mepnet.stage2.synthesis import drawn_edges, tolerate_lines
    from mepnet.state import change_map, fit_tone, state_render

    base = _shape()
    shape = base.copy()
    shape.add(_bg.Component.primitive("3003"), 0, (-3, 6, 0), 2)
    r = _bg.render(shape, make_camera(CAM), 256, 256, style=_bg.RenderStyle(line_px=2.0))
    picture = r.rgb.transpose(2, 0, 1) / 255.0
    state, outline = state_render(base, CAM, 256)
    change = change_map(picture, state, fit_tone(picture, state))
    parts = tolerate_lines(change, outline) > CHANGE_THRESHOLD  # part outlines only
    rims = tolerate_lines(change, outline | drawn_edges(state)) > CHANGE_THRESHOLD
    new = r.ids == 2
    old = (r.ids >= 0) & ~new
    assert parts[old].mean() > 0.15 and rims[old].mean() < 0.05
    assert rims[new].mean() > 0.95
