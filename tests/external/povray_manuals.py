"""Synthetic manuals with every step picture redrawn by POV-Ray (a ray tracer: a second renderer
never used in training, drawn unlike mepnet and unlike LeoCAD: no edge lines, a key light with
cast shadows, specular highlights, the real LDraw part meshes).

    python tests/external/povray_manuals.py --data IN --out OUT [--workers N] [--size-check]

copies the manual folders under IN (with answers) to OUT and redraws every step image, main
build and submodule builds, with POV-Ray; ``manual.json``, the answers and the instance maps
are copied unchanged, so ``python -m mepnet.eval --data OUT`` scores mepnet on POV-Ray's
pictures with the same geometry, cameras and truth.

Per step: the shape after the step as flat LDraw (``leocad_manuals.step_ldraw``: mepnet's
lattice -> LDraw placement), each part's real geometry from the LDraw library
(``mepnet._brickgeom.load_part_mesh``) in the part's colour (LDraw's ``LDConfig.ldr``), drawn
by POV-Ray orthographically from the step's camera, set exactly from mepnet's camera (eye
direction, image axes with roll, scale and translation; LDraw -> POV-Ray: y negated, a
left-handed frame as POV-Ray's). Lights are fixed to the camera: a key light from the upper
left that casts shadows, a weaker fill from the right, ambient light. The picture is drawn at
twice the manual's size with anti-aliasing on a transparent page, aligned to mepnet's framing
by the same silhouette similarity as LeoCAD's (``leocad_manuals.align``: here almost the
identity, which checks the camera), composed onto a white page and reduced. A step whose
silhouette IoU after alignment is below 0.9 FAILs (exit status 1 at the end); the IoU of the
best alignment of the picture mirrored left-right is recorded (same handedness: the unmirrored
wins). ``OUT/povray_report.json`` holds the per-step figures.

OUT is written to a temporary folder beside it and renamed at the end; an existing OUT is never
touched (exit 2). Needs ``povray`` (3.7; Debian: ``apt-get install povray``) and the LDraw
library (``../shared/ldraw`` beside the clone, or ``--ldraw``).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import leocad_manuals as lm  # noqa: E402
from mepnet import BrickGeomError  # noqa: E402
from mepnet import _brickgeom as _bg  # noqa: E402
from mepnet.errors import MepnetError  # noqa: E402
from mepnet.files import atomic_folder  # noqa: E402
from mepnet.manual import answers_of, load_manual  # noqa: E402
from mepnet.manual.images import read_instance_map  # noqa: E402
from PIL import Image  # noqa: E402

PROG = "povray_manuals"
REPORT = "povray_report.json"
MIN_IOU = lm.MIN_IOU
SUPERSAMPLE = lm.SUPERSAMPLE
#: How far (LDU) the orthographic camera's plane stands from the view centre, towards the eye.
EYE_DISTANCE = 20000.0

SCENE_HEAD = """#version 3.7;
global_settings { assumed_gamma 1.0 ambient_light rgb 1 max_trace_level 5 }
background { rgbt <1, 1, 1, 1> }
#declare F = finish { ambient 0.18 diffuse 0.78 specular 0.35 roughness 0.015 }
"""


def pov(p: np.ndarray) -> str:
    return f"<{p[0]:.6f}, {p[1]:.6f}, {p[2]:.6f}>"


def pov_camera(cam: dict[str, Any], aspect: float) -> str:
    """POV-Ray's camera for a mepnet step camera, in POV-Ray's frame (mepnet's world with z
    negated: LDraw's with y negated). The view centre is the point mepnet draws at NDC (0, 0),
    the view is 2/scale LDU high, the image's right and up are mepnet's u and v."""
    eye, u, v = lm.camera_axes(cam)
    s = float(cam["scale"])
    tx, ty = cam["translation"]
    centre = -(tx / s) * u - (ty / s) * v
    f = np.array([1.0, 1.0, -1.0])  # mepnet world -> POV-Ray
    height = 2.0 / s
    return (
        "camera { orthographic\n"
        f"  location {pov(f * (centre + EYE_DISTANCE * eye))}\n"
        f"  direction {pov(f * -eye)}\n"
        f"  right {pov(f * u * height * aspect)}\n"
        f"  up {pov(f * v * height)}\n}}\n"
        # lights fixed to the camera: key from the upper left (shadows), fill from the right
        f"light_source {{ {pov(f * (centre + EYE_DISTANCE * (eye + 0.9 * v - 0.7 * u)))} "
        "color rgb 0.75 parallel point_at "
        f"{pov(f * centre)} }}\n"
        f"light_source {{ {pov(f * (centre + EYE_DISTANCE * (eye + 0.2 * v + 0.9 * u)))} "
        "color rgb 0.3 parallel point_at "
        f"{pov(f * centre)} shadowless }}\n"
    )


_MESHES: dict[str, str] = {}


def part_mesh(ldraw: Path, part: str) -> str:
    """``mesh2`` body of an LDraw part's real geometry in LDraw's frame (the library gives
    brickgeom's frame: LDraw's y and z negated)."""
    if part not in _MESHES:
        v, t, _ = _bg.load_part_mesh(str(ldraw), part)
        v = v.astype(np.float64) * np.array([1.0, -1.0, -1.0])
        verts = ",".join(f"<{a:.3f},{b:.3f},{c:.3f}>" for a, b, c in v)
        faces = ",".join(f"<{a},{b},{c}>" for a, b, c in t)
        _MESHES[part] = (
            f"vertex_vectors {{ {len(v)}, {verts} }}\nface_indices {{ {len(t)}, {faces} }}"
        )
    return _MESHES[part]


def colour_rgb(code: int, ldraw: Path) -> tuple[float, float, float]:
    if code >= 0x2000000:  # direct colour 0x2RRGGBB
        r, g, b = (code >> 16) & 255, (code >> 8) & 255, code & 255
    else:
        r, g, b = _bg.colour_rgb(code, str(ldraw))
    return r / 255, g / 255, b / 255


def scene(ldr_text: str, cam: dict[str, Any], aspect: float, ldraw: Path) -> str:
    """The POV-Ray scene of a flat LDraw file (type-1 lines only) from a step camera."""
    declared: dict[str, str] = {}
    objects = []
    for line in ldr_text.splitlines():
        f = line.split()
        if not f or f[0] != "1":
            continue
        code = int(f[1], 0)
        x, y, z, a, b, c, d, e, g, h, i, j = (float(q) for q in f[2:14])
        part = f[14].lower().removesuffix(".dat")
        if part not in declared:
            declared[part] = f"P{len(declared)}"
        r, gr, bl = colour_rgb(code, ldraw)
        # LDraw: p' = M p + t with M = [[a b c] [d e g] [h i j]]; POV-Ray's matrix lists the
        # columns of M, then t
        objects.append(
            f"object {{ {declared[part]} texture {{ pigment {{ srgb <{r:.4f},{gr:.4f},{bl:.4f}> }}"
            f" finish {{ F }} }} matrix <{a},{d},{h}, {b},{e},{i}, {c},{g},{j}, {x},{y},{z}> }}"
        )
    meshes = [f"#declare {n} = mesh2 {{ {part_mesh(ldraw, p)} }}" for p, n in declared.items()]
    body = "\n".join(objects)
    return (
        SCENE_HEAD
        + pov_camera(cam, aspect)
        + "\n".join(meshes)
        + f"\nunion {{\n{body}\nscale <1, -1, 1>\n}}\n"
    )


def run_povray(pov_file: Path, png: Path, w: int, h: int) -> np.ndarray:
    """POV-Ray's RGBA picture (h x w) of a scene; retried once."""
    cmd = [
        "nice", "-n", "10", "povray", f"+I{pov_file}", f"+O{png}", f"+W{w}", f"+H{h}", "+UA",
        "+A0.1", "+AM2", "+R2", "+FN", "-D", "+Q9", "-V", "-GA",
    ]  # fmt: skip
    err = ""
    for _ in range(2):
        png.unlink(missing_ok=True)
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=pov_file.parent)
        if r.returncode == 0 and png.is_file():
            with Image.open(png) as im:
                return np.asarray(im.convert("RGBA"))
        err = (r.stderr.strip().splitlines() or [f"exit status {r.returncode}"])[-1]
    raise RuntimeError(f"povray failed on {pov_file.name}: {err}")


