"""Cameras estimated from the pictures (mepnet.cameras), the frame comparison (mepnet.frames),
the camfit binding, and the commands on manuals without cameras."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import generate_manuals
from mepnet import _brickgeom as _bg
from mepnet.cameras import BuildCameras, drop_cameras, moved_camera, reprojection_error
from mepnet.eval import _camera_errors
from mepnet.frames import Motion, candidate_motions, matches, moved, symmetries
from mepnet.geom import bounds_corners, rotate_ldu
from mepnet.manual import load_manual
from mepnet.plan import accuracy, run_manual
from mepnet.stage2 import make_predictor
from PIL import Image


@pytest.fixture(scope="module")
def manuals(tmp_path_factory: pytest.TempPathFactory) -> Path:
    # two small manuals (6 and 9 steps, one submodule): the tests run stage 2 by synthesis
    return generate_manuals(tmp_path_factory.mktemp("camdata"), 2, 31016)


@pytest.fixture(scope="module")
def runs(manuals: Path) -> list[tuple[object, object, object]]:
    """(manual, teacher-forced run with the manual's cameras, with estimated ones) per manual,
    stage 2 by synthesis (the oracles read the true yaw, which the first step's frame
    convention does not keep)."""
    synthesis = make_predictor("synthesis")
    out = []
    for d in sorted(manuals.iterdir()):
        man = load_manual(d)
        given = run_manual(man, synthesis, teacher_forced=True)
        estimated = run_manual(drop_cameras(man), synthesis, teacher_forced=True)
        out.append((man, given, estimated))
    return out


def _turned_error(got: _bg.Camera, cam: _bg.Camera) -> float:
    """Rotation error (degrees) of ``got`` against ``cam`` up to quarter turns of the azimuth
    (a base the same after a quarter turn looks the same from each)."""
    from mepnet.cameras import rotation_error

    return min(
        rotation_error(
            got,
            _bg.Camera(cam.elevation, cam.azimuth + 90.0 * k, 0.0, cam.scale, cam.translation),
        )
        for k in range(4)
    )


def errors(runs: list[tuple[object, object, object]], first: bool) -> list[tuple[float, float]]:
    out = []
    for man, _, run in runs:
        for b in run.builds:  # type: ignore[attr-defined]
            for s in b.steps:
                if (s.index == 1) == first:
                    e = _camera_errors(man, run, b, s)
                    if e is not None:
                        out.append(e)
    return out


def _drawn_step(
    tmp_path: Path, k: int, shape: _bg.Assembly, cam: _bg.Camera, entries: list[object]
) -> object:
    """Step ``k`` of a 256-pixel page showing ``shape`` drawn from ``cam``, adding ``entries``."""
    from mepnet.manual.page import Step

    path = tmp_path / f"step_{k}.png"
    Image.fromarray(_bg.render(shape, cam, 256, 256).rgb).save(path)
    return Step(k, path, None, entries, (256, 256))


def test_later_steps_recover_the_true_camera(runs: list[tuple[object, object, object]]):
    errs = np.array(errors(runs, first=False))
    assert len(errs) >= 10
    # rotation within a degree or two, reprojection of the true shape within a pixel or two
    assert np.median(errs[:, 0]) < 1.0 and np.median(errs[:, 1]) < 0.5, np.median(errs, axis=0)
    assert (errs[:, 1] < 2.0).mean() >= 0.8, errs


def test_first_steps_recover_the_camera_up_to_the_frame(runs: list[tuple[object, object, object]]):
    errs = np.array(errors(runs, first=True))
    assert len(errs) == 3
    assert np.median(errs[:, 0]) < 2.0 and np.median(errs[:, 1]) < 2.0, errs


def test_every_estimated_step_records_its_camera(runs: list[tuple[object, object, object]]):
    for _, given, run in runs:
        for b in run.builds:  # type: ignore[attr-defined]
            for s in b.steps:
                assert s.camera is not None and s.camera.source == "estimated"
                assert (s.camera.camera is None) == (s.camera.failure is not None)
                assert s.camera.seconds >= 0.0
                rec = s.camera.to_json()
                assert rec["camera_source"] == "estimated" and "camera_fit" in rec
        for b in given.builds:  # type: ignore[attr-defined]
            assert all(s.camera.source == "given" for s in b.steps)


def test_poses_with_estimated_cameras_stay_close_to_given_ones(
    runs: list[tuple[object, object, object]],
):
    right_given = right = total = 0
    for _, given, run in runs:
        r, t = accuracy(run)  # type: ignore[arg-type]
        right, total = right + r, total + t
        right_given += accuracy(given)[0]  # type: ignore[arg-type]
    assert total >= 15
    # what is lost on these manuals: a step whose base is a plate hidden under three new parts
    # (main step 2, 3 components) and two of main step 5's four (with given cameras that step
    # was 3 of 4 right until stop 43's QUIET_LEVEL, 4 now; with estimated ones 2 before and after)
    assert right >= right_given - 5, (right, right_given, total)


def test_blank_and_noise_pictures_fail_their_step_and_the_plan_goes_on(
    manuals: Path, tmp_path: Path
):
    src = sorted(manuals.iterdir())[1]
    dst = tmp_path / src.name
    shutil.copytree(src, dst)
    man = load_manual(dst)
    steps = man.main.steps
    assert len(steps) >= 5
    size = man.image_size
    Image.new("RGB", size, (250, 250, 250)).save(steps[1].image_path)
    rng = np.random.default_rng(0)
    noise = rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
    Image.fromarray(noise).save(steps[2].image_path)
    run = run_manual(drop_cameras(load_manual(dst)), make_predictor("synthesis"))
    main = run.main
    for k in (1, 2):
        s = main.steps[k]
        assert s.camera is not None and s.camera.camera is None
        assert s.camera.failure and s.camera.failure.startswith("camera could not be estimated")
        assert all(p.failure == s.camera.failure for p in s.predictions)
        assert not any(s.placed)
    assert main.steps[0].camera.camera is not None  # type: ignore[union-attr]
    # the plan goes on: a later step is estimated again
    assert any(s.camera.camera is not None for s in main.steps[3:])  # type: ignore[union-attr]


def test_blank_picture_fails_a_first_step(manuals: Path, tmp_path: Path):
    man = load_manual(sorted(manuals.iterdir())[0])
    blank = tmp_path / "blank.png"
    Image.new("RGB", man.image_size, (255, 255, 255)).save(blank)
    step = man.main.steps[0]
    import dataclasses

    est = next(
        BuildCameras(man.image_size).hypotheses(
            dataclasses.replace(step, image_path=blank, camera=None),
            _bg.Assembly(),
            man.primitive_components(),
            False,
        )
    )
    assert est.camera is None and est.failure is not None and "blank" in est.failure


def test_infer_on_a_manual_without_cameras_writes_the_cameras_it_used(
    manuals: Path, tmp_path: Path
):
    src = sorted(manuals.iterdir())[1]  # (the other loses its step 2: a hidden base)
    stripped = tmp_path / "stripped"
    r = subprocess.run(
        [sys.executable, "-m", "mepnet.manual", "strip", str(src), "--out", str(stripped)]
        + ["--no-cameras"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    assert all(
        "camera" not in s for s in json.loads((stripped / "manual.json").read_text())["steps"]
    )
    out = tmp_path / "plan"
    r = subprocess.run(
        [sys.executable, "-m", "mepnet.infer", str(stripped), "--out", str(out)]
        + ["--predictor", "synthesis", "--no-progress"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    plan = json.loads((out / "plan.json").read_text())
    steps = plan["steps"] + [s for sub in plan["submodules"] for s in sub["steps"]]
    for s in steps:
        assert s["camera_source"] == "estimated"
        assert (s["camera"] is None) == ("camera_failure" in s)
        if s["camera"] is not None:
            assert set(s["camera"]) == {"elevation", "azimuth", "roll", "scale", "translation"}
            assert 0.0 <= s["camera_fit"] <= 1.0
    assert sum(s["camera"] is not None for s in steps) >= 0.9 * len(steps)
    assert plan["placed"] >= 0.9 * plan["components"]
    # the same plan as with the manual's cameras, up to the frame (compared in Python)
    man = load_manual(src)
    given = run_manual(man, make_predictor("synthesis"))
    estimated = run_manual(drop_cameras(man), make_predictor("synthesis"))
    rg, total = accuracy(given)
    re, _ = accuracy(estimated)
    assert re >= rg - 1, (re, rg, total)


def test_eval_with_estimated_cameras_reports_camera_errors(manuals: Path, tmp_path: Path):
    one = sorted(manuals.iterdir())[0]
    out = tmp_path / "m.json"
    r = subprocess.run(
        [sys.executable, "-m", "mepnet.eval", "--no-progress", "--data", str(one)]
        + ["--predictor", "oracle", "--camera", "estimated", "--autoregressive"]
        + ["--cd-points", "500", "--json", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    assert "estimated from the pictures" in r.stdout and "frame" in r.stdout
    m = json.loads(out.read_text())
    assert m["camera"] == "estimated"
    for key in (
        "camera_rotation_deg_median",
        "camera_reprojection_px_median",
        "camera_reprojection_px_mean",
        "camera_first_reprojection_px_median",
        "camera_seconds_per_step",
        "camera_failures",
    ):
        assert key in m
    assert m["camera_steps"] == m["n_steps"] and m["camera_failures"] <= 1
    assert m["camera_reprojection_px_median"] < 2.0
    # the steps whose camera is off, each with its error, or None where none was estimated
    (pm,) = m["per_manual"]
    off = pm["camera_off"]
    assert all(v is None or (len(v) == 2 and v[1] > 1.0) for v in off.values()), off
    assert m["camera_failures"] == sum(v is None for v in off.values())
    # steps the picture cannot tell without its camera: wrong steps, counted apart
    undecidable = set(pm["camera_undecidable"])
    assert undecidable <= set(pm["wrong"]) - set(pm["undetermined"])
    assert (m["camera_undecidable_components"] > 0) == bool(undecidable)
    bad = subprocess.run(
        [sys.executable, "-m", "mepnet.eval", "--data", str(one), "--predictor", "oracle"]
        + ["--camera", "guessed"],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1


# ---------------------------------------------------------------------------------------------
# Frames


def test_motions_compose_invert_and_move_cameras():
    m = Motion(1, (3, 2, -5))
    assert m.inverse().after(m).is_identity and m.after(m.inverse()).is_identity
    yaw, t = m.apply(2, (5, 1, 7))
    assert m.inverse().apply(yaw, t) == (2, (5, 1, 7))
    cam = _bg.Camera(27.0, 300.0, 3.0, 0.02, (0.1, -0.2))
    pts = np.array([[10.0, 8.0, 30.0], [-40.0, 16.0, 0.0], [0.0, 0.0, 0.0]])
    shifted = np.array([rotate_ldu(p, 1) + np.array([30.0, 16.0, -50.0]) for p in pts])
    a, _ = cam.project(pts, 256, 256)
    b, _ = moved_camera(cam, m).project(shifted, 256, 256)
    assert np.abs(a - b).max() < 1e-9


def test_symmetries_and_candidate_motions():
    brick = _bg.Component.primitive("3001")
    square = _bg.Component.primitive("3003")
    slope = _bg.Component.primitive("3039")
    assert [m.turn for m in symmetries([(brick, 0, (0, 3, 0), 4)])] == [2]
    assert [m.turn for m in symmetries([(square, 0, (0, 3, 0), 4)])] == [1, 2, 3]
    assert symmetries([(slope, 0, (0, 3, 0), 4)]) == []
    pred, true = [(slope, 0, (0, 3, 0), 4)], [(slope, 1, (4, 3, 4), 4)]
    found = [m for m in candidate_motions(pred, true) if matches(pred, true, m) == 1]
    assert found == [Motion(1, (4, 0, 4))]
    assert matches(pred, true) == 0
    assert moved(pred[0], found[0])[1:3] == (1, (4, 3, 4))


# ---------------------------------------------------------------------------------------------
# Binding


def test_binding_types_and_bad_input():
    rgb = np.full((80, 100, 3), 255, np.uint8)
    rgb[20:60, 20:80] = (200, 30, 30)
    fg, bg = _bg.foreground_mask(rgb)
    assert fg.dtype == np.bool_ and fg.shape == (80, 100) and bg == (255, 255, 255)
    assert fg.sum() == 40 * 60
    hist = _bg.edge_directions(rgb)
    assert hist.shape == (360,) and math.isclose(float(hist.sum()), 1.0, rel_tol=1e-6)
    # horizontal and vertical edges: directions near 0 (180) and 90 degrees, 3:2 by length
    near_0, near_90 = hist[[0, 1, 358, 359]].sum(), hist[178:182].sum()
    assert near_0 + near_90 > 0.8 and 1.2 < near_0 / near_90 < 2.2, (near_0, near_90)
    with pytest.raises(ValueError, match="H, W, 3"):
        _bg.foreground_mask(np.zeros((4, 4, 4), np.uint8))
    pic = _bg.FitPicture(rgb)
    assert pic.size == (100, 80)
    asm = _bg.Assembly()
    asm.add(_bg.Component.primitive("3001"), 0, (0, 3, 0))
    cam = _bg.Camera(30.0, 315.0, 0.0, 0.02, (0.0, 0.0))
    with pytest.raises(ValueError, match="foreground mask has shape"):
        _bg.fit_camera(asm, pic, np.zeros((3, 3), bool), cam)
    with pytest.raises(_bg.BrickGeomError, match="empty shape"):
        _bg.fit_camera(_bg.Assembly(), pic, fg, cam)
    with pytest.raises(_bg.BrickGeomError, match="levels"):
        _bg.fit_camera(asm, pic, fg, cam, levels=[])
    fit = _bg.fit_camera(asm, pic, fg, cam, levels=[0], iterations=0)
    assert isinstance(fit, _bg.CameraFit) and isinstance(fit.camera, _bg.Camera)
    assert 0.0 <= fit.agree <= 1.0 and 0.0 <= fit.iou <= 1.0 and fit.samples > 0
    sil = _bg.box_silhouette(asm, cam, 100, 80)
    assert sil.dtype == np.bool_ and sil.shape == (80, 100) and sil.any()
    ranked = _bg.search_placements(asm, _bg.Component.primitive("3003"), fg, [(30.0, 315.0, 0.0)])
    assert ranked and all(0.0 <= r[0] <= 1.0 for r in ranked)
    assert ranked == sorted(ranked, key=lambda r: -r[0])


def test_a_base_hidden_by_the_new_part_keeps_the_previous_view(tmp_path: Path):
    """A slope almost wholly hidden behind the brick put in front of it (only its top shows):
    the base alone fits nowhere, and the brick set another way from a view turned a quarter
    explains the picture nearly as well. Camera and placement searched together find the view
    the previous step was drawn from (manuals mostly only zoom and pan), within a degree."""
    from mepnet.cameras import CameraEstimate, rotation_error
    from mepnet.manual.page import ComponentRef, StepComponent

    slope, grille = ComponentRef("3040b", None), ComponentRef("2877", None)
    comps = {r: _bg.Component.primitive(r.part) for r in (slope, grille)}
    base = _bg.Assembly()
    base.add(comps[slope], 2, (4, 3, -1), 73)
    whole = base.copy()
    whole.add(comps[grille], 2, (1, 3, -2), 28)
    cams = [
        _bg.Camera(23.67, 315.58, 0.0, 0.0284, (-0.586, -0.850)),
        _bg.Camera(23.67, 315.58, 0.0, 0.0253, (0.069, -0.572)),
    ]
    steps = [
        _drawn_step(tmp_path, 1, base, cams[0], [StepComponent(slope, 1, 73)]),
        _drawn_step(tmp_path, 2, whole, cams[1], [StepComponent(grille, 1, 28)]),
    ]
    est = BuildCameras((256, 256))
    given = CameraEstimate(cams[0], "given")
    est.accept(steps[0], given, None, base)
    first = next(iter(est.hypotheses(steps[1], base, comps, teacher_forced=False)))
    assert first.camera is not None
    assert rotation_error(first.camera, cams[1]) < 1.0, (first.how, first.camera)


def test_a_symmetric_base_does_not_fill_the_joint_shortlist_with_turned_copies(tmp_path: Path):
    """A 2x2 corner plate on a 2x2 brick: the brick looks the same from four views, so each
    placement seen from each view is the same whole turned. Counted once, the true placement
    makes the shortlist and is fitted: the view (up to the brick's quarter turns) within a
    degree and the zoom within 2% (the four copies crowded it out: 2 degrees, 11% small)."""
    from mepnet.manual.page import ComponentRef, Step, StepComponent

    brick, corner = ComponentRef("3003", None), ComponentRef("2420", None)
    comps = {r: _bg.Component.primitive(r.part) for r in (brick, corner)}
    base = _bg.Assembly()
    base.add(comps[brick], 0, (2, 3, 0), 1)
    whole = base.copy()
    whole.add(comps[corner], 1, (2, 4, 1), 4)
    cam = _bg.Camera(22.67, 307.57, 0.0, 0.02709, (-0.171, -0.476))
    path = tmp_path / "step_2.png"
    Image.fromarray(_bg.render(whole, cam, 256, 256).rgb).save(path)
    step = Step(2, path, None, [StepComponent(corner, 1, 4)], (256, 256))
    est = BuildCameras((256, 256))
    fits = est._joint(step, base, comps, est.picture(step), None)
    assert fits
    got = fits[0][0].camera
    assert _turned_error(got, cam) < 1.0, got
    assert abs(got.scale / cam.scale - 1.0) < 0.02, got


def test_edge_orientation_is_not_pulled_by_upright_edges():
    """A round brick under a corner plate, a 1x1 tile and a 1x3 tile: the brick's upright
    sides are the strongest straight edges of the drawing, yet they are the y axis from every
    view (roll 0). The plates' edges give the view within 2 degrees (counted, the upright
    edges made it 5 degrees of elevation and a front view, 14 and 35 degrees off)."""
    from mepnet.cameras import edge_orientation

    asm = _bg.Assembly()
    for part, yaw, t, colour in [
        ("3941", 1, (1, 3, 0), 2),
        ("2420", 2, (2, 4, -1), 14),
        ("3070", 3, (0, 4, 1), 71),
        ("63864", 0, (0, 5, -1), 2),
    ]:
        asm.add(_bg.Component.primitive(part), yaw, t, colour)
    cam = _bg.Camera(18.86, 305.14, 0.0, 0.0199, (0.262, -0.422))
    el, az = edge_orientation(_bg.render(asm, cam, 256, 256).rgb)
    assert abs(el - cam.elevation) < 2.0, (el, az)
    assert abs((az - cam.azimuth + 45.0) % 90.0 - 45.0) < 2.0, (el, az)


def test_the_joint_search_places_two_components_over_a_hidden_base(tmp_path: Path):
    """A 1x2 plate half under a 2x2 tile, a corner panel hanging under the tile, zoomed out
    2.3 times from the previous picture: the plate alone fits nowhere. Camera and both
    placements searched together (the panel can only be placed once the tile is) find the
    view within a degree and the zoom within 2% (one component only: no camera at all)."""
    from mepnet.cameras import rotation_error
    from mepnet.manual.page import ComponentRef, Step, StepComponent

    plate, tile, panel = (ComponentRef(p, None) for p in ("3023", "3068b", "6231"))
    comps = {r: _bg.Component.primitive(r.part) for r in (plate, tile, panel)}
    base = _bg.Assembly()
    base.add(comps[plate], 3, (1, 1, -6), 25)
    whole = base.copy()
    whole.add(comps[tile], 1, (0, 2, -4), 1)
    whole.add(comps[panel], 1, (0, 3, -1), 28)
    cam = _bg.Camera(32.88, 40.42, 0.0, 0.01527, (-0.191, -0.237))
    path = tmp_path / "step_2.png"
    Image.fromarray(_bg.render(whole, cam, 256, 256).rgb).save(path)
    step = Step(2, path, None, [StepComponent(tile, 1, 1), StepComponent(panel, 1, 28)], (256, 256))
    est = BuildCameras((256, 256))
    anchor = _bg.Camera(32.88, 40.42, 0.0, 0.03541, (-1.527, -0.947))
    fits = est._joint(step, base, comps, est.picture(step), anchor)
    assert fits
    got = fits[0][0].camera
    assert rotation_error(got, cam) < 1.0, got
    assert abs(got.scale / cam.scale - 1.0) < 0.02, got


def test_the_scale_sweep_finds_a_shape_built_far_from_the_origin(tmp_path: Path):
    """A 2x3 brick on a round plate, built 60 LDU from the world origin and drawn large: the
    sweep's reference, resampled at each scale, is centred on the shape, not on the origin
    (centred on the origin it was cut off at the larger scales, and the best start was 27%
    small: the fit from it explained half the picture). The best start's zoom within 3%, its
    fit within a pixel of the truth."""
    from mepnet.cameras import reprojection_error
    from mepnet.geom import bounds_corners

    plate, brick = _bg.Component.primitive("4032a"), _bg.Component.primitive("3002")
    whole = _bg.Assembly()
    whole.add(plate, 3, (4, 1, -7), 71)
    whole.add(brick, 1, (4, 4, -6), 0)
    cam = _bg.Camera(30.12, 310.85, 0.0, 0.0218, (0.393, -0.938))
    path = tmp_path / "step.png"
    Image.fromarray(_bg.render(whole, cam, 256, 256).rgb).save(path)
    from mepnet.manual.page import Step

    est = BuildCameras((256, 256))
    pic = est.picture(Step(2, path, None, [], (256, 256)))
    # the previous step's view, zoomed in 1.2 times
    start = _bg.Camera(cam.elevation, cam.azimuth, 0.0, 1.2 * cam.scale, (0.0, 0.0))
    found = est._sweep_scored(whole, pic, start, wide=False)
    assert found
    best = found[0][1]
    assert abs(best.scale / cam.scale - 1.0) < 0.03, best
    fit = est._fit(whole, pic, best, (4, 1, 0))
    corners = np.asarray(bounds_corners(whole), dtype=np.float64)
    assert reprojection_error(fit.camera, cam, corners, (256, 256)) < 1.0, fit.camera


def test_the_usual_zoom_is_the_previous_steps_not_the_framed_shapes(tmp_path: Path):
    """A 2x8 plate with a brick and a plate on it, drawn small (the shape spans a third of the
    picture) after a step drawn 1.5 times larger. The narrow sweep looks within the usual zoom
    of the previous step's scale; it looked within the usual zoom of the shape framed to fill
    the picture, which a shape this small lies outside of, and started 20% too small (U20
    manual 4, step 2). The first start's zoom within 8% of the truth, its fit within a pixel."""
    from mepnet.cameras import reprojection_error
    from mepnet.geom import bounds_corners
    from mepnet.manual.page import Step

    plate, brick, small = (_bg.Component.primitive(p) for p in ("3034", "3001", "3710"))
    base = _bg.Assembly()
    base.add(plate, 0, (0, 1, 0), 288)
    whole = base.copy()
    whole.add(brick, 0, (-4, 4, 0), 0)
    whole.add(small, 1, (6, 2, 0), 4)
    cam = _bg.Camera(27.5, 53.7, 0.0, 0.0056, (0.19, 0.13))
    path = tmp_path / "step.png"
    Image.fromarray(_bg.render(whole, cam, 256, 256).rgb).save(path)
    est = BuildCameras((256, 256))
    pic = est.picture(Step(2, path, None, [], (256, 256)))
    prev = _bg.Camera(27.5, 53.7, 0.0, 1.5 * cam.scale, (0.0, 0.0))
    start = est._sweep(base, pic, prev, wide=False)[0]
    assert abs(start.scale / cam.scale - 1.0) < 0.08, (start, cam)
    fit = est._fit_inside(base, pic, start)
    corners = np.asarray(bounds_corners(base), dtype=np.float64)
    assert reprojection_error(fit.camera, cam, corners, (256, 256)) < 1.0, fit.camera


def test_two_bricks_standing_apart_from_the_base_keep_the_carried_view(tmp_path: Path):
    """Two 1x3 bricks stacked on the ground beside a slope on a plate, zoomed out 2.4 times:
    the joint search (which only places parts on the base) explains the picture roughly
    (78% of pixels) with the bricks elsewhere. Such rough wholes come after the base's own
    fits, so the first camera tried is the carried view at the right zoom (they came first
    and used up every hypothesis: zoom 4-7% off, the bricks misplaced)."""
    from mepnet.cameras import CameraEstimate, rotation_error
    from mepnet.manual.page import ComponentRef, StepComponent

    plate, slope, brick = (ComponentRef(p, None) for p in ("3623", "60481", "3622"))
    comps = {r: _bg.Component.primitive(r.part) for r in (plate, slope, brick)}
    base = _bg.Assembly()
    base.add(comps[plate], 0, (2, 1, 3), 72)
    base.add(comps[slope], 0, (0, 7, 1), 19)
    whole = base.copy()
    whole.add(comps[brick], 0, (-1, 3, 8), 320)
    whole.add(comps[brick], 0, (-1, 6, 8), 320)
    cams = [
        _bg.Camera(31.53, 310.26, 0.0, 0.018949, (-0.4710, -0.3821)),
        _bg.Camera(31.53, 310.26, 0.0, 0.0078697, (0.0162, -0.2447)),
    ]
    steps = [
        _drawn_step(tmp_path, 2, base, cams[0], [StepComponent(slope, 1, 19)]),
        _drawn_step(tmp_path, 3, whole, cams[1], [StepComponent(brick, 2, 320)]),
    ]
    est = BuildCameras((256, 256))
    est.accept(steps[0], CameraEstimate(cams[0], "given"), None, base)
    first = next(iter(est.hypotheses(steps[1], base, comps, teacher_forced=False)))
    assert first.camera is not None
    assert first.how == "carried", first.how
    assert rotation_error(first.camera, cams[1]) < 1.0, first.camera
    assert abs(first.camera.scale / cams[1].scale - 1.0) < 0.02, first.camera


def test_a_white_brick_on_a_white_page_is_foreground_and_ranked_by_its_silhouette(tmp_path: Path):
    """A white 2x3 brick on an inverted slope, drawn on a white page: the brick's top face (22
    below the page per channel) is part of the drawing (left out at a threshold of 30, so the
    drawing's box was the brick's sides only). The joint search's shortlist, ranked by the
    rendered wholes' silhouettes, has the true placement among its first three (ranked by
    boxes, which draw the slope as its whole bounding box, it was 22nd at the true view and
    fell out of the shortlist)."""
    from mepnet.manual.page import ComponentRef, Step, StepComponent

    slope, brick = ComponentRef("3665", None), ComponentRef("3002", None)
    comps = {r: _bg.Component.primitive(r.part) for r in (slope, brick)}
    base = _bg.Assembly()
    base.add(comps[slope], 3, (2, 3, -1), 5)
    whole = base.copy()
    whole.add(comps[brick], 0, (0, 6, 0), 15)
    cam = _bg.Camera(23.46, 309.38, 0.0, 0.0171, (0.120, -0.332))
    render = _bg.render(whole, cam, 256, 256)
    path = tmp_path / "step_2.png"
    Image.fromarray(render.rgb).save(path)
    step = Step(2, path, None, [StepComponent(brick, 1, 15)], (256, 256))
    est = BuildCameras((256, 256))
    pic = est.picture(step)
    true = render.ids >= 0
    assert (pic.fg & true).sum() / (pic.fg | true).sum() > 0.98
    view = (cam.elevation, cam.azimuth, 0.0)
    short = est._joint_short(base, comps[brick], pic, {view}, None, [], 36)
    top = [(yaw, t) for yaw, t, _ in short[:3]]
    assert any(comps[brick].same_placement(y, t, 0, (0, 6, 0)) for y, t in top), top


def test_the_joint_search_turns_the_view_over_a_round_base(tmp_path: Path):
    """A white 1x2x5 brick on a round 2x2 tile: the tile's azimuth is free, so the first step's
    camera (the convention's) is 26 degrees off the page's, and the picture's edges (a white
    part on a white page) give no view either. The joint search also looks from the anchor's
    elevation turned both ways and finds the view within a degree (it searched the anchor's
    and the edges' views only: no camera, the placement a stud off)."""
    from mepnet.manual.page import ComponentRef, Step, StepComponent

    tile, brick = ComponentRef("4150", None), ComponentRef("22886", None)
    comps = {r: _bg.Component.primitive(r.part) for r in (tile, brick)}
    base = _bg.Assembly()
    base.add(comps[tile], 2, (1, 1, 1), 0)
    whole = base.copy()
    whole.add(comps[brick], 1, (-2, 9, 1), 15)
    cam = _bg.Camera(27.13, 324.33, 0.0, 0.0170, (-0.218, -0.511))
    path = tmp_path / "step_2.png"
    Image.fromarray(_bg.render(whole, cam, 256, 256).rgb).save(path)
    step = Step(2, path, None, [StepComponent(brick, 1, 15)], (256, 256))
    est = BuildCameras((256, 256))
    anchor = _bg.Camera(27.10, -10.41, 0.0, 0.0225, (0.5, -0.1))
    fits = est._joint(step, base, comps, est.picture(step), anchor)
    assert fits
    got = fits[0][0].camera
    assert _turned_error(got, cam) < 1.0, got
    assert abs(got.scale / cam.scale - 1.0) < 0.02, got


def test_a_round_first_part_is_seen_from_its_elevation(tmp_path: Path):
    """A round 2x2 brick alone (a build's first step): its box silhouette is a square block's,
    which ranked a 12.5-degree view first (fitted to 8 degrees, the plan built on it wrong).
    Ranked by its rendered silhouette, the search finds the page's 26 degrees of elevation (a
    round part fixes no azimuth: that is the frame convention's)."""
    from mepnet.manual.page import ComponentRef, StepComponent

    ref = ComponentRef("3941", None)
    comps = {ref: _bg.Component.primitive(ref.part)}
    shape = _bg.Assembly()
    shape.add(comps[ref], 0, (0, 3, -1), 72)
    cam = _bg.Camera(25.79, 37.64, 0.0, 0.0269, (-0.129, -0.571))
    step = _drawn_step(tmp_path, 1, shape, cam, [StepComponent(ref, 1, 72)])
    got = next(BuildCameras((256, 256))._first(step, comps)).camera
    assert got is not None
    assert abs(got.elevation - cam.elevation) < 1.5, got
    assert abs(got.scale / cam.scale - 1.0) < 0.03, got


def test_a_first_step_of_three_parts_finds_the_view_of_its_largest(tmp_path: Path):
    """A first step adding a 1x2 grille brick, a corner plate and a 1x1 brick that hides part
    of the grille brick: the grille brick's scale sweep, started from the picture's edges with
    no previous scale to prefer, takes its best-scored start (the first start, nearest a
    previous scale that does not exist, was 22% too large and nothing fitted: the step was
    predicted from the convention's prior view, wrong). The camera is the page's up to a
    quarter turn."""
    from mepnet.manual.page import ComponentRef, StepComponent

    refs = [ComponentRef(p, None) for p in ("2877", "2420", "87087")]
    comps = {r: _bg.Component.primitive(r.part) for r in refs}
    shape = _bg.Assembly()
    colours = (14, 73, 4)
    for r, yaw, t, colour in zip(
        refs, (0, 1, 2), ((-1, 3, -1), (2, 1, 3), (0, 3, 1)), colours, strict=True
    ):
        shape.add(comps[r], yaw, t, colour)
    cam = _bg.Camera(23.34, 324.43, 0.0, 0.01814, (0.0329, -0.0334))
    entries = [StepComponent(r, 1, c) for r, c in zip(refs, colours, strict=True)]
    got = next(
        BuildCameras((256, 256))._first(_drawn_step(tmp_path, 1, shape, cam, entries), comps)
    ).camera
    assert got is not None
    assert _turned_error(got, cam) < 1.5, got
    assert abs(got.scale / cam.scale - 1.0) < 0.03, got


def test_a_first_step_tries_its_other_parts_when_the_largest_misleads(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """A first step adding a 1x3 brick and a round 2x2 brick (equal volume: the brick, listed
    first, is searched first). The 1x3 brick fits a 12.5-degree view as well as the page's 25,
    and the step predicted from it explains a fifth of the picture: the step failed (U20 manual
    7; the next steps were built on nothing). The round brick's own fit is the next hypothesis,
    and the plan loop keeps the camera that explains the step."""
    import mepnet.cameras as cameras_module
    from mepnet.manual.page import ComponentRef, StepComponent
    from mepnet.plan import _estimated_camera_step
    from mepnet.stage2.base import StepContext, predict_step

    # the squared-colour sweep (before the colour kernel) is what misled here; the kernel's
    # finds the page's view from the 1x3 brick, so the mechanism is tested with the old one
    monkeypatch.setattr(cameras_module, "SWEEP_KERNEL", False)
    refs = [ComponentRef(p, None) for p in ("3622", "3941")]
    colours = (272, 15)
    comps = {r: _bg.Component.primitive(r.part) for r in refs}
    shape = _bg.Assembly()
    for r, yaw, t, colour in zip(refs, (1, 0), ((-2, 3, 2), (1, 3, 3)), colours, strict=True):
        shape.add(comps[r], yaw, t, colour)
    cam = _bg.Camera(25.07, 49.7, 0.0, 0.02074, (0.2509, -0.0778))
    entries = [StepComponent(r, 1, c) for r, c in zip(refs, colours, strict=True)]
    step = _drawn_step(tmp_path, 1, shape, cam, entries)
    cameras = BuildCameras((256, 256))
    views = []
    for est in cameras.hypotheses(step, _bg.Assembly(), comps, False):
        views.append(est.camera)
        # its own making (a search: under a second), not the caller's pause before it
        assert est.seconds < 3.0
        if len(views) == 1:
            time.sleep(3.0)
    assert len(views) >= 2
    assert abs(views[0].elevation - cam.elevation) > 5  # the largest part's best fit misleads
    synthesis = make_predictor("synthesis")

    def predict(page: object) -> tuple[list[object], float]:
        return predict_step(
            synthesis, StepContext(page, _bg.Assembly(), comps, (256, 256), ()), None
        )

    preds, _, est = _estimated_camera_step(cameras, predict, step, _bg.Assembly(), comps, False)
    assert est.failure is None and est.camera is not None
    assert _turned_error(est.camera, cam) < 1.0, est.camera
    assert abs(est.camera.scale / cam.scale - 1.0) < 0.02, est.camera
    assert all(p.placed for p in preds)
    # with no time for a second hypothesis the misleading one is all there is: the step fails
    import mepnet.plan

    monkeypatch.setattr(mepnet.plan, "HYPOTHESES_BUDGET_S", 0.0)
    cameras = BuildCameras((256, 256))
    _, _, est = _estimated_camera_step(cameras, predict, step, _bg.Assembly(), comps, False)
    assert est.failure is not None


def test_the_scale_sweep_keeps_a_hidden_dark_base_on_the_picture(tmp_path: Path):
    """A dark red 1x1 plate all but hidden by the grey brick put on it, beside a tan plate: its
    colours match the picture almost nowhere, so every placement on the picture scores below
    zero. Beyond the picture counted as a black page that costs nothing, the sweep put the base
    there (360 pixels off); beyond the picture is page now, and every start lies on it."""
    from mepnet.manual.page import ComponentRef, Step, StepComponent

    refs = [ComponentRef(p, None) for p in ("3024", "3021", "3005")]
    comps = {r: _bg.Component.primitive(r.part) for r in refs}
    base = _bg.Assembly()
    base.add(comps[refs[0]], 2, (-8, 1, -1), 320)
    whole = base.copy()
    whole.add(comps[refs[1]], 0, (-5, 1, 2), 19)
    whole.add(comps[refs[2]], 0, (-8, 4, -1), 71)
    prev = _bg.Camera(17.15, 48.05, 0.0, 0.05505, (2.5277, -1.1485))
    cam = _bg.Camera(17.15, 48.05, 0.0, 0.01540, (0.8776, -0.4639))
    path = tmp_path / "step_2.png"
    Image.fromarray(_bg.render(whole, cam, 256, 256).rgb).save(path)
    step = Step(
        2,
        path,
        None,
        [StepComponent(r, 1, c) for r, c in zip(refs[1:], (19, 71), strict=True)],
        (256, 256),
    )
    est = BuildCameras((256, 256))
    starts = est._sweep(base, est.picture(step), prev, wide=False)
    assert starts
    centre = np.asarray(bounds_corners(base), dtype=float).mean(axis=0)
    px, _ = cam.project(centre[None], 256, 256)
    assert 0 <= px[0, 0] < 256 and 0 <= px[0, 1] < 256  # where the picture shows it
    for start in starts:
        px, _ = start.project(centre[None], 256, 256)
        assert 0 <= px[0, 0] < 256 and 0 <= px[0, 1] < 256, start


def test_a_hidden_tiny_base_is_not_explained_by_the_previous_zoom(tmp_path: Path):
    """A 2x2 tile put on a 1x1 plate, the view zoomed out 1.7 times: the plate is wholly
    hidden. The carried view at the old zoom, with the tile set beside the plate, explains the
    picture passably (84% of pixels agree), which used to end the search; the tile and the
    camera searched together explain it fully, at the true zoom. Only a check that leaves
    little doubt ends the search now."""
    from mepnet.cameras import CameraEstimate, rotation_error
    from mepnet.manual.page import ComponentRef, Step, StepComponent
    from mepnet.plan import StepContext, _estimated_camera_step, predict_step

    plate, tile = ComponentRef("3024", None), ComponentRef("3068b", None)
    comps = {r: _bg.Component.primitive(r.part) for r in (plate, tile)}
    base = _bg.Assembly()
    base.add(comps[plate], 1, (-1, 1, 0), 72)
    whole = base.copy()
    whole.add(comps[tile], 3, (-1, 2, 0), 0)
    cams = [
        _bg.Camera(35.896, 313.725, 0.0, 0.049569, (0.25844, 0.17105)),
        _bg.Camera(35.896, 313.725, 0.0, 0.029848, (0.29306, -0.06087)),
    ]
    steps = [
        _drawn_step(tmp_path, 1, base, cams[0], [StepComponent(plate, 1, 72)]),
        _drawn_step(tmp_path, 2, whole, cams[1], [StepComponent(tile, 1, 0)]),
    ]
    est = BuildCameras((256, 256))
    est.accept(steps[0], CameraEstimate(cams[0], "given"), None, base)
    synthesis = make_predictor("synthesis")

    def predict(page: Step) -> tuple[list[object], float]:
        return predict_step(synthesis, StepContext(page, base.copy(), comps, (256, 256), ()), None)

    preds, _, got = _estimated_camera_step(est, predict, steps[1], base, comps, False)
    assert got.camera is not None
    assert rotation_error(got.camera, cams[1]) < 1.0, got
    assert abs(got.camera.scale / cams[1].scale - 1.0) < 0.03, (got.how, got.camera)
    # the plate is hidden: the tile's corner over it is free, the tile covers it
    (p,) = preds
    assert p.placed and p.failure is None
    shape = base.copy()
    shape.add(comps[tile], p.yaw, p.t, 0)
    rendered = _bg.render(shape, got.camera, 256, 256).rgb
    drawn = np.asarray(Image.open(steps[1].image_path).convert("RGB"))
    assert np.mean(np.abs(rendered.astype(int) - drawn.astype(int)).max(axis=2) > 40) < 0.01


def test_a_step_whose_picture_cannot_fix_the_camera_is_counted_undecidable():
    """A 1x1 plate wholly hidden under a 2x2 tile: the tile half a stud further along, drawn
    with the camera panned by as much, gives the same picture (`undecidable`, reported
    beside the strict figure); drawn with the manual's camera it does not."""
    from types import SimpleNamespace as NS

    from mepnet.eval import undecidable

    plate, tile = _bg.Component.primitive("3024"), _bg.Component.primitive("3068b")
    cam = _bg.Camera(35.896, 313.725, 0.0, 0.029848, (0.29306, -0.06087))
    truth = [[(plate, 1, (-1, 1, 0), 72)], [(tile, 3, (-1, 2, 0), 0)]]
    shift = np.array([-1, 0, 0])
    px, _ = cam.project(np.array([[0.0, 0.0, 0.0], shift * [10.0, 8.0, 10.0]]), 256, 256)
    dx, dy = px[0] - px[1]
    panned = _bg.Camera(
        cam.elevation,
        cam.azimuth,
        0.0,
        cam.scale,
        (cam.translation[0] + dx * 2 / 256, cam.translation[1] - dy * 2 / 256),
    )
    man = NS(
        image_size=(256, 256), main=NS(steps=[None, NS(camera=cam, camera_object=lambda: cam)])
    )
    b = NS(key=None, build=NS(steps=[None, NS(components=[NS(colour=0)])]))
    run = NS(components={"tile": tile})
    guess = NS(placed=True, component="tile", yaw=3, t=(-2, 2, 0), entry=0)

    def step(camera: _bg.Camera) -> NS:
        return NS(index=2, camera=NS(camera=camera, source="estimated"), predictions=[guess])

    assert undecidable(man, run, b, step(panned), truth)
    assert not undecidable(man, run, b, step(cam), truth)


def test_a_picture_lit_another_way_is_explained_by_the_true_camera():
    """Another instruction tool lights the faces of each axis its own way (LeoCAD draws the faces
    mepnet darkens most at 1.6 times mepnet's brightness): a per-channel tone cannot map that
    onto mepnet's shading, and the true camera and shape then agreed with under 80% of the
    picture, so the plan loop never took the true camera as explaining it. With a shade factor
    per face axis the fit from a start a few pixels off agrees with nearly all of it and lands
    on the true camera (flat faces of one colour show fewer edges: a few tenths of a pixel)."""
    from mepnet.cameras import FIT_LINES, FIT_SAMPLES, reprojection_error

    asm = _bg.Assembly()
    asm.add(_bg.Component.primitive("3001"), 0, (0, 3, 0), 4)
    asm.add(_bg.Component.primitive("3003"), 1, (1, 6, 0), 1)
    asm.add(_bg.Component.primitive("3020"), 0, (-2, 7, 1), 14)
    size = 256
    points = np.asarray(bounds_corners(asm), dtype=np.float64)
    for light, (el, az) in [  # lit alike (flat) or by mepnet's own shading
        ("flat", (27.0, 215.0)),
        ("flat", (20.0, 250.0)),
        ("lambert", (27.0, 215.0)),
    ]:
        cam = _bg.Camera(el, az, 0.0, 1.0, (0.0, 0.0)).fitted(points, 0.7)
        rgb = _bg.render(asm, cam, size, size, style=_bg.RenderStyle(shading=light)).rgb
        fg, _ = _bg.foreground_mask(rgb)
        start = _bg.Camera(
            cam.elevation + 1.0,
            cam.azimuth - 1.5,
            0.0,
            cam.scale * 1.02,
            (cam.translation[0] + 0.02, cam.translation[1] - 0.01),
        )
        fit = _bg.fit_camera(
            asm,
            _bg.FitPicture(rgb),
            fg,
            start,
            levels=[4, 1, 0],
            lines=FIT_LINES,
            samples=FIT_SAMPLES,
        )
        assert fit.agree >= 0.9 and fit.iou >= 0.97, (light, az, fit.agree, fit.iou)
        assert reprojection_error(cam, fit.camera, points, (size, size)) < 0.5, (light, az)


def test_the_scale_sweep_finds_a_base_half_hidden_by_a_new_part(tmp_path: Path):
    """A later step that zooms in 1.26 times and lays a white 1x6 plate and a tan tile over a
    dark red and green base (synthetic manual seed 970007, main step 9). Scored by squared
    colour difference, every base pixel under the white plate cost up to eight times what a
    visible one earned, so the base scored best shrunk to half the size inside its own faces;
    scored by colour likeness, a hidden pixel costs little and the true zoom is the first
    start."""
    from mepnet.manual import load_manual

    data = generate_manuals(tmp_path / "data", 1, 970007)
    man = load_manual(next(p for p in data.iterdir() if p.is_dir()))
    comps = man.answers.components(man)
    steps, ans = man.main.steps, man.answers.main
    prev, step = (
        _bg.Camera(**{**s.camera, "translation": tuple(s.camera["translation"])})
        for s in steps[7:9]
    )
    base = ans.assembly_before(8, comps)
    est = BuildCameras(man.image_size)
    pic = est.picture(steps[8])
    start = est._sweep(base, pic, prev, wide=False)[0]
    assert abs(start.scale / step.scale - 1.0) < 0.1, (start, step)
    fit = est._fit_inside(base, pic, start)
    corners = np.asarray(bounds_corners(base), dtype=float)
    assert reprojection_error(step, fit.camera, corners, man.image_size) < 1.0, fit.camera


def test_wide_outlines_are_taken_off_the_silhouette(tmp_path: Path):
    """Lines four pixels wide centred on the parts' edges (another tool's style) make the
    drawing two pixels larger all round; the stripped drawing's silhouette is the parts' own
    again, and mepnet's own pictures (one-pixel lines inside the parts) are left alone."""
    from mepnet.cameras import outline_stripped
    from mepnet.detector.targets import _grown
    from mepnet.manual.page import ComponentRef

    refs = [ComponentRef(p, None) for p in ("3001", "3022", "3710")]
    comps = {r: _bg.Component.primitive(r.part) for r in refs}
    shape = _bg.Assembly()
    for r, yaw, t, colour in zip(
        refs, (0, 1, 0), ((0, 3, 0), (6, 1, 0), (0, 4, 0)), (4, 14, 1), strict=True
    ):
        shape.add(comps[r], yaw, t, colour)
    cam = _bg.Camera(30.0, 40.0, 0.0, 1.0, (0.0, 0.0)).fitted(
        np.asarray(bounds_corners(shape), dtype=float), 0.8
    )
    r = _bg.render(shape, cam, 256, 256)
    ids = np.asarray(r.ids)
    own = np.ascontiguousarray(r.rgb)
    fg, _ = _bg.foreground_mask(own, 20.0, 16)
    same_rgb, same_fg = outline_stripped(own, fg)
    assert (same_fg == fg).all() and (same_rgb == own).all()

    # the widest of the restyle's thick lines (2 px either side of each edge), opaque
    edge = np.zeros(ids.shape, dtype=bool)
    edge[:, 1:] |= ids[:, 1:] != ids[:, :-1]
    edge[1:, :] |= ids[1:, :] != ids[:-1, :]
    thick = own.astype(np.float32).copy()
    thick[_grown(edge, 2)] = 40.0
    thick = np.ascontiguousarray(thick.clip(0, 255).astype(np.uint8))
    fg_thick, _ = _bg.foreground_mask(thick, 20.0, 16)
    truth = ids >= 0
    assert (fg_thick & ~truth).sum() > 1.5 * (truth & ~np.roll(truth, 1, axis=1)).sum()
    _, stripped = outline_stripped(thick, fg_thick)
    assert (stripped ^ truth).sum() < 0.2 * (fg_thick ^ truth).sum()


def test_a_style_whose_checks_agree_less_explains_its_steps_sooner(tmp_path: Path):
    """Another tool's drawing agrees with mepnet's at most so well (LeoCAD's: median 0.80 with
    the true camera and shape), so the fixed 80% called four in ten of its later steps
    unexplained: every camera hypothesis was predicted with (four predictions a step, and more
    chances to keep a wrong one). Once the manual's checks show its style, a step is explained
    at their median less a margin; a style like mepnet's own keeps the fixed threshold."""
    from types import SimpleNamespace

    from mepnet.cameras import CameraEstimate, PageStyle
    from mepnet.manual.page import ComponentRef, Step, StepComponent
    from mepnet.plan import EXPLAINED_AGREE, STYLE_MARGIN, _estimated_camera_step

    style = PageStyle()
    assert style.explained(EXPLAINED_AGREE, STYLE_MARGIN) == EXPLAINED_AGREE
    style.agrees += [0.81, 0.79]
    assert style.explained(EXPLAINED_AGREE, STYLE_MARGIN) == pytest.approx(0.75)
    assert PageStyle([1.0, 0.99, 1.0]).explained(EXPLAINED_AGREE, STYLE_MARGIN) == EXPLAINED_AGREE

    ref = ComponentRef("3001", None)
    comps = {ref: _bg.Component.primitive(ref.part)}
    base = _bg.Assembly()
    for x in (-8, 0, 8):
        base.add(comps[ref], 0, (x, 3, 0), 4)
    step = Step(2, tmp_path / "step_2.png", None, [StepComponent(ref, 1, 4)], (256, 256))
    cam = _bg.Camera(30.0, 40.0, 0.0, 0.02, (0.0, 0.0))

    class Cameras:  # two hypotheses; every check of a right view agrees 78%
        def __init__(self, style: PageStyle):
            self.style, self.asked = style, 0

        def hypotheses(self, *args: object):
            for how in ("carried", "joint"):
                self.asked += 1
                yield CameraEstimate(cam, "estimated", 0.9, how)

        def check(self, *args: object):
            return SimpleNamespace(iou=0.98, agree=0.78, moved_px=0.0)

        def accept(self, *args: object) -> None:
            pass

    def predict(page: object) -> tuple[list[object], float]:
        return [], 0.0

    for known, asked in ((PageStyle(), 2), (style, 1)):
        cameras = Cameras(known)
        _estimated_camera_step(cameras, predict, step, base, comps, False)  # type: ignore[arg-type]
        assert cameras.asked == asked


def test_a_check_that_explains_the_silhouette_tells_the_style():
    """Only checks that overlap the drawing well (and pass) record the style's agreement."""
    from types import SimpleNamespace

    from mepnet.cameras import STYLE_IOU, CameraEstimate

    cams = BuildCameras((256, 256))
    cam = _bg.Camera(30.0, 40.0, 0.0, 0.02, (0.0, 0.0))
    est = CameraEstimate(cam, "estimated", 0.9, "carried")
    step = object()
    cams.accept(step, est, SimpleNamespace(iou=STYLE_IOU + 0.02, agree=0.8, camera=cam))  # type: ignore[arg-type]
    cams.accept(step, est, SimpleNamespace(iou=STYLE_IOU - 0.05, agree=0.7, camera=cam))  # type: ignore[arg-type]
    cams.accept(step, est, None)  # type: ignore[arg-type]
    assert cams.style.agrees == [0.8]


def test_picture_reductions_match_numpy_reference():
    """The histogram median and the cell sums give what plain numpy gives, exactly."""
    from mepnet.cameras import _median_u8, _reduce

    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 1000, 4001):
        v = rng.integers(0, 256, (n, 3), dtype=np.uint8)
        want = np.median(v.astype(np.float32), axis=0)
        got = _median_u8(v)
        assert got.dtype == want.dtype and np.array_equal(got, want), n
    for shape in ((256, 256, 3), (200, 130, 3), (256, 256), (97, 64)):
        im = rng.integers(0, 256, shape, dtype=np.uint8)
        for x in (im, im > 128):
            h, w = x.shape[:2]
            f = -(-max(h, w) // 64)
            hp, wp = -(-h // f) * f, -(-w // f) * f
            pad = [(0, hp - h), (0, wp - w)] + [(0, 0)] * (x.ndim - 2)
            p = np.pad(x, pad, mode="edge").astype(np.float64)
            want = p.reshape(hp // f, f, wp // f, f, *x.shape[2:]).mean(axis=(1, 3))
            got = _reduce(x, 64)
            assert got.dtype == np.float32 and got.shape == want.shape
            np.testing.assert_allclose(got, want, rtol=1e-6)


def test_outline_stripping_leaves_a_black_page_alone():
    """A drawing on a black page (its median colour 0): nothing to strip, and no division by
    the page's brightness."""
    from mepnet.cameras import outline_stripped

    rgb = np.zeros((64, 64, 3), dtype=np.uint8)
    rgb[16:48, 16:48] = 200
    rgb[16:48, 16:20] = 10
    fg = rgb.max(axis=2) > 0
    out, out_fg = outline_stripped(rgb, fg)
    assert np.array_equal(out, rgb) and np.array_equal(out_fg, fg)


def test_sweep_correlations_match_a_direct_sum():
    """The sweep's batched FFT correlation equals the sum it stands for: at offset (dy, dx),
    the picture's weight under the reference's silhouette plus ``gain`` times its values
    times the reference's, the picture (twice the reference's size) wrapping round."""
    from mepnet.cameras import _correlations, _rfft2

    rng = np.random.default_rng(5)
    h, w, k, gain = 6, 5, 2, 0.7
    weight = rng.normal(size=(2 * h, 2 * w)).astype(np.float32)
    values = rng.normal(size=(k, 2 * h, 2 * w)).astype(np.float32)
    planes = rng.normal(size=(3, 1 + k, h, w)).astype(np.float32)
    spectra = _rfft2(np.concatenate([weight[None], values]))
    got = _correlations(planes, spectra[0], spectra[1:], gain)
    assert got.shape == (3, 2 * h, 2 * w)
    for s in range(3):
        ref = np.zeros((1 + k, 2 * h, 2 * w), np.float64)
        ref[:, :h, :w] = planes[s]
        for dy, dx in ((0, 0), (1, 3), (2 * h - 1, 2), (4, 2 * w - 1)):
            moved = np.roll(np.concatenate([weight[None], values]), (-dy, -dx), axis=(1, 2))
            want = (moved[0] * ref[0]).sum() + gain * (moved[1:] * ref[1:]).sum()
            assert got[s, dy, dx] == pytest.approx(want, abs=1e-4)
