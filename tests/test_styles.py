"""Render styles and mepnet.styles: the default draws today's pictures bit for bit, each factor
changes the picture the way it says, never the instance maps or answers, synth --styles is
deterministic, and bad styles are one-line errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mepnet import RenderStyle, render
from mepnet import _brickgeom as _bg
from mepnet.errors import ConfigError
from mepnet.manual import answers_of, load_manual, write_manual
from mepnet.styles import (
    check_style,
    default_style,
    draw_step,
    draw_style,
    page_effects,
    render_style,
    restyled_step,
)

EXAMPLE = Path(__file__).resolve().parents[1] / "python" / "mepnet" / "data" / "example_manual"


@pytest.fixture(scope="module")
def manual(tmp_path_factory: pytest.TempPathFactory):
    """A generated manual (seed 990008, 256 px) with its answers, loaded."""
    out = tmp_path_factory.mktemp("styles") / "m"
    seed = 990008
    write_manual(
        out,
        _bg.synth_manual(seed, {"image_size": 256}),
        {"kind": "synthetic", "seed": seed, "generator": {"image_size": 256}},
        writer="test",
    )
    return load_manual(out)


def last_step(manual):  # type: ignore[no-untyped-def]
    """(assembly in build order, camera, asm ids new in the step, asm ids before) of the main
    build's last step."""
    answers = answers_of(manual)
    comps = answers.components(manual)
    truth = answers.main
    k = len(manual.main.steps) - 1
    new = set(truth.steps[k].instance_ids)
    asm = _bg.Assembly()
    new_ids, old_ids = [], []
    for i in sorted(i for s in truth.steps for i in s.instance_ids):
        inst = truth.instances[i]
        iid = asm.add(comps[inst.component], inst.yaw, inst.t, inst.colour)
        (new_ids if i in new else old_ids).append(iid)
    return asm, manual.main.steps[k].camera_object(), new_ids, old_ids


def draw(manual, **style):  # type: ignore[no-untyped-def]
    asm, cam, new_ids, old_ids = last_step(manual)
    return render(asm, cam, 256, 256, style=style, new_ids=new_ids, old_ids=old_ids)


def dark(rgb: np.ndarray) -> int:
    return int((rgb.max(axis=2) < 60).sum())


# -- the default look ---------------------------------------------------------------------------


def test_default_style_redraws_the_bundled_example_bit_for_bit():
    example = load_manual(EXAMPLE)
    answers = answers_of(example)
    comps = answers.components(example)
    for k, step in enumerate(example.main.steps):
        rgb, ids = draw_step(example, (None, k), default_style(), np.random.default_rng(0), comps)
        assert np.array_equal(rgb, step.image())
        assert np.array_equal(ids, answers.main.truth(k).ids())


def test_default_style_argument_forms_are_the_same_picture(manual):
    plain = draw(manual)
    asm, cam, new_ids, old_ids = last_step(manual)
    for style in (None, {}, RenderStyle(), RenderStyle.from_dict(RenderStyle().to_dict())):
        r = render(asm, cam, 256, 256, style=style, new_ids=new_ids, old_ids=old_ids)
        assert np.array_equal(r.rgb, plain.rgb)
    assert RenderStyle().is_default and not RenderStyle(fade=0.1).is_default
    a = _bg.synth_manual(7, {"image_size": 64})
    b = _bg.synth_manual(7, {"image_size": 64}, style={})
    assert all(
        np.array_equal(x["rgb"], y["rgb"])
        for x, y in zip(a["main"]["steps"], b["main"]["steps"], strict=True)
    )


# -- each factor --------------------------------------------------------------------------------


def test_fewer_lines_fewer_dark_edge_pixels(manual):
    counts = [dark(draw(manual, lines=m).rgb) for m in ("all", "parts", "silhouette", "none")]
    assert counts[0] > counts[1] > counts[2] > counts[3]


def test_line_colour_and_width(manual):
    base = draw(manual, front_lines=True)
    black = draw(manual, front_lines=True, line_colour=(0, 0, 0))
    assert (black.rgb.max(axis=2) == 0).sum() > 500
    assert dark(draw(manual, front_lines=True, line_px=2).rgb) > dark(base.rgb) * 1.5
    part = draw(manual, front_lines=True, line_colour="part", line_darken=0.5)
    assert dark(part.rgb) < dark(base.rgb)


