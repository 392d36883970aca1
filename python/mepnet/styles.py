"""Manuals drawn in many styles, by mepnet's own renderer (see ``docs/styles.md``).

A *style* is how one renderer draws one manual (a renderer is consistent within a manual): a
JSON-able dict with

- ``render``: settings of :class:`mepnet.RenderStyle` (lighting and shading model, which edges
  are lines and in what colour and width, anti-aliasing, stud outlines, palette, page colour, the
  highlight of new parts and the fade of old ones); the rasterizer draws them, so id maps and
  answers are untouched;
- ``image``: what happens to the finished picture (paper grain and uneven lighting, blur, a
  lower resolution resampled back, a JPEG round trip): :func:`page_effects`;
- ``meshes``: ``builtin`` or ``ldraw`` (the real LDraw part geometry, when a library is given).

:func:`draw_style` draws one from the distribution below; :data:`DEFAULT_SHARE` of the draws
are exactly the renderer's own look (empty ``render`` and ``image``). Otherwise each factor is
drawn on its own:

=================  ========================================================================
factor             distribution
=================  ========================================================================
light              view space (x right, y up, z away from the viewer): x U(-0.9, 0.9),
                   y U(0.2, 1), z U(-1, -0.1)
shading            lambert 50%, flat 15%, bands 15%, specular 20% (strength U(0.2, 0.6),
                   exponent U(8, 48)); ambient U(0.45, 0.8), ambient + diffuse U(0.9, 1.15)
lines              all edges 60%, part outlines 15%, outer contour 10%, none 15% (flat
                   shading: part outlines instead of the last two)
line colour        near black / grey on dark parts 45%, darker part colour 30% (x U(0.3,
                   0.6)), one fixed dark colour 25%
line width         U(0.7, 2.2) px per 256 px of image; on the nearer surface 70%
anti-aliasing      3x3 supersampling 40%
studs              outlined tops 75%, no outline at the stud top (steps < 4.5 LDU) 25%
creases            a crease from U(37, 53) degrees between faces
palette            LDraw's own 60%, muted 20% (saturation U(0.5, 0.8), lightened U(0.05,
                   0.25)), saturated 20% (saturation U(1.15, 1.5), darkened U(0, 0.1))
new parts          outlined in a highlight colour 15% (U(1.5, 3) px per 256)
old parts          faded toward white 15% (U(0.3, 0.65))
page               white 60%, tinted 40% (grey, cream or blue-grey, U(5, 30) below white)
paper              grain (sigma U(1.5, 5) grey levels) and a lighting gradient (to U(0, 8)%) 20%
blur               Gaussian, sigma U(0.3, 1.0) px per 256, 25%
resolution         drawn at U(0.5, 0.9) of the size and resampled back, 25%
JPEG               quality U(30, 90), 30%
meshes             LDraw's real part geometry 30% (when a library is given)
=================  ========================================================================

Perspective is not among the factors: mepnet's camera is weak perspective everywhere (the
rasterizer, keypoints, stage 2, camera fitting), and a perspective picture would no longer
agree with the answers it is trained against.
"""

from __future__ import annotations

import argparse
import io
import os
from pathlib import Path
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.errors import ConfigError
from mepnet.manual import ComponentRef, Manual

#: Share of drawn styles that are exactly the renderer's own look.
DEFAULT_SHARE = 0.2
#: Version of the style dict (recorded with it).
STYLE_VERSION = 1
#: Highlight colours of new parts (as instruction tools use them).
HIGHLIGHTS = ((255, 40, 40), (255, 140, 0), (40, 200, 255), (255, 0, 200), (120, 230, 40))
#: Fixed line colours.
LINE_COLOURS = ((0, 0, 0), (51, 51, 51), (40, 30, 20), (20, 30, 60))
#: Keys of a style's ``image`` part.
IMAGE_KEYS = ("grain", "gradient", "blur", "scale", "jpeg")


def _r(x: float, digits: int = 3) -> float:
    return round(float(x), digits)


def default_style() -> dict[str, Any]:
    """The renderer's own look, as a style."""
    return {"version": STYLE_VERSION, "render": {}, "image": {}, "meshes": "builtin"}


