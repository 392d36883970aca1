"""mepnet.consistency: per-step confidence and flags, and earlier placements that later pictures
contradict, re-placed."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import generate_manuals
from mepnet import _brickgeom as _bg
from mepnet.consistency import (
    Placement,
    View,
    build,
    check_step,
    disagreement,
    repair,
)
from mepnet.manual import answers_of, iter_manual_dirs, load_manual
from mepnet.plan import ManualRun, accuracy, built_exactly, plan_json, run_manual, step_matches
from mepnet.stage2 import make_predictor
from mepnet.stage2.base import EarlierStep, Prediction, Predictor, StepContext


@pytest.fixture(scope="module")
def manual_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return next(iter(iter_manual_dirs(generate_manuals(tmp_path_factory.mktemp("cs"), 1, 31337))))


def _truth(manual_dir: Path):
    m = load_manual(manual_dir)
    comps = answers_of(m).components(m)
    ans = m.answers.build(None)  # type: ignore[union-attr]
    placements = []
    for k in range(len(m.main.steps)):
        for j, inst in enumerate(ans.truth(k).placed()):
            placements.append(
                Placement(k + 1, j, comps[inst.component], inst.yaw, tuple(inst.t), inst.colour)
            )
    return m, comps, ans, placements


def _revised(run: ManualRun) -> list[tuple[int, int]]:
    """Every revision of the main build's plan as (the step revised, the step that found it)."""
    return [(r.step, r.found_at) for s in run.main.steps for r in s.revisions]


def test_a_right_step_is_confident_and_a_wrong_one_is_flagged(manual_dir: Path):
    m, comps, ans, placements = _truth(manual_dir)
    steps = m.main.steps
    k = len(steps) - 1
    base = build([p for p in placements if p.step <= k])
    assert base is not None
    earlier = tuple(
        EarlierStep(steps[i], sum(1 for p in placements if p.step <= i + 1)) for i in range(k)
    )
    ctx = StepContext(steps[k], base, comps, m.image_size, earlier)
    mine = [p for p in placements if p.step == k + 1]
    preds = [Prediction(0, ans.truth(k).placed()[0].component, p.yaw, p.t) for p in mine]
    right = build(placements)
    good = check_step(ctx, preds, right)  # type: ignore[arg-type]
    assert good.confidence is not None and good.confidence > 0.8 and not good.flags
    # the step's parts left out: nothing explains what changed
    bad = check_step(ctx, [Prediction(0, preds[0].component, None, None)], base.copy())
    assert bad.confidence is not None and bad.confidence < 0.1
    assert any("not placed" in f for f in bad.flags)
    assert any("not explained" in f for f in bad.flags)


def _moved(placements: list[Placement], view: View) -> tuple[int, Placement] | None:
    """An earlier instance moved to another valid place where the picture shows the page."""
    w = h = 256
    for i in range(len(placements) - 1, -1, -1):
        p = placements[i]
        if p.step >= view.step:
            continue
        rest = placements[:i] + placements[i + 1 :]
        rest_shape = build(rest)
        if rest_shape is None:
            continue
        page = ~view.wide
        ranked, _ = _bg.abys_ranked(rest_shape, view.camera, w, h, p.component, page, 8, 5.0)
        for yaw, t, _iou in ranked:
            moved = Placement(p.step, p.pred, p.component, yaw, tuple(t), p.colour)
            if p.component.same_placement(p.yaw, p.t, yaw, tuple(t)):
                continue
            trial = placements[:i] + [moved] + placements[i + 1 :]
            if build(trial) is not None and disagreement(trial, [view], w, h)[0] > 300:
                return i, moved
    return None


def test_an_earlier_placement_the_pictures_contradict_is_put_back(manual_dir: Path):
    m, _, _, placements = _truth(manual_dir)
    steps = m.main.steps
    views = [View.of(k + 1, steps[k].camera_object(), steps[k].image()) for k in range(len(steps))]
    found = _moved(placements, views[-1])
    assert found is not None, "no earlier instance could be moved for the test"
    i, moved = found
    wrong = placements[:i] + [moved] + placements[i + 1 :]
    fixed, revisions = repair(wrong, views, 256, 256)
    assert len(revisions) >= 1
    r = next(r for r in revisions if (r.step, r.pred) == (moved.step, moved.pred))
    assert r.disagreement[1] < r.disagreement[0]
    truth = placements[i]
    assert truth.component.same_placement(truth.yaw, truth.t, fixed[i].yaw, fixed[i].t)
    # the true plan needs nothing
    same, none = repair(placements, views, 256, 256)
    assert none == [] and same == placements