def test_highlight_outlines_new_instances(manual):
    r = draw(manual, highlight=(255, 0, 255), highlight_px=2)
    magenta = np.all(r.rgb == (255, 0, 255), axis=2)
    assert magenta.sum() > 100
    _, _, new_ids, _ = last_step(manual)
    near_new = np.isin(r.ids, new_ids)
    # every highlighted pixel is on a new instance or within 2 px of one
    grown = near_new.copy()
    for _ in range(2):
        g = grown.copy()
        g[1:] |= grown[:-1]
        g[:-1] |= grown[1:]
        g[:, 1:] |= grown[:, :-1]
        g[:, :-1] |= grown[:, 1:]
        grown = g
    assert grown[magenta].all()
    # without new instances there is nothing to highlight
    asm, cam, _, _ = last_step(manual)
    assert not np.all(
        render(asm, cam, 256, 256, style={"highlight": (255, 0, 255)}).rgb == (255, 0, 255), axis=2
    ).any()


def test_faded_instances_are_lighter(manual):
    _, _, new_ids, old_ids = last_step(manual)
    plain, faded = draw(manual), draw(manual, fade=0.6)
    old = np.isin(plain.ids, old_ids)
    new = np.isin(plain.ids, new_ids)
    assert faded.rgb[old].astype(float).mean() > plain.rgb[old].astype(float).mean() + 40
    assert np.array_equal(faded.rgb[new], plain.rgb[new])


def test_light_direction_and_shading_change_face_shades(manual):
    above = draw(manual)
    below = draw(manual, light=(0.45, -0.75, -0.5))
    part = above.ids >= 0
    assert (above.rgb[part] != below.rgb[part]).any(axis=1).mean() > 0.5
    flat = draw(manual, shading="flat", lines="none")
    # flat shading: one colour per brick
    asm, _, _, _ = last_step(manual)
    bricks = {iid: len(comp.bricks) for iid, comp, _, _ in asm.instances()}
    for iid in np.unique(flat.ids[flat.ids >= 0]):
        assert len(np.unique(flat.rgb[flat.ids == iid], axis=0)) <= bricks[int(iid)]
    spec = draw(manual, shading="specular", specular=0.6, shininess=4)
    assert spec.rgb[part].astype(float).mean() > above.rgb[part].astype(float).mean()
    bands = draw(manual, shading="bands")
    assert not np.array_equal(bands.rgb, above.rgb)


def test_palette_and_page(manual):
    def saturation(r):  # type: ignore[no-untyped-def]
        px = r.rgb[r.ids >= 0].astype(float)
        return (px.max(axis=1) - px.min(axis=1)).mean()

    base = draw(manual)
    assert saturation(draw(manual, saturation=0.5)) < saturation(base)
    assert saturation(draw(manual, saturation=1.4)) > saturation(base)
    page = draw(manual, background=(240, 235, 220))
    assert (page.rgb[page.ids < 0] == (240, 235, 220)).all()


def test_styles_never_change_instance_maps(manual):
    plain = draw(manual)
    rng = np.random.default_rng(3)
    for _ in range(12):
        style = draw_style(rng)
        r = draw(manual, **{**style["render"], "supersample": 1})
        assert np.array_equal(r.ids, plain.ids)
        assert np.array_equal(r.depth, plain.depth)
        assert np.array_equal(r.visible_pixels, plain.visible_pixels)


def test_page_effects():
    rng = np.random.default_rng(0)
    img = np.full((64, 64, 3), 255, np.uint8)
    img[16:48, 16:48] = (200, 30, 30)
    img[16:48, 31] = 0
    assert page_effects(img, default_style(), rng) is img
    for key, value in (
        ("grain", 4.0),
        ("gradient", 0.08),
        ("blur", 1.0),
        ("scale", 0.5),
        ("jpeg", 40),
    ):
        style = {"image": {key: value}}
        out = page_effects(img, style, np.random.default_rng(1))
        assert out.shape == img.shape and out.dtype == np.uint8
        assert not np.array_equal(out, img), key
        assert np.array_equal(out, page_effects(img, style, np.random.default_rng(1))), key
    # blur and resampling soften the line
    for key, value in (("blur", 1.0), ("scale", 0.5)):
        out = page_effects(img, {"image": {key: value}}, rng)
        assert out[32, 31].min() > 0