def draw_style(
    rng: np.random.Generator, image_size: int = 256, ldraw: bool = False
) -> dict[str, Any]:
    """One manual's style drawn from the distribution of this module's docstring; pixel sizes
    follow ``image_size``; ``ldraw``: an LDraw library is at hand (a share uses its meshes)."""
    if rng.random() < DEFAULT_SHARE:
        return default_style()
    px = image_size / 256.0
    render: dict[str, Any] = {}
    # lighting and shading
    render["light"] = [
        _r(rng.uniform(-0.9, 0.9)),
        _r(rng.uniform(0.2, 1.0)),
        _r(rng.uniform(-1.0, -0.1)),
    ]
    shading = str(rng.choice(["lambert", "flat", "bands", "specular"], p=[0.5, 0.15, 0.15, 0.2]))
    render["shading"] = shading
    # a face lit head-on is near its part colour (x U(0.9, 1.15)); the ambient share sets the
    # contrast between lit and unlit faces
    render["ambient"] = _r(rng.uniform(0.45, 0.8))
    render["diffuse"] = _r(rng.uniform(0.9, 1.15) - render["ambient"])
    if shading == "specular":
        render["specular"] = _r(rng.uniform(0.2, 0.6))
        render["shininess"] = _r(rng.uniform(8, 48), 1)
    # lines
    render["lines"] = str(
        rng.choice(["all", "parts", "silhouette", "none"], p=[0.6, 0.15, 0.1, 0.15])
    )
    if shading == "flat" and render["lines"] in ("silhouette", "none"):
        # flat faces without lines lose the shape: such a renderer draws part outlines
        render["lines"] = "parts"
    u = rng.random()
    if u < 0.45:
        render["line_colour"] = "auto"
    elif u < 0.75:
        render["line_colour"] = "part"
        render["line_darken"] = _r(rng.uniform(0.3, 0.6))
    else:
        render["line_colour"] = list(LINE_COLOURS[int(rng.integers(len(LINE_COLOURS)))])
    supersample = 3 if rng.random() < 0.4 else 1
    render["supersample"] = supersample
    # lines drawn U(0.7, 2.2) px wide per 256 px: the rasterizer's lines are 2 * round(line_px
    # * supersample) - 1 samples wide
    width = rng.uniform(0.7, 2.2) * px
    render["line_px"] = _r(max(round((width * supersample + 1) / 2), 1) / supersample, 3)
    render["front_lines"] = bool(rng.random() < 0.7)
    render["plane_edge"] = 1.0 if rng.random() < 0.75 else 4.5
    render["crease_cos"] = _r(np.cos(np.radians(rng.uniform(37, 53))))
    # palette
    u = rng.random()
    if u < 0.2:
        render["saturation"] = _r(rng.uniform(0.5, 0.8))
        render["lighten"] = _r(rng.uniform(0.05, 0.25))
    elif u < 0.4:
        render["saturation"] = _r(rng.uniform(1.15, 1.5))
        render["lighten"] = _r(-rng.uniform(0.0, 0.1))
    # emphasis, as instruction tools do it
    if rng.random() < 0.15:
        render["highlight"] = list(HIGHLIGHTS[int(rng.integers(len(HIGHLIGHTS)))])
        render["highlight_px"] = _r(max(rng.uniform(1.5, 3.0) * px, 0.5), 2)
    if rng.random() < 0.15:
        render["fade"] = _r(rng.uniform(0.3, 0.65))
    # page
    if rng.random() < 0.4:
        kind = int(rng.integers(3))  # grey, warm (cream) or cool (blue-grey)
        toward = [(1.0, 1.0, 1.0), (0.25, 0.5, 1.0), (1.0, 0.6, 0.25)][kind]
        depth = rng.uniform(5, 30)
        render["background"] = [int(round(255 - depth * t)) for t in toward]
    image: dict[str, Any] = {}
    if rng.random() < 0.2:
        image["grain"] = _r(rng.uniform(1.5, 5), 2)
        image["gradient"] = _r(rng.uniform(0, 0.08))
    if rng.random() < 0.25:
        image["blur"] = _r(rng.uniform(0.3, 1.0) * px)
    if rng.random() < 0.25:
        image["scale"] = _r(rng.uniform(0.5, 0.9))
    if rng.random() < 0.3:
        image["jpeg"] = int(rng.integers(30, 91))
    meshes = "ldraw" if ldraw and rng.random() < 0.3 else "builtin"
    return {"version": STYLE_VERSION, "render": render, "image": image, "meshes": meshes}