def test_a_part_beside_the_model_is_put_back_by_its_own_picture(monkeypatch: pytest.MonkeyPatch):
    """A dark green 2x4 plate on a 2x4 brick of its colour adds almost nothing to the
    silhouette (a plate's thickness), so a change map can miss it and stage 2 stand it on the
    ground beside the brick, over the page. The step's own picture contradicts that at once:
    with the latest step's parts suspect too (:data:`OWN_STEP`) and candidates ranked against
    the whole silhouette (:data:`SILHOUETTE_CANDIDATES`; what is unexplained beside the brick
    is only the plate's thin edge), the repair puts it on the brick before the next step is
    predicted. Either off, it stays."""
    import mepnet.consistency as consistency

    brick, plate = _bg.Component.primitive("3001"), _bg.Component.primitive("3020")
    cam = _bg.Camera(30.0, 225.0, 0.0, 0.012, (0.0, -0.1))
    green = 288  # dark green
    b = Placement(1, 0, brick, 0, (0, 3, 0), green)
    true = Placement(2, 0, plate, 0, (0, 4, 0), green)
    wrong = Placement(2, 0, plate, 0, (-8, 1, -8), green)  # on the ground, over the page
    pictures = [build([b]), build([b, true])]
    assert all(p is not None for p in pictures) and build([b, wrong]) is not None
    views = [View.of(k + 1, cam, _bg.render(a, cam, 128, 128).rgb) for k, a in enumerate(pictures)]
    assert disagreement([b, wrong], views, 128, 128)[1] > 1000
    fixed, revisions = repair([b, wrong], views, 128, 128)
    assert [(r.step, r.found_at) for r in revisions] == [(2, 2)]
    assert plate.same_placement(fixed[1].yaw, fixed[1].t, true.yaw, true.t)
    assert disagreement(fixed, views, 128, 128) == [0, 0]
    monkeypatch.setattr(consistency, "SILHOUETTE_CANDIDATES", 0)
    fixed, _ = repair([b, wrong], views, 128, 128)
    assert not plate.same_placement(fixed[1].yaw, fixed[1].t, true.yaw, true.t)
    monkeypatch.setattr(consistency, "SILHOUETTE_CANDIDATES", 16)
    monkeypatch.setattr(consistency, "OWN_STEP", False)
    assert repair([b, wrong], views, 128, 128) == ([b, wrong], [])


def test_the_plan_records_confidence_flags_and_revisions(manual_dir: Path):
    man = load_manual(manual_dir)
    run = run_manual(man, make_predictor("oracle"))
    doc = plan_json(run)
    for s in doc["steps"]:
        assert 0.0 <= s["confidence"] <= 1.0
        assert isinstance(s["flags"], list) and s["revisions"] == []
    assert np.mean([s["confidence"] for s in doc["steps"]]) > 0.8
    # teacher-forced runs and repair=False make no revisions
    off = run_manual(man, make_predictor("oracle"), repair=False)
    assert all(s.revisions == [] and s.repair_seconds == 0.0 for b in off.builds for s in b.steps)


