"""Stage-2 speed: seconds per step of brickgeom's pose inference from oracle detections, on fresh
synthetic manuals, split into primitive-only and submodule steps; and, for the keypoint
matching itself (no masks), a ratio against a straightforward NumPy implementation of the same
matching (the same ray search over heights, the same validity rules, the same greedy order),
measured in the same run on the same steps, answers checked equal.

Targets (issue: stage 2): median <= 5 ms per primitive-only step, <= 50 ms per submodule step.

    python tests/benchmarks/bench_stage2.py --out docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench_geom import NumpyAssembly, replace_section, rot_cells  # noqa: E402
from conftest import generate_manuals  # noqa: E402
from mepnet import _brickgeom as _bg  # noqa: E402
from mepnet.manual import answers_of, iter_manual_dirs, load_manual  # noqa: E402
from mepnet.stage2 import StepContext  # noqa: E402
from mepnet.stage2.baselines import truth_detections  # noqa: E402

UNIT = np.array([10.0, 8.0, 10.0])


def rot_ldu(p: np.ndarray, yaw: int) -> np.ndarray:
    x, y, z = p
    return np.array([(x, y, z), (z, y, -x), (-x, y, -z), (-z, y, x)][yaw % 4], dtype=float)


def numpy_best(ref: NumpyAssembly, lo, hi, comp, yaw, kp, cam_px, view, max_err=6.0):
    """The same ray search as brickgeom's stage 2, in NumPy: (error, depth, t) or None."""
    a = rot_ldu(comp.keypoints[0].astype(float), yaw)
    base = cam_px[:, :3] @ a + cam_px[:, 3]
    j = cam_px[:, :3] * UNIT
    cv = rot_cells(comp.voxels, yaw)
    ys = np.arange(-cv[:, 1].min(), hi[1] + 1 - cv[:, 1].min() + 2)
    m = j[:, [0, 2]]
    rhs = np.asarray(kp)[None, :] - base[None, :] - ys[:, None] * j[:, 1][None, :]
    xz = np.linalg.solve(m, rhs.T).T  # (H, 2)
    d = np.arange(-2, 3)
    gx, gz = np.meshgrid(d, d, indexing="ij")
    ts = np.stack(
        [
            (np.round(xz[:, 0])[:, None] + gx.ravel()[None, :]).ravel(),
            np.repeat(ys, gx.size),
            (np.round(xz[:, 1])[:, None] + gz.ravel()[None, :]).ravel(),
        ],
        axis=1,
    ).astype(np.int64)
    codes = ref.check_many(comp, yaw, ts)
    ok = ts[codes >= 0]
    if len(ok) == 0:
        return None
    world = a[None, :] + ok * UNIT
    px = world @ cam_px[:, :3].T + cam_px[:, 3]
    err = np.linalg.norm(px - np.asarray(kp)[None, :], axis=1)
    keep = err <= max_err
    if not keep.any():
        return None
    ok, err, world = ok[keep], err[keep], world[keep]
    depth = world @ view
    tied = err <= err.min() + 2.5
    order = np.lexsort((err[tied], depth[tied]))  # nearest first among ties
    i = np.flatnonzero(tied)[order[0]]
    return float(err[i]), tuple(int(v) for v in ok[i])


def numpy_step(base: _bg.Assembly, ctx: StepContext, types) -> list:
    """Greedy sequential placement as in brickgeom, with the NumPy search."""
    cam = ctx.camera
    w, h = ctx.image_size
    cam_px = cam.pixel_matrix(w, h)
    view = cam.rotation()[2]
    asm = base.copy()
    pending = [(ti, di) for ti, t in enumerate(types) for di in range(t["count"])]
    placed = []
    while pending:
        ref = NumpyAssembly.from_assembly(asm) if len(asm) else None
        found = []
        for ti, di in pending:
            t = types[ti]
            det = t["detections"][di]
            yaw = (
                int(np.argmax(det["rotation"][3:]))
                if t["component"].symmetry == 1
                else (0 if t["component"].symmetry == 4 else int(np.argmax(det["rotation"][1:3])))
            )
            if ref is None:
                found.append(None)
                continue
            lo, hi = asm.bounds()
            found.append(
                numpy_best(ref, lo, hi, t["component"], yaw, det["keypoint"], cam_px, view)
            )
        best = min((f[0], i) for i, f in enumerate(found) if f is not None) if any(found) else None
        if best is None:
            break
        i = best[1]
        ti, di = pending.pop(i)
        t_best = found[i][1]
        det = types[ti]["detections"][di]
        comp = types[ti]["component"]
        yaw = (
            int(np.argmax(det["rotation"][3:]))
            if comp.symmetry == 1
            else (0 if comp.symmetry == 4 else int(np.argmax(det["rotation"][1:3])))
        )
        asm.add(comp, yaw, t_best)
        placed.append((ti, yaw, t_best))
    return placed