#: Mixed into a manual's seed for its style (so the style's random stream is its own).
STYLE_STREAM = 0x57_79_6C_65


def manual_style(seed: int, image_size: int, ldraw: bool) -> dict[str, Any]:
    """The style of the generated manual of ``seed`` under ``mepnet.synth --styles`` (a
    function of the seed alone)."""
    return draw_style(np.random.default_rng([STYLE_STREAM, seed]), image_size, ldraw=ldraw)


def check_style(style: Any) -> dict[str, Any]:
    """``style`` checked (a dict with ``render``, ``image`` and ``meshes`` as
    :func:`draw_style` makes); a bad one is a :class:`~mepnet.errors.ConfigError`."""
    if not isinstance(style, dict):
        raise ConfigError(f"a style must be a dict, got {type(style).__name__}")
    unknown = sorted(set(style) - {"version", "render", "image", "meshes"})
    if unknown:
        raise ConfigError(f"unknown style keys: {', '.join(unknown)}")
    render_style(style)
    image = style.get("image", {})
    if not isinstance(image, dict) or set(image) - set(IMAGE_KEYS):
        raise ConfigError(f"style image settings must be a dict of {', '.join(IMAGE_KEYS)}")
    ranges = {
        "grain": (0, 50),
        "gradient": (0, 0.5),
        "blur": (0, 8),
        "scale": (0.1, 1),
        "jpeg": (1, 100),
    }
    for k, v in image.items():
        lo, hi = ranges[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
            raise ConfigError(f"style image {k} must be a number within [{lo}, {hi}], got {v!r}")
    if style.get("meshes", "builtin") not in ("builtin", "ldraw"):
        raise ConfigError(f"style meshes must be builtin or ldraw, got {style.get('meshes')!r}")
    return style


def render_style(style: dict[str, Any]) -> _bg.RenderStyle:
    """The :class:`mepnet.RenderStyle` of a style's ``render`` settings (a
    :class:`~mepnet.errors.ConfigError` naming the setting when one is bad)."""
    settings = style.get("render", {})
    if not isinstance(settings, dict):
        raise ConfigError("style render settings must be a dict")
    try:
        return _bg.RenderStyle.from_dict(settings)
    except (ValueError, TypeError, _bg.BrickGeomError) as e:
        raise ConfigError(f"style: {e}") from None


def page_effects(rgb: np.ndarray, style: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    """A finished step picture (H, W, 3 uint8) as printed, scanned and stored: paper grain and a
    lighting gradient, blur, a lower resolution resampled back to (W, H), a JPEG round trip
    (the style's ``image`` settings, in that order). Same size out; the input is not changed."""
    from PIL import Image, ImageFilter

    image = style.get("image", {})
    if not image:
        return rgb
    h, w = rgb.shape[:2]
    out = rgb
    if image.get("grain") or image.get("gradient"):
        img = rgb.astype(np.float32)
        if image.get("gradient"):
            # light falling off across the page in a random direction
            a = rng.uniform(0, 2 * np.pi)
            ys, xs = np.mgrid[0:h, 0:w]
            ramp = np.cos(a) * (xs / max(w - 1, 1) - 0.5) + np.sin(a) * (ys / max(h - 1, 1) - 0.5)
            img *= (1 - image["gradient"] * (ramp + 0.5))[..., None]
        if image.get("grain"):
            grain = rng.normal(0, image["grain"], size=(h, w)).astype(np.float32)
            img += grain[..., None]
        out = np.clip(img, 0, 255).round().astype(np.uint8)
    pil = Image.fromarray(out)
    if image.get("blur"):
        pil = pil.filter(ImageFilter.GaussianBlur(radius=float(image["blur"])))
    if image.get("scale") and image["scale"] < 1:
        small = (max(int(round(w * image["scale"])), 1), max(int(round(h * image["scale"])), 1))
        pil = pil.resize(small, Image.Resampling.BOX).resize((w, h), Image.Resampling.BILINEAR)
    if image.get("jpeg"):
        buf = io.BytesIO()
        pil.save(buf, format="JPEG", quality=int(image["jpeg"]))
        buf.seek(0)
        with Image.open(buf) as j:
            pil = j.convert("RGB")
    return np.asarray(pil)


def style_generated(manual: dict[str, Any], style: dict[str, Any], seed: int) -> None:
    """Apply a style's page effects to every step picture of a generated manual (the dict of
    ``_brickgeom.synth_manual``, drawn with the style's render settings), in place;
    deterministic for ``seed``."""
    if not style.get("image"):
        return
    builds = [manual["main"], *(s["build"] for s in manual["submodules"])]
    for b, build in enumerate(builds):
        for k, step in enumerate(build["steps"]):
            rng = np.random.default_rng([seed, b, k])
            step["rgb"] = page_effects(step["rgb"], style, rng)


def draw_step(
    manual: Manual,
    key: tuple[int | None, int],
    style: dict[str, Any],
    rng: np.random.Generator,
    components: dict[ComponentRef, _bg.Component] | None = None,
    ldraw_dir: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Step ``key`` (build: a submodule index or None for the main model, step index) of a
    manual with answers, drawn again in ``style`` from its true shape and camera: the picture
    (H, W, 3) uint8 at the manual's size and its instance map (H, W) int32 of the build's
    instance ids (-1 on the page). The step's instances are marked new, earlier ones old. With
    the built-in meshes the instance map is the manual's own (the style changes only colours);
    ``ldraw_dir`` is used when the style asks for LDraw meshes."""
    from mepnet.manual import answers_of

    build, k = key
    answers = answers_of(manual)
    comps = components if components is not None else answers.components(manual)
    truth = answers.build(build)
    page = manual.main if build is None else manual.submodules[build]
    step = page.steps[k]
    # instances in build order, as the generator draws them (the same order breaks depth ties)
    shown = sorted(i for s in truth.steps[: k + 1] for i in s.instance_ids)
    new = set(truth.steps[k].instance_ids)
    asm = _bg.Assembly()
    lut = np.full(len(shown) + 1, -1, dtype=np.int32)  # asm id -> build id; last: the page
    new_ids, old_ids = [], []
    for i in shown:
        inst = truth.instances[i]
        iid = asm.add(comps[inst.component], inst.yaw, inst.t, inst.colour)
        lut[iid] = i
        (new_ids if i in new else old_ids).append(iid)
    generator = manual.source.get("generator") if isinstance(manual.source, dict) else None
    supersample = generator.get("supersample", 1) if isinstance(generator, dict) else 1
    w, h = manual.image_size
    r = _bg.render(
        asm,
        step.camera_object(),
        w,
        h,
        supersample=supersample if supersample in (1, 3) else 1,
        ldraw_dir=ldraw_dir if style.get("meshes") == "ldraw" else None,
        style=render_style(style),
        new_ids=new_ids,
        old_ids=old_ids,
    )
    ids = lut[r.ids]  # -1 indexes the page's entry
    return page_effects(r.rgb, style, rng), ids


def restyled_step(
    manual: Manual,
    key: tuple[int | None, int],
    rng: np.random.Generator,
    components: dict[ComponentRef, _bg.Component] | None = None,
    ldraw_dir: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Step ``key`` drawn in a style drawn from ``rng`` (:func:`draw_style`, at the manual's
    size): the picture and instance map of :func:`draw_step`. For training: the sample shows
    another renderer's look while its targets stay exact."""
    style = draw_style(rng, max(manual.image_size), ldraw=ldraw_dir is not None)
    return draw_step(manual, key, style, rng, components, ldraw_dir)


def style_summary(style: dict[str, Any]) -> str:
    """A few words on a style (for captions)."""
    r, im = style.get("render", {}), style.get("image", {})
    if not r and not im:
        return "the renderer's own look"
    words = [r.get("shading", "lambert"), f"lines {r.get('lines', 'all')}"]
    if r.get("lines", "all") != "none":
        colour = r.get("line_colour", "auto")
        words.append(colour if isinstance(colour, str) else "fixed")
    if r.get("saturation", 1.0) < 1:
        words.append("muted")
    elif r.get("saturation", 1.0) > 1:
        words.append("saturated")
    if r.get("highlight"):
        words.append("highlight")
    if r.get("fade"):
        words.append("fade")
    if r.get("background"):
        words.append("tint")
    words += [k for k in ("grain", "blur", "jpeg") if k in im]
    if "scale" in im:
        words.append("low-res")
    if style.get("meshes") == "ldraw":
        words.append("LDraw meshes")
    return ", ".join(words)


def contact_sheet(
    manual: Manual,
    key: tuple[int | None, int],
    styles: list[dict[str, Any]],
    columns: int = 4,
    tile: int = 256,
    ldraw_dir: str | None = None,
) -> np.ndarray:
    """One step drawn in each style, tiled ``columns`` wide with a caption under each."""
    import textwrap

    from PIL import Image, ImageDraw

    caption = 26
    rows = (len(styles) + columns - 1) // columns
    sheet = Image.new("RGB", (columns * tile, rows * (tile + caption)), (255, 255, 255))
    pen = ImageDraw.Draw(sheet)
    for n, style in enumerate(styles):
        rgb, _ = draw_step(manual, key, style, np.random.default_rng(n), ldraw_dir=ldraw_dir)
        im = Image.fromarray(rgb).resize((tile, tile), Image.Resampling.BILINEAR)
        x, y = (n % columns) * tile, (n // columns) * (tile + caption)
        sheet.paste(im, (x, y))
        pen.rectangle([x, y, x + tile - 1, y + tile - 1], outline=(200, 200, 200))
        text = textwrap.wrap(f"{n + 1}. {style_summary(style)}", width=tile // 6)[:2]
        pen.multiline_text((x + 3, y + tile + 1), "\n".join(text), fill=(0, 0, 0), spacing=1)
    return np.asarray(sheet)


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m mepnet.styles`` argument parser."""
    from mepnet.cli import ArgumentParser

    ap = ArgumentParser(
        prog="python -m mepnet.styles",
        description="A contact sheet: one step of a generated manual in the styles that "
        "`mepnet.synth --styles` gives the manuals of the first seeds.",
    )
    ap.add_argument("--sheet", required=True, type=Path, help="PNG to write (256 colours)")
    ap.add_argument("--seed", type=int, default=990008, help="manual seed (default 990008)")
    ap.add_argument("--step", type=int, default=20, help="step number (default 20)")
    ap.add_argument("--styles", type=int, default=12, help="how many styles (default 12)")
    ap.add_argument(
        "--ldraw-dir",
        default=os.environ.get("LDRAWDIR"),
        help="LDraw library for the styles that use real part geometry (default: $LDRAWDIR)",
    )
    return ap


def main(argv: list[str] | None = None) -> int:
    """Entry point: write the contact sheet; returns the exit status."""
    from mepnet.cli import run

    args = build_parser().parse_args(argv)
    return run("mepnet.styles", lambda: _main(args))


def _main(args: argparse.Namespace) -> int:
    import tempfile

    from PIL import Image

    from mepnet.manual import load_manual, write_manual

    if not 1 <= args.styles <= 64:
        raise ConfigError(f"--styles must be within 1..64, got {args.styles}")
    manual_dict = _bg.synth_manual(args.seed, {"image_size": 256})
    n_steps = len(manual_dict["main"]["steps"])
    if not 1 <= args.step <= n_steps:
        raise ConfigError(f"--step must be within 1..{n_steps} for manual {args.seed}")
    # the renderer's own look first, then the styles of seeds 0, 1, ... that differ from it
    styles, seed = [default_style()], 0
    while len(styles) < args.styles:
        style = manual_style(seed, 256, ldraw=args.ldraw_dir is not None)
        seed += 1
        if style["render"] or style["image"]:
            styles.append(style)
    with tempfile.TemporaryDirectory() as tmp:
        source = {"kind": "synthetic", "seed": args.seed, "generator": {"image_size": 256}}
        manual = load_manual(
            write_manual(Path(tmp) / "manual", manual_dict, source, writer="mepnet.styles")
        )
        sheet = contact_sheet(manual, (None, args.step - 1), styles, ldraw_dir=args.ldraw_dir)
    # a 256-colour palette keeps the sheet small (paper grain does not compress)
    small = Image.fromarray(sheet).quantize(
        colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
    )
    small.save(args.sheet, optimize=True)
    for n, style in enumerate(styles):
        print(f"{n + 1}. {style_summary(style)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