def test_a_tried_placement_drawn_over_the_rest_is_drawn_as_the_whole_shape(manual_dir: Path):
    """The repair draws each placement it tries alone over the plan drawn without that
    instance: that gives exactly the pixels drawing the whole plan gives (where it is drawn, and
    where in colours unlike the page), in every view, for instances of any step and placements
    in front of or behind the rest; with the page the part's own colour, so that a hidden part's
    pixels counted as its own would show."""
    import dataclasses

    from mepnet.consistency import _backdrops, _disagreement_with

    m, _, _, placements = _truth(manual_dir)
    steps = m.main.steps
    views = [View.of(k + 1, steps[k].camera_object(), steps[k].image()) for k in range(len(steps))]
    w = h = 256
    compared = 0
    for i in range(0, len(placements), max(1, len(placements) // 6)):
        p = placements[i]
        rest = placements[:i] + placements[i + 1 :]
        rest_shape = build(rest)
        if rest_shape is None:
            continue
        alone = _bg.Assembly()
        alone.add(p.component, p.yaw, p.t, p.colour)
        r = _bg.render(alone, views[-1].camera, w, h, line_px=0.0)
        own = np.median(r.rgb[r.ids >= 0], axis=0).astype(np.float32)
        pages = [dataclasses.replace(v, page=own) for v in views]
        backdrops = _backdrops(rest, pages, w, h)
        page = ~views[-1].narrow
        ranked, _ = _bg.abys_ranked(rest_shape, views[-1].camera, w, h, p.component, page, 4, 5.0)
        for yaw, t in [(p.yaw, p.t)] + [(y, tuple(u)) for y, u, _ in ranked]:
            moved = Placement(p.step, p.pred, p.component, yaw, t, p.colour)
            trial = placements[:i] + [moved] + placements[i + 1 :]
            shape = build(trial)
            if shape is None:
                continue
            single = _bg.Assembly()
            single.add(p.component, yaw, t, p.colour)
            for v, b in zip(pages, backdrops, strict=True):
                if p.step > v.step:
                    continue
                ids, seen = v.drawn(build([q for q in trial if q.step <= v.step]), w, h)
                drawn, seen2 = b.over(single, w, h)
                assert (drawn == (ids >= 0)).all() and (seen2 == seen).all()
            assert _disagreement_with(moved, backdrops, w, h) == disagreement(trial, pages, w, h)
            compared += 1
    assert compared >= 6


def test_a_tie_a_later_step_tells_apart_is_settled_there(tmp_path: Path):
    """Fresh F20 manual 1 step 7: a 2x2 corner plate wholly hidden under a 2x4 brick placed in
    the same step; two of its places explain the picture equally (stage 2 keeps the other as a
    tie) and it took the wrong one. Step 14's part then cannot stand where the picture shows it
    (the wrong plate is in the way): predicted again on the tie, step 14 explains its picture
    better, and the plan takes the tie: the whole manual is built exactly right. The retry is
    a second look at step 14, on its own smaller budget (:data:`mepnet.plan.TIE_RETRY_BUDGET_S`)."""
    from mepnet.plan import TIE_RETRY_BUDGET_S, built_exactly

    man = load_manual(next(iter(iter_manual_dirs(generate_manuals(tmp_path, 1, 930001)))))
    predictor = make_predictor("mepnet")
    budgets = []
    plain = predictor.predict

    def spy(ctx):
        budgets.append(ctx.budget_s)
        return plain(ctx)

    predictor.predict = spy  # type: ignore[method-assign]
    run = run_manual(man, predictor)
    steps = sum(len(b.steps) for b in run.builds)
    assert budgets.count(None) == steps  # every step's own prediction: stage 2's budget
    assert budgets.count(TIE_RETRY_BUDGET_S) >= 1 and len(budgets) > steps  # and the retries'
    step7 = run.main.steps[6]
    assert any(p.extra.get("ties") for p in step7.predictions)
    revised = [r for s in run.main.steps for r in s.revisions]
    assert [(r.step, r.found_at) for r in revised] == [(7, 14)]
    assert revised[0].disagreement[1] < revised[0].disagreement[0]
    assert built_exactly(run)


def test_a_tie_is_tried_only_where_it_opens_a_place_the_picture_shows(
    monkeypatch: pytest.MonkeyPatch,
):
    """A 1x1 plate tied between two corners of a 2x4 brick; the step's 2x2 plate is drawn
    where one corner's plate would be in the way. The tie opens that place (a retry can find
    it) only when the plate taken is that corner's; a tie between places the 2x2 plate's
    picture never meets opens nothing (its retry could only predict the same)."""
    import mepnet.plan as plan
    from mepnet.geom import manual_camera
    from mepnet.plan import _opens

    # the best 6 placements (the count until stop 62; the plan now looks at 40, where on a
    # shape this small some place of the 2x2 plate meets any corner)
    monkeypatch.setattr(plan, "TIE_OPENS", 6)
    brick, plate2, plate1 = (_bg.Component.primitive(n) for n in ("3001", "3022", "3024"))

    def shape(*items):
        a = _bg.Assembly()
        for c, t in items:
            a.add(c, 0, t)
        return a

    base = (brick, (0, 3, 0))
    true, blocking, free = (plate2, (-2, 4, 0)), (plate1, (-3, 4, -1)), (plate1, (3, 4, 1))
    drawn = shape(base, free, true)
    camera = manual_camera(drawn)
    changed = _bg.render(drawn, camera, 128, 128, line_px=0.0).ids == 2  # the 2x2 plate
    assert changed.sum() > 500
    placed = [Placement(3, 0, plate2, 0, (2, 4, 0), 4)]  # the step put it elsewhere
    view = (camera, 128, 128)
    assert _opens(shape(base, blocking), shape(base, free), placed, changed, view)
    elsewhere = (plate1, (1, 4, 1))  # a tie between two corners the 2x2 plate never meets
    assert not _opens(shape(base, elsewhere), shape(base, free), placed, changed, view)


def test_a_picture_from_a_new_side_tells_a_tie_apart():
    """A 1x1 brick with a side stud on a 2x4 brick: seen from the manual camera's side two of
    its yaws turn the stud away alike (no picture there can tell them apart); from the other
    side the picture is at the drawing of the true one and far from the other's."""
    from mepnet.consistency import tie_distances
    from mepnet.geom import manual_camera

    brick, side = _bg.Component.primitive("3001"), _bg.Component.primitive("87087")

    def shape(yaw: int) -> _bg.Assembly:
        a = _bg.Assembly()
        a.add(brick, 0, (0, 3, 0), 4)
        a.add(side, yaw, (0, 6, 0), 1)
        return a

    front = manual_camera(shape(0))
    back = _bg.Camera(front.elevation, front.azimuth + 180.0, 0.0, front.scale, front.translation)
    tied = [
        (a, b)
        for a in range(4)
        for b in range(a + 1, 4)
        if tie_distances(_bg.render(shape(a), front, 128, 128).rgb, shape(a), shape(b), front)
        is None
    ]
    assert len(tied) == 1
    a, b = tied[0]
    for true, other in ((a, b), (b, a)):
        picture = _bg.render(shape(true), back, 128, 128).rgb
        d = tie_distances(picture, shape(true), shape(other), back)
        assert d is not None and d[2] >= 100
        assert d[0] < 0.05 < 0.5 < d[1]


def test_a_tie_a_picture_from_a_new_side_tells_apart_is_settled_there(tmp_path: Path):
    """Fresh F20 manual 15 step 3: a 1x1 brick with a side stud turned away from the camera;
    its two yaws that turn the stud away draw every picture alike until step 11, where the
    view turns a quarter: stage 2 keeps the other yaw as a tie though the step is well
    explained (a round's next choice drawn exactly like its decision), and step 11's picture
    shows which one it is: the plan takes the tie there."""
    man = load_manual(next(iter(iter_manual_dirs(generate_manuals(tmp_path, 1, 930015)))))
    man.main.steps[:] = man.main.steps[:11]
    run = run_manual(man, make_predictor("mepnet"))
    step3 = run.main.steps[2]
    assert any(p.extra.get("ties") for p in step3.predictions)
    revised = [r for s in run.main.steps for r in s.revisions]
    assert [(r.step, r.found_at) for r in revised] == [(3, 11)]
    assert revised[0].disagreement[1] < revised[0].disagreement[0]
    assert step_matches(run, step3) == 1
    assert step3.alternatives == []  # settled: nothing left to flag


def test_a_part_no_picture_shows_is_flagged_with_its_alternatives(tmp_path: Path):
    """Our pictures of F20v manual 19, main steps 1-7 (tests/data/unsettled): steps 4 and 7
    each add a 1x1 brick with a side stud (87087) whose stud faces away in every picture, so
    no picture tells its turns apart. The plan takes one and says so: the step is flagged, its
    alternatives listed in plan.json, and the truth is the plan's or one of them; a step
    whose picture shows everything (step 1, a plate) has none. mepnet.eval counts them."""
    from mepnet.eval import alternatives_counts

    man = load_manual(Path(__file__).parent / "data" / "unsettled")
    run = run_manual(man, make_predictor("mepnet"))
    steps = run.main.steps
    assert steps[0].alternatives == []
    doc = plan_json(run)
    for k in (3, 6):
        s = steps[k]
        assert s.alternatives, k + 1
        assert any("the manual does not show which" in f for f in s.check.flags)
        rec = doc["steps"][k]["alternatives"]
        assert len(rec) == len(s.alternatives)
        for alt in rec:
            for x in alt:
                comp = doc["steps"][k]["components"][x["index"]]
                assert comp["component"] == {"part": "87087"}
                assert x["lattice"] == comp["lattice"] and x["yaw"] != comp["yaw"]
    assert "alternatives" not in doc["steps"][0]
    counts = dict(
        zip(("steps", "wrong", "flagged", "offered"), alternatives_counts(run), strict=True)
    )
    # every wrong step is one whose truth the flag offers (the 87087s: a coin toss each)
    assert counts["wrong"] == counts["flagged"] == counts["offered"]
    assert counts["steps"] >= 2
    right, total = accuracy(run)
    assert total - right == counts["wrong"] > 0  # one component each, steps 4 and 7 here


def test_a_grille_brick_leocad_draws_with_its_grille_is_placed_at_once():
    """LeoCAD's pictures of F20i manual 7, main steps 1-5: until 2877 had its grille in our
    library (stop 61), stage 2 put step 4's grille brick far behind its place (drawn at nearly
    the same pixels, the grille's lines unexplained); step 5's picture showed it wrong, the
    repair moved it back and step 5 was predicted again on the shape as revised
    (:data:`mepnet.plan.AGAIN_AFTER_REPAIR`, which this case was the test of). Drawn with its
    grille, the brick is placed right at once and nothing needs revising."""
    man = load_manual(Path(__file__).parent / "data" / "leocad_again")
    run = run_manual(man, make_predictor("mepnet"))
    assert _revised(run) == []
    assert [step_matches(run, s) for s in run.main.steps] == [1, 1, 1, 2, 1]


class _Misplacing(Predictor):
    """The shipped predictor, except that the grille brick of step 4 (3 parts built before it)
    goes where ``wrong`` says: a mistake like the one stage 2 made on these pictures before
    2877 had its grille."""

    name = "misplacing"

    def __init__(self, wrong: tuple[int, tuple[int, int, int]]):
        self.inner = make_predictor("mepnet")
        self.wrong = wrong

    def predict(self, ctx: StepContext) -> list[Prediction]:
        preds = self.inner.predict(ctx)
        if ctx.step.index != 4 or len(ctx.base) != 3:
            return preds
        yaw, t = self.wrong
        return [
            dataclasses.replace(p, yaw=yaw, t=t) if str(p.component) == "2877" else p for p in preds
        ]


def test_a_step_whose_picture_moved_an_earlier_part_is_predicted_again(
    monkeypatch: pytest.MonkeyPatch,
):
    """LeoCAD's pictures of F20i manual 7, main steps 1-5, with step 4's grille brick put far
    behind its place, turned and three plates lower, where step 4's picture draws it at nearly
    the same pixels (stage 2 put it thereabouts until 2877 had its grille, stop 61; the
    place's silhouette overlaps the truth's with IoU 0.84). Step 5's picture, from the other
    side, shows it wrong and the repair moves it back; but step 5 was predicted on the shape
    with it where it was, its plate placed to explain what the misplaced brick left. Predicted
    again on the shape as revised (:data:`mepnet.plan.AGAIN_AFTER_REPAIR`), the step takes
    the new prediction and records it as its own revision."""
    import mepnet.plan as plan

    man = load_manual(Path(__file__).parent / "data" / "leocad_again")
    wrong = (2, (10, 3, 7))
    truth = answers_of(man).build(None).truth(3).placed()
    assert [(str(i.component), i.yaw, tuple(i.t)) for i in truth][0] == ("2877", 3, (4, 6, 2))
    run = run_manual(man, _Misplacing(wrong))
    assert _revised(run) == [(4, 5), (5, 5)]
    assert run.main.steps[3].revisions == [] and run.main.steps[4].revisions[0].before == wrong
    assert [step_matches(run, s) for s in run.main.steps] == [1, 1, 1, 2, 1]
    assert run.main.steps[4].predictions[0].extra.get("revised_at") == 5
    monkeypatch.setattr(plan, "AGAIN_AFTER_REPAIR", False)
    run = run_manual(man, _Misplacing(wrong))
    assert _revised(run) == [(4, 5)]
    assert step_matches(run, run.main.steps[4]) == 0


def test_a_place_scored_alike_though_drawn_apart_is_kept_open_and_settled_later(
    monkeypatch: pytest.MonkeyPatch,
):
    """LeoCAD's pictures of F20y manual 7, main steps 1-14: step 10 adds a 1x1 brick (3005)
    all but hidden behind the model, a sliver of one face in view. Stage 2 scores a place a
    plate higher and two cells over 0.0002 above the true one; our drawings of the two differ
    in 86 pixels (LeoCAD shades the sliver's faces otherwise), too many for a near tie, so the
    plan built on it until step 14, whose round plate stands on the brick, could not be
    explained (confidence 0.42) and went elsewhere. Kept as a close tie
    (:data:`mepnet.stage2.synthesis.CLOSE_TIE`), step 14 takes it."""
    import mepnet.stage2.synthesis as synthesis

    man = load_manual(Path(__file__).parent / "data" / "leocad_close_tie")
    run = run_manual(man, make_predictor("mepnet"))
    assert _revised(run) == [(10, 14)]
    assert [step_matches(run, s) for s in run.main.steps[9:]] == [4, 1, 2, 1, 1]
    assert built_exactly(run)
    monkeypatch.setattr(synthesis, "CLOSE_TIE", 0.0)
    run = run_manual(man, make_predictor("mepnet"))
    assert _revised(run) == []
    assert step_matches(run, run.main.steps[9]) == 3 and step_matches(run, run.main.steps[13]) == 0


def test_a_tie_that_blocks_a_later_parts_turn_is_settled_there(monkeypatch: pytest.MonkeyPatch):
    """Our pictures of F20z manual 6, main steps 1-25: step 23's 1x1 panel (6231) at yaw 1 or
    2 draws its picture alike (a tie). Step 25 puts an inverted slope (3665) beside it; at the
    panel's kept yaw the slope's true turn collides, so it is turned and the step explains its
    picture 0.98, 72 pixels of it showing the true turn. Retried below 0.995
    (:data:`mepnet.plan.TIE_RETRY_BELOW`), on ties opening any of the best 40 places
    (:data:`~mepnet.plan.TIE_OPENS`), taken for a gain of 0.001 (:data:`~mepnet.plan.TIE_GAIN`),
    the tie is settled at step 25; with stop 61's 0.9, 6 and 0.01 it was not."""
    import mepnet.plan as plan

    man = load_manual(Path(__file__).parent / "data" / "ours_tie_turn")
    run = run_manual(man, make_predictor("mepnet"))
    assert _revised(run) == [(23, 25)]
    assert built_exactly(run)
    monkeypatch.setattr(plan, "TIE_RETRY_BELOW", 0.9)
    monkeypatch.setattr(plan, "TIE_GAIN", 0.01)
    monkeypatch.setattr(plan, "TIE_OPENS", 6)
    run = run_manual(man, make_predictor("mepnet"))
    assert _revised(run) == []
    assert [step_matches(run, run.main.steps[k]) for k in (22, 24)] == [0, 1]


def test_a_hidden_part_drawn_alike_elsewhere_is_kept_open_and_settled_later(
    monkeypatch: pytest.MonkeyPatch,
):
    """LeoCAD's pictures of F20n manual 0, main steps 1-10: step 7 adds a 1x1 brick behind the
    model, a sliver of it in view; stage 2 scores a place far off (also hidden) 0.009 above
    the true one, whose drawing differs by 17 pixels. Kept as a near tie though it fills
    another box (:data:`mepnet.stage2.synthesis.NEAR_TIE_BOXES` off), the picture of step 10,
    from another side, settles it. (The far place was reached by a move along the view ray;
    since stop 59 such a move is held to the wide search's terms, :data:`RAY_APART`, and step 7
    is right at once: turned off here, so that the tie is what this test sees.)"""
    import mepnet.stage2.synthesis as synthesis

    man = load_manual(Path(__file__).parent / "data" / "leocad_hidden")
    run = run_manual(man, make_predictor("mepnet"))
    assert _revised(run) == []
    assert step_matches(run, run.main.steps[6]) == 1
    monkeypatch.setattr(synthesis, "RAY_APART", False)
    run = run_manual(man, make_predictor("mepnet"))
    assert _revised(run) == [(7, 10)]
    assert step_matches(run, run.main.steps[6]) == 1
    monkeypatch.setattr(synthesis, "NEAR_TIE_BOXES", True)
    run = run_manual(man, make_predictor("mepnet"))
    assert step_matches(run, run.main.steps[6]) == 0