# -- styles drawn, manuals and training ---------------------------------------------------------


def test_draw_style_distribution():
    rng = np.random.default_rng(0)
    styles = [draw_style(rng, 256, ldraw=True) for _ in range(400)]
    for s in styles:
        check_style(json.loads(json.dumps(s)))  # JSON round trip, valid
        render_style(s)
    default = sum(not s["render"] and not s["image"] for s in styles) / len(styles)
    assert 0.12 < default < 0.28
    lines = [s["render"].get("lines") for s in styles if s["render"]]
    assert {"all", "parts", "silhouette", "none"} <= set(lines)
    assert any(s["meshes"] == "ldraw" for s in styles)
    assert not any(s["meshes"] == "ldraw" for s in (draw_style(rng) for _ in range(50)))
    assert draw_style(np.random.default_rng(5)) == draw_style(np.random.default_rng(5))


def test_restyled_step_keeps_targets_exact(manual):
    answers = answers_of(manual)
    comps = answers.components(manual)
    for k in range(0, len(manual.main.steps), 5):
        truth = answers.main.truth(k).ids()
        rgb, ids = restyled_step(manual, (None, k), np.random.default_rng(k), comps)
        assert rgb.shape == (256, 256, 3) and rgb.dtype == np.uint8
        # anti-aliased pictures take ids at pixel centres: at most a few edge pixels move
        assert (ids != truth).mean() < 0.001
    for b, _ in manual.builds():
        if b is not None:
            rgb, ids = draw_step(manual, (b, 0), default_style(), np.random.default_rng(0), comps)
            assert np.array_equal(ids, answers.build(b).truth(0).ids())


def test_training_samples_with_styles(manual):
    from mepnet.detector.config import ModelConfig
    from mepnet.train.data import training_sample

    cfg = ModelConfig.named("tiny")
    key = (None, 3)
    plain = training_sample(manual, key, cfg, False, np.random.default_rng(1))
    off = training_sample(manual, key, cfg, False, np.random.default_rng(1), styles=0.0)
    assert all(torch_equal(plain.tensors[k], off.tensors[k]) for k in plain.tensors)
    styled = [
        training_sample(manual, key, cfg, True, np.random.default_rng(s), styles=1.0)
        for s in range(4)
    ]
    assert any(not torch_equal(s.tensors["image"], plain.tensors["image"]) for s in styled)
    again = training_sample(manual, key, cfg, True, np.random.default_rng(2), styles=1.0)
    assert torch_equal(again.tensors["image"], styled[2].tensors["image"])
    for s in styled:
        # zoom augmentation moves targets with the picture; without it they are the page's
        assert s.tensors["inst_valid"].sum() == plain.tensors["inst_valid"].sum()
    exact = training_sample(manual, key, cfg, False, np.random.default_rng(0), styles=1.0)
    for k in ("heatmap", "inst_cell", "inst_offset", "inst_rot", "inst_slot"):
        assert torch_equal(exact.tensors[k], plain.tensors[k]), k


def torch_equal(a, b) -> bool:  # type: ignore[no-untyped-def]
    import torch

    return bool(torch.equal(a, b))


def synth(*args: str) -> subprocess.CompletedProcess[str]:
    # the built-in meshes only: no LDraw library from the environment
    env = {k: v for k, v in os.environ.items() if k != "LDRAWDIR"}
    return subprocess.run(
        [sys.executable, "-m", "mepnet.synth", "--no-progress", *args],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )


