"""mepnet's pictures of real models next to an established LDraw renderer's (LeoCAD).

For each model: ``python -m mepnet.ldraw to-manual`` draws it (front-left three-quarter view,
elevation 30, azimuth 315, real part geometry) and LeoCAD draws, from the same view
(``--camera-angles 30 -45 --orthographic``), (a) the parts mepnet converted (the manual's
answers: the final shape, submodules expanded, written back to LDraw with mepnet's
``ldraw_placement``), and (b) the whole original file. The final pictures are reduced to silhouettes
(pixels unlike the page colour), cropped to their bounding boxes and resized to 96x96; the table
gives the IoU of mepnet's silhouette with LeoCAD's and with LeoCAD's mirrored left-right. Same
handedness: the first is high and clearly above the second. (b) is lower for every model
because mepnet draws only the parts it converts.

    python tests/external/compare_renderer.py [MODEL.mpd ...] [--json OUT]

Needs ``leocad`` and ``xvfb-run`` (Debian: ``apt-get install leocad xvfb xauth``) and the shared
LDraw library (``../shared/ldraw``); default models: every file in ``../shared/real/models``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from mepnet.geom import rotate_lattice
from mepnet.ldraw.io import ldraw_placement
from mepnet.manual import answers_of, load_manual
from mepnet.manual.images import read_instance_map
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared"
SIDE = 96


def crop(fg: np.ndarray, what: object) -> np.ndarray:
    """The silhouette cropped to its bounding box, resized to SIDE x SIDE."""
    if not fg.any():
        raise ValueError(f"{what}: the picture is empty")
    rows, cols = np.nonzero(fg)
    fg = fg[rows.min() : rows.max() + 1, cols.min() : cols.max() + 1]
    img = Image.fromarray(fg.astype(np.uint8) * 255).resize((SIDE, SIDE), Image.NEAREST)
    return np.asarray(img) > 127


def our_silhouette(step_image: Path) -> np.ndarray:
    """mepnet's own picture: its instance map (white parts on the white page count too)."""
    ids = read_instance_map(step_image.with_name(step_image.stem + "_ids.png"))
    return crop(ids >= 0, step_image)


def silhouette(path: Path) -> np.ndarray:
    """The opaque pixels (LeoCAD writes a transparent page), else the pixels unlike the page
    colour (the median of the border); cropped and resized."""
    img = Image.open(path)
    alpha = np.asarray(img.convert("RGBA"))[..., 3]
    if img.mode == "RGBA" and (alpha < 128).any():
        fg = alpha >= 128
    else:
        rgb = np.asarray(img.convert("RGB"), dtype=np.int32)
        border = np.concatenate([rgb[0], rgb[-1], rgb[:, 0], rgb[:, -1]])
        fg = np.abs(rgb - np.median(border, axis=0)).sum(axis=2) > 40
    return crop(fg, path)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def leocad(model: Path, out: Path, ldraw: Path) -> None:
    cmd = [
        "xvfb-run", "-a", "leocad", "-l", str(ldraw), "-i", str(out), "-w", "512", "-h", "512",
        "--camera-angles", "30", "-45", "--orthographic", str(model),
    ]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True, timeout=300)


def ours(model: Path, folder: Path, ldraw: Path) -> Path:
    cmd = [
        sys.executable, "-m", "mepnet.ldraw", "to-manual", str(model), "--out", str(folder),
        "--ldraw-dir", str(ldraw), "--size", "256", "--supersample", "1",
    ]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True, timeout=600)
    return sorted(folder.glob("step_*[0-9].png"))[-1]


def written_back(manual: Path, out: Path) -> Path:
    """The converted final shape (the manual's answers, submodules expanded) as one flat LDraw
    file, every part placed with mepnet's lattice -> LDraw conversion."""
    m = load_manual(manual)
    answers = answers_of(m)
    comps = answers.components(m)
    asm = answers.main.assembly_before(len(m.main.steps), comps)
    lines = ["0 FILE converted.ldr"]
    for _, comp, yaw, t in asm.instances():
        for part, byaw, bt, colour in comp.bricks:
            r = rotate_lattice(bt, yaw)
            pos, mat = ldraw_placement((yaw + byaw) % 4, (r[0] + t[0], r[1] + t[1], r[2] + t[2]))
            nums = " ".join(f"{v:g}" for v in [*pos, *(x for row in mat for x in row)])
            lines.append(f"1 {colour} {nums} {part}.dat")
    out.write_text("\n".join([*lines, "0 NOFILE", ""]))
    return out


def compare(model: Path, ldraw: Path, work: Path) -> dict[str, float | str]:
    work.mkdir(parents=True, exist_ok=True)
    mine = our_silhouette(ours(model, work / "manual", ldraw))
    row: dict[str, float | str] = {"model": model.name}
    for key, source in (
        ("converted", written_back(work / "manual", work / "converted.ldr")),
        ("original", model),
    ):
        theirs = work / f"leocad_{key}.png"
        leocad(source, theirs, ldraw)
        b = silhouette(theirs)
        row[key] = round(iou(mine, b), 3)
        row[f"{key}_mirrored"] = round(iou(mine, b[:, ::-1]), 3)
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="*", type=Path)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    if shutil.which("leocad") is None or shutil.which("xvfb-run") is None:
        print("compare_renderer: error: needs leocad and xvfb-run", file=sys.stderr)
        return 2
    ldraw = SHARED / "ldraw"
    models = args.models or sorted((SHARED / "real" / "models").glob("*.mpd"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, m in enumerate(models):
            rows.append(compare(m, ldraw, Path(tmp) / str(i)))
            r = rows[-1]
            print(
                f"| {r['model']} | {r['converted']:.3f} | {r['converted_mirrored']:.3f} "
                f"| {r['original']:.3f} | {r['original_mirrored']:.3f} |",
                flush=True,
            )
    for key in ("converted", "original"):
        a = np.array([r[key] for r in rows], dtype=float)
        b = np.array([r[f"{key}_mirrored"] for r in rows], dtype=float)
        print(
            f"{key}: median IoU {np.median(a):.3f} (mirrored {np.median(b):.3f}); "
            f"{int((a > b).sum())} of {len(rows)} models closer unmirrored"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