# ---------------------------------------------------------------------------------------------
# Workers

_W: dict[str, Any] = {}


def _init(ldraw: str, tmp: str) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C
    os.nice(10)
    work = Path(tempfile.mkdtemp(prefix="povray-w", dir=tmp))
    _W.update(ldraw=Path(ldraw), work=work, manuals={})


def _manual(src: str) -> Any:
    cache = _W["manuals"]
    if src not in cache:
        cache.clear()
        cache[src] = load_manual(src)
    return cache[src]


def redraw_step(job: tuple[str, str, int | None, int]) -> dict[str, Any]:
    """Draw one step with POV-Ray, align it, write the picture; returns the step's figures.
    ``job``: (manual folder, output folder or "" for none, build key, step k (1-based))."""
    src, dst, key, k = job
    manual = _manual(src)
    build = manual.main if key is None else manual.submodules[key]
    step = build.steps[k - 1]
    ans = answers_of(manual).build(key).steps[k - 1]
    w, h = manual.image_size
    work: Path = _W["work"]
    pov_file = work / "step.pov"
    size = SUPERSAMPLE * max(w, h)
    pov_file.write_text(scene(lm.step_ldraw(manual, key, k), step.camera, 1.0, _W["ldraw"]))
    t0 = time.perf_counter()
    rgba = run_povray(pov_file, work / "step.png", size, size)
    seconds = time.perf_counter() - t0
    assert ans.ids_path is not None
    mask = read_instance_map(ans.ids_path, (w, h)) >= 0
    row: dict[str, Any] = {
        "manual": Path(src).name,
        "build": build.name,
        "step": k,
        "image": step.image_path.name,
        "leocad_s": round(seconds, 3),  # (the renderer's seconds: the key leocad_manuals sums)
    }
    target = Path(dst) / step.image_path.relative_to(manual.path) if dst else None
    return lm.place_picture(rgba, mask, (w, h), row, target, "POV-Ray")