def test_synth_styles_deterministic_and_answers_unchanged(tmp_path: Path):
    common = ["--manuals", "3", "--seed", "20", "--size", "96"]
    runs = {}
    for name, extra in (("a", ["--workers", "1"]), ("b", ["--workers", "2"]), ("plain", [])):
        styles = [] if name == "plain" else ["--styles"]
        r = synth("--out", str(tmp_path / name), *common, *extra, *styles)
        assert r.returncode == 0, r.stderr
        runs[name] = tmp_path / name
    for folder in sorted(runs["a"].iterdir()):
        other = runs["b"] / folder.name
        for f in sorted(folder.iterdir()):
            assert f.read_bytes() == (other / f.name).read_bytes(), f
        styled = json.loads((folder / "manual.json").read_text())
        plain = json.loads((runs["plain"] / folder.name / "manual.json").read_text())
        assert styled["source"]["style"]["version"] == 1
        check_style(styled["source"]["style"])
        del styled["source"]["style"]
        assert styled == plain
        for f in folder.glob("*_ids.png"):
            assert f.read_bytes() == (runs["plain"] / folder.name / f.name).read_bytes()


# -- bad styles ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("style", "error", "match"),
    [
        ({"ambient": -1}, _bg.InvalidArgumentError, "style ambient must be within"),
        ({"fade": 1.0}, _bg.InvalidArgumentError, "style fade"),
        ({"light": (0, 0, 0)}, _bg.InvalidArgumentError, "non-zero direction"),
        ({"light": (0, 1)}, ValueError, "three numbers"),
        ({"shading": "phong"}, _bg.InvalidArgumentError, "shading must be"),
        ({"lines": "thin"}, _bg.InvalidArgumentError, "lines must be"),
        ({"line_colour": "red"}, ValueError, "line_colour must be"),
        ({"highlight": (300, 0, 0)}, ValueError, "highlight must be an"),
        ({"supersample": 2}, _bg.InvalidArgumentError, "supersample must be 1 or 3"),
        ({"line_px": 40}, _bg.InvalidArgumentError, "line width"),
        ({"ambient": "bright"}, ValueError, "style setting 'ambient'"),
        ({"colour": 1}, ValueError, "unknown style setting 'colour'"),
    ],
)
def test_bad_render_styles_are_clear_errors(manual, style, error, match):
    asm, cam, _, _ = last_step(manual)
    with pytest.raises(error, match=match):
        render(asm, cam, 32, 32, style=style)
    with pytest.raises(error, match=match):
        _bg.synth_manual(1, {"image_size": 16}, style=style)
    with pytest.raises(ConfigError, match=match):
        render_style({"render": style})


def test_bad_style_arguments(manual):
    asm, cam, _, _ = last_step(manual)
    with pytest.raises(ValueError, match="style must be a RenderStyle, a dict or None"):
        render(asm, cam, 32, 32, style="dark")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="beyond any assembly"):
        render(asm, cam, 32, 32, new_ids=[1 << 30])
    with pytest.raises(ConfigError, match="unknown style keys"):
        check_style({"render": {}, "paper": 1})
    with pytest.raises(ConfigError, match="style image jpeg"):
        check_style({"render": {}, "image": {"jpeg": 0}})
    with pytest.raises(ConfigError, match="style meshes"):
        check_style({"meshes": "lego"})


def test_bad_training_share_and_sheet_arguments(tmp_path: Path):
    from mepnet.train.config import TrainConfig, validate

    with pytest.raises(ConfigError, match="--styles must be within"):
        validate(TrainConfig(styles=1.5, steps=1))
    r = subprocess.run(
        [sys.executable, "-m", "mepnet.styles", "--sheet", str(tmp_path / "s.png"), "--step", "0"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--step must be" in r.stderr
    assert not (tmp_path / "s.png").exists()


def test_contact_sheet_command(tmp_path: Path):
    out = tmp_path / "sheet.png"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "mepnet.styles",
            "--sheet",
            str(out),
            "--styles",
            "4",
            "--step",
            "3",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={k: v for k, v in os.environ.items() if k != "LDRAWDIR"},
    )
    assert r.returncode == 0, r.stderr
    from PIL import Image

    with Image.open(out) as im:
        assert im.size == (4 * 256, 256 + 26)
    assert r.stdout.splitlines()[0] == "1. the renderer's own look"