def plain_types(types) -> list[dict]:
    """Per-type detections (:class:`mepnet.stage2.keypoint.DetectedType`) as plain Python
    values, for the NumPy reference."""
    return [
        {
            "component": t.component,
            "count": t.count,
            "detections": [
                {
                    "keypoint": tuple(t.detections.keypoints[j]),
                    "rotation": t.detections.rotations[j].tolist(),
                }
                for j in range(len(t.detections))
            ],
        }
        for t in types
    ]


def binding_types(types, masks: bool = True) -> list[_bg.StepDetections]:
    """Per-type detections as the binding's ``infer_step`` takes them (``masks=False``: the
    keypoint matching alone)."""
    return [
        _bg.StepDetections(
            t.component,
            t.count,
            np.ascontiguousarray(t.detections.keypoints, np.float64),
            np.ascontiguousarray(t.detections.scores, np.float32),
            np.ascontiguousarray(t.detections.rotations, np.float32),
            np.ascontiguousarray(t.detections.masks, bool) if masks else None,
        )
        for t in types
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/benchmarks.md")
    ap.add_argument("--manuals", type=int, default=20)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        generate_manuals(Path(d), args.manuals, 900000)
        prim, subm, ours_match, ref_match = [], [], [], []
        agree = compared = 0
        for md in iter_manual_dirs(d):
            man = load_manual(md)
            answers = answers_of(man)
            comps = answers.components(man)
            for key, b in man.builds():
                base = _bg.Assembly()
                for k, step in enumerate(b.steps):
                    truth = answers.build(key).truth(k)
                    ctx = StepContext(
                        step=step, base=base, components=comps, image_size=man.image_size
                    )
                    w, h = man.image_size
                    types = truth_detections(ctx, truth, 0.0, None)
                    with_masks = binding_types(types)
                    t0 = time.perf_counter()
                    _bg.infer_step(base, ctx.camera, w, h, with_masks)
                    dt = time.perf_counter() - t0
                    has_sub = any(sc.component.submodule is not None for sc in step.components)
                    (subm if has_sub else prim).append(dt)
                    if not has_sub and len(base):
                        nomask, plain = binding_types(types, masks=False), plain_types(types)
                        t0 = time.perf_counter()
                        ours = _bg.infer_step(base, ctx.camera, w, h, nomask)
                        t1 = time.perf_counter()
                        theirs = numpy_step(base, ctx, plain)
                        t2 = time.perf_counter()
                        ours_match.append(t1 - t0)
                        ref_match.append(t2 - t1)
                        compared += 1
                        agree += int(
                            sorted((o.type, o.yaw, o.t) for o in ours if o.t is not None)
                            == sorted(theirs)
                        )
                    for i in truth.placed():
                        base.add(comps[i.component], i.yaw, i.t)
    med = lambda x: 1e3 * float(np.median(x))  # noqa: E731
    tot = lambda x: 1e3 * float(np.sum(x))  # noqa: E731
    lines = [
        "## Stage 2: pose inference",
        "",
        f"`tests/benchmarks/bench_stage2.py` on {args.manuals} fresh synthetic manuals (seed 900000, 256 px), "
        f"oracle detections with masks, ground-truth base shapes; this machine ({os.cpu_count()} cores). "
        "Targets: median <= 5 ms per primitive-only step, <= 50 ms per submodule step.",
        "",
        "| steps | count | median (ms) | mean (ms) | p95 (ms) |",
        "|---|---:|---:|---:|---:|",
        f"| primitive-only | {len(prim)} | {med(prim):.2f} | {1e3 * np.mean(prim):.2f} | {1e3 * np.percentile(prim, 95):.2f} |",
        f"| with a submodule | {len(subm)} | {med(subm):.2f} | {1e3 * np.mean(subm):.2f} | {1e3 * np.percentile(subm, 95):.2f} |",
        "",
        "Keypoint matching alone (no masks; primitive-only steps with a non-empty base), brickgeom vs "
        "the NumPy reference in the benchmark (same search, same rules, same greedy order; chosen poses "
        f"equal on {agree}/{compared} steps):",
        "",
        "| implementation | total (ms) | median per step (ms) |",
        "|---|---:|---:|",
        f"| brickgeom | {tot(ours_match):.1f} | {med(ours_match):.3f} |",
        f"| NumPy reference | {tot(ref_match):.1f} | {med(ref_match):.3f} |",
        f"| ratio | {np.sum(ref_match) / np.sum(ours_match):.1f}x | {np.median(ref_match) / np.median(ours_match):.1f}x |",
    ]
    print("\n".join(lines))
    replace_section(args.out, "bench_stage2", "\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