# ---------------------------------------------------------------------------------------------
# The command


def draw(jobs: list[tuple[str, str, int | None, int]], workers: int, ldraw: Path) -> list[Any]:
    rows: list[dict[str, Any]] = []
    work = Path(tempfile.mkdtemp(prefix="povray-work-"))
    try:
        p = mp.get_context("fork").Pool(
            workers, initializer=_init, initargs=(str(ldraw), str(work))
        )
        try:
            for i, r in enumerate(p.imap(redraw_step, jobs)):
                rows.append(r)
                if not r["ok"]:
                    print(f"FAIL {r['manual']} {r['build']} step {r['step']}: IoU "
                          f"{r['iou']:.3f} {r.get('problem', '')}".rstrip(), flush=True)  # fmt: skip
                if (i + 1) % 50 == 0 or i + 1 == len(jobs):
                    print(f"{i + 1}/{len(jobs)} steps drawn", file=sys.stderr, flush=True)
            p.close()
            p.join()
        finally:
            p.terminate()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, type=Path, help="a manual folder or a folder of them")
    ap.add_argument("--out", type=Path, help="output folder (must not exist)")
    ap.add_argument("--size-check", action="store_true",
                    help="draw a few steps of the first manual and print their fit; write nothing")  # fmt: skip
    ap.add_argument("--workers", type=int, default=2, help="POV-Ray processes (default 2)")
    ap.add_argument("--ldraw", type=Path, default=lm.SHARED / "ldraw", help="LDraw library")
    args = ap.parse_args(argv)
    try:
        if not 1 <= args.workers <= 16:
            raise lm.InputError(f"--workers must be 1..16, got {args.workers}")
        if not args.size_check:
            if args.out is None:
                raise lm.InputError("--out is required (or --size-check)")
            if args.out.exists() or args.out.is_symlink():
                raise lm.InputError(f"--out {args.out}: already exists (choose a new folder)")
        manuals = lm.check_inputs(args.data, args.ldraw, ("povray", "nice"), "povray", "POV-Ray")
    except lm.InputError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    os.nice(10)
    try:
        if args.size_check:
            m = manuals[0]
            n = len(m.main.steps)
            jobs = [(str(m.path), "", None, k) for k in sorted({1, 2, max(1, n // 2), n})]
            for r in draw(jobs, args.workers, args.ldraw):
                print(f"{r['manual']} {r['build']} step {r['step']}: IoU {r['iou']:.3f} "
                      f"(mirrored {r['iou_mirrored']:.3f}), size ratio {r.get('scale', math.nan):.4f}, "
                      f"shift {r.get('shift_px')} px, {r['leocad_s']:.2f} s")  # fmt: skip
            return 0
        return redraw_all(manuals, args)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted (nothing written)", file=sys.stderr)
        return 130
    except (RuntimeError, OSError, BrickGeomError, MepnetError) as e:
        print(f"{PROG}: error: {str(e).splitlines()[0]} (nothing written)", file=sys.stderr)
        return 1


def redraw_all(manuals: list[Any], args: argparse.Namespace) -> int:
    started = time.time()
    with atomic_folder(args.out, PROG, replace=False) as tmp:
        rows = draw(lm.copy_manuals(manuals, tmp), args.workers, args.ldraw)
        s = lm.summary(rows)
        s["povray_s_mean"] = s.pop("leocad_s_mean")
        s["seconds"] = round(time.time() - started, 1)
        s["command"] = " ".join(["python", "tests/external/povray_manuals.py", *sys.argv[1:]])
        s["alignment"] = (
            "POV-Ray ndc = scale * mepnet ndc + shift (the camera is set exactly: about the "
            "identity); iou: the written picture's alpha >= 0.5 against the instance map; "
            "iou_mirrored: the best alignment of the picture mirrored left-right"
        )
        (tmp / REPORT).write_text(json.dumps({"summary": s, "steps": rows}, indent=1) + "\n")
    i, mi = s["iou"], s["iou_mirrored"]
    print(f"{s['steps']} steps: silhouette IoU after alignment median {i['median']:.3f}, "
          f"5th percentile {i['p05']:.3f}, min {i['min']:.3f}; {s['failed']} below {MIN_IOU}; "
          f"mirrored median {mi['median']:.3f}; size ratio median "
          f"{(s['scale'] or {}).get('median', math.nan):.4f}; POV-Ray "
          f"{s['povray_s_mean']:.2f} s per picture")  # fmt: skip
    handed = i["median"] > mi["median"]
    if not handed:
        print("FAIL handedness: the mirrored picture fits better than the picture itself")
    print(f"wrote {len(manuals)} manual(s), {len(rows)} pictures, to {args.out} in "
          f"{s['seconds']:.0f} s (report: {args.out / REPORT})")  # fmt: skip
    return 0 if s["failed"] == 0 and handed else 1


if __name__ == "__main__":
    raise SystemExit(main())
