"""Manuals redrawn as another renderer might draw them, to measure robustness.

    python -m mepnet.restyle --data DIR --out OUT [--only gamma,sat,page,lines,blur]
                             [--strength S] [--seed N]

copies every manual folder under DIR to OUT and redraws its step images with one style per
manual (a renderer is consistent within a manual): a per-channel gamma (tone curve), a
saturation change, a tinted page, thick or faint outlines, and a light blur half the time. Geometry,
cameras, instance maps and ground truth are unchanged; ``manual.json`` records the style under
``source.restyle``. Each manual is written to a temporary folder and renamed when complete;
manuals already in OUT are left as they are.
"""

from __future__ import annotations

import argparse
import json
import shutil
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from mepnet.cli import ArgumentParser, run
from mepnet.errors import ConfigError
from mepnet.files import atomic_folder
from mepnet.manual import iter_manual_dirs, load_manual

#: What a style may change (``--only`` picks a subset).
FACTORS = ("gamma", "sat", "page", "lines", "blur")


def draw_style(rng: np.random.Generator, strength: float) -> dict[str, Any]:
    """A renderer's look: gamma per channel within exp(+-0.35 strength), saturation x
    (1 +- 0.3 strength), page colour down to 25 strength below white per channel, thick or
    faint lines, blur or not."""
    return {
        "gamma": np.exp(rng.uniform(-0.35, 0.35, size=3) * strength).round(3).tolist(),
        "sat": round(1 + float(rng.uniform(-0.3, 0.3)) * strength, 3),
        "page": (255 - rng.uniform(0, 25, size=3) * strength).round(1).tolist(),
        "lines": "thick" if rng.random() < 0.5 else "faint",
        "blur": bool(rng.random() < 0.5),
    }


def restyle_image(
    rgb: np.ndarray, ids: np.ndarray, style: dict[str, Any], rng: np.random.Generator
) -> np.ndarray:
    """One step image (H, W, 3 uint8; ``ids`` its instance map, -1 on the page) in ``style``
    (only the factors it names)."""
    from mepnet.detector.targets import blur, restyle_lines

    img = rgb.astype(np.float32)
    if "gamma" in style:
        img = 255 * (img / 255) ** np.asarray(style["gamma"], np.float32)
    if "sat" in style:
        grey = img.mean(axis=2, keepdims=True)
        img = grey + style["sat"] * (img - grey)
    if "page" in style:
        img[ids < 0] = style["page"]
    if "lines" in style:
        img = restyle_lines(img, ids, rng, style["lines"])
    if style.get("blur"):
        img = blur(img)
    return np.clip(img, 0, 255).round().astype(np.uint8)


def regions_of(rgb: np.ndarray) -> np.ndarray:
    """A stand-in for an instance map when the manual has no answers, (H, W) int32: the page
    (near-white pixels) is -1, everything else labelled by its colour quantised to 8 levels per
    channel, so that part edges and outlines fall where labels change."""
    q = (rgb.astype(np.int32) // 32).astype(np.int32)
    labels = (q[..., 0] * 64 + q[..., 1] * 8 + q[..., 2]).astype(np.int32)
    labels[(rgb >= 245).all(axis=2)] = -1
    return labels


def restyle_manual(src: Path, out: Path, only: tuple[str, ...], strength: float, seed: int) -> int:
    """Write ``out`` (must not exist) as ``src`` redrawn; returns the number of images. Lines
    are redrawn along the instance map's edges, or, for a manual without answers (as users have
    it), along the edges of the picture's own colour regions (:func:`regions_of`)."""
    from PIL import Image

    manual = load_manual(src)  # checks the folder and lists every step image
    rng = np.random.default_rng(
        [seed, zlib.crc32(src.resolve().name.encode("utf-8", "surrogateescape"))]
    )
    style = {k: v for k, v in draw_style(rng, strength).items() if k in only}
    with atomic_folder(out, "mepnet.restyle", replace=False) as tmp:
        for p in src.iterdir():
            if p.is_file() and not p.name.startswith("."):
                shutil.copyfile(p, tmp / p.name)
        steps = 0
        for key, build in manual.builds():
            for k, step in enumerate(build.steps):
                rel = step.image_path.relative_to(src)
                (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
                rgb = step.image()
                if manual.answers is not None and manual.answers.build(key).steps[k].ids_path:
                    ans = manual.answers.build(key).steps[k]
                    assert ans.ids_path is not None
                    target = tmp / ans.ids_path.relative_to(src)
                    if not target.exists():
                        target.parent.mkdir(parents=True, exist_ok=True)
                        shutil.copyfile(ans.ids_path, target)
                    ids = ans.ids()
                else:
                    ids = regions_of(rgb)
                img_rng = np.random.default_rng(
                    [seed, zlib.crc32(str(rel).encode("utf-8", "surrogateescape"))]
                )
                Image.fromarray(restyle_image(rgb, ids, style, img_rng)).save(tmp / rel)
                steps += 1
        doc = json.loads((tmp / "manual.json").read_text())
        doc.setdefault("source", {})["restyle"] = {"seed": seed, "strength": strength, **style}
        (tmp / "manual.json").write_text(json.dumps(doc, indent=1) + "\n")
    return steps


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m mepnet.restyle`` argument parser."""
    ap = ArgumentParser(prog="python -m mepnet.restyle", description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, type=Path, help="a manual folder or a folder of them")
    ap.add_argument("--out", required=True, type=Path, help="output folder")
    ap.add_argument(
        "--only",
        default=",".join(FACTORS),
        help=f"comma-separated factors to apply (default: all of {','.join(FACTORS)})",
    )
    ap.add_argument("--strength", type=float, default=1.0, help="style strength (default 1)")
    ap.add_argument("--seed", type=int, default=0, help="style seed (default 0)")
    return ap


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (2 on bad input, with one line on stderr)."""
    args = build_parser().parse_args(argv)
    return run("mepnet.restyle", lambda: _main(args))


def _main(args: argparse.Namespace) -> int:
    only = tuple(f for f in args.only.split(",") if f)
    unknown = [f for f in only if f not in FACTORS]
    if unknown or not only:
        raise ConfigError(f"--only: unknown factor(s) {unknown or only} (choose from {FACTORS})")
    if args.seed < 0:
        raise ConfigError(f"--seed must not be negative, got {args.seed}")
    if not (0.0 <= args.strength <= 2.0):
        raise ConfigError(f"--strength must be within 0..2, got {args.strength}")
    if not args.data.is_dir():
        raise ConfigError(f"--data {args.data}: not a folder")
    manuals = list(iter_manual_dirs(args.data))
    if not manuals:
        raise ConfigError(f"--data {args.data}: no manual folders (manual.json) there")
    args.out.mkdir(parents=True, exist_ok=True)
    done = 0
    for src in manuals:
        out = args.out / src.resolve().name  # (--data . names the folder it is)
        if out.exists():
            continue
        restyle_manual(src, out, only, args.strength, args.seed)
        done += 1
    print(f"restyled {done} manual(s) into {args.out} ({len(manuals) - done} already there)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
