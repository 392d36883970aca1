"""Benchmark of brickgeom's assembly checks against a NumPy reference, measured in the same run.

The reference is a straightforward vectorised NumPy implementation of the same rules
(free studs from the occupancy grid, stud/anti-stud matching, voxel collision, ground), written
here so both sides are measured on identical assemblies. Results are checked to agree before
any timing is reported.

    python tests/benchmarks/bench_geom.py --out docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from dataclasses import dataclass

import mepnet
import numpy as np

# ---------------------------------------------------------------------------------------------
# Building test assemblies


def grow_assembly(n: int, seed: int) -> mepnet.Assembly:
    """A random connected assembly of `n` parts, grown with candidate enumeration."""
    rng = np.random.default_rng(seed)
    ids = [p for p in mepnet.part_ids() if mepnet.part_info(p)["category"] in ("simple", "tile")]
    ids = [p for p in ids if len(mepnet.part_info(p)["studs"]) > 0] or ids
    asm = mepnet.Assembly()
    comps = {p: mepnet.Component.primitive(p) for p in ids}
    side = int(np.sqrt(n)) * 4 + 8
    while len(asm) < n:
        c = comps[ids[rng.integers(len(ids))]]
        yaw = int(rng.integers(4))
        # ground placements over a wide field keep the model low and wide, like real sets
        ground = (-side, side, -side, side) if rng.random() < 0.3 else None
        ts, kinds = asm.candidates(c, yaw, ground)
        if len(ts) == 0:
            continue
        t = ts[rng.integers(len(ts))]
        asm.add(c, yaw, tuple(int(v) for v in t))
    return asm


# ---------------------------------------------------------------------------------------------
# The NumPy reference


def rot_points(p: np.ndarray, yaw: int) -> np.ndarray:
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    return np.stack([(x, y, z), (z, y, -x), (-x, y, -z), (-z, y, x)][yaw % 4], axis=1)


def rot_cells(c: np.ndarray, yaw: int) -> np.ndarray:
    i, j, k = c[:, 0], c[:, 1], c[:, 2]
    return np.stack(
        [(i, j, k), (k, j, -i - 1), (-i - 1, j, -k - 1), (-k - 1, j, i)][yaw % 4], axis=1
    )


def key(p: np.ndarray) -> np.ndarray:
    p = p.astype(np.int64) + (1 << 20)
    return (p[..., 0] << 42) | (p[..., 1] << 21) | p[..., 2]


@dataclass
class NumpyAssembly:
    """Dense occupancy grid plus stud/anti-stud arrays, built from an Assembly's instances."""

    occ: np.ndarray
    origin: np.ndarray
    studs: np.ndarray
    anti: np.ndarray
    free_stud_points: np.ndarray | None = None
    free_anti_points: np.ndarray | None = None
    free_stud_keys: np.ndarray | None = None
    free_anti_keys: np.ndarray | None = None

    @classmethod
    def from_assembly(cls, asm: mepnet.Assembly) -> NumpyAssembly:
        (lo, hi) = asm.bounds()
        pad = 40
        lo = (lo[0] - pad, 0, lo[2] - pad)
        hi = (hi[0] + pad, hi[1] + pad, hi[2] + pad)
        occ, origin = asm.occupancy(lo, hi)
        studs, anti = [], []
        for _, comp, yaw, t in asm.instances():
            studs.append(rot_points(comp.studs, yaw) + np.array(t))
            anti.append(rot_points(comp.anti_studs, yaw) + np.array(t))
        ref = cls(occ.astype(bool), np.array(origin), np.concatenate(studs), np.concatenate(anti))
        # Like the Rust assembly, keep the free connection points of the current state.
        ref.free_stud_points = ref.free_studs()
        ref.free_anti_points = ref.free_anti_studs()
        ref.free_stud_keys = key(ref.free_stud_points)
        ref.free_anti_keys = key(ref.free_anti_points)
        return ref

    def filled(self, cells: np.ndarray) -> np.ndarray:
        idx = cells - self.origin
        inside = np.all((idx >= 0) & (idx < np.array(self.occ.shape)), axis=-1)
        out = np.zeros(cells.shape[:-1], dtype=bool)
        ii = idx[inside]
        out[inside] = self.occ[ii[:, 0], ii[:, 1], ii[:, 2]]
        return out

    def _around(self, p: np.ndarray, layer: np.ndarray) -> np.ndarray:
        d = np.array([[-1, 0, -1], [0, 0, -1], [-1, 0, 0], [0, 0, 0]])
        base = p.copy()
        base[:, 1] = layer
        return base[:, None, :] + d[None, :, :]

    def free_studs(self) -> np.ndarray:
        s = np.unique(self.studs, axis=0)
        return s[~self.filled(self._around(s, s[:, 1])).any(axis=1)]

    def free_anti_studs(self) -> np.ndarray:
        a = np.unique(self.anti, axis=0)
        a = a[a[:, 1] > 0]
        return a[~self.filled(self._around(a, a[:, 1] - 1)).any(axis=1)]

    def check_many(self, comp: mepnet.Component, yaw: int, ts: np.ndarray) -> np.ndarray:
        """Codes as Assembly.check_many: 0 on studs, 1 from below, 2 ground, -1 collision,
        -2 not connected, -3 below ground."""
        vox = rot_cells(comp.voxels, yaw)
        studs = rot_points(comp.studs, yaw)
        anti = rot_points(comp.anti_studs, yaw)
        fs, fa = self.free_stud_keys, self.free_anti_keys
        codes = np.full(len(ts), -2, dtype=np.int8)
        wv = vox[None, :, :] + ts[:, None, :]
        min_y = wv[:, :, 1].min(axis=1)
        ground = min_y == 0
        codes[ground] = 2
        if len(studs):
            below = np.isin(key(studs[None] + ts[:, None]), fa).any(axis=1)
            codes[below] = 1
        if len(anti):
            on = np.isin(key(anti[None] + ts[:, None]), fs).any(axis=1)
            codes[on] = 0
        collide = self.filled(wv).any(axis=1)
        codes[collide] = -1
        codes[min_y < 0] = -3
        return codes

    def candidates(self, comp: mepnet.Component, yaw: int) -> np.ndarray:
        studs = rot_points(comp.studs, yaw)
        anti = rot_points(comp.anti_studs, yaw)
        ts = [
            (self.free_stud_points[:, None, :] - anti[None, :, :]).reshape(-1, 3),
            (self.free_anti_points[:, None, :] - studs[None, :, :]).reshape(-1, 3),
        ]
        ts = np.unique(np.concatenate(ts), axis=0)
        codes = self.check_many(comp, yaw, ts)
        return ts[codes >= 0]


# ---------------------------------------------------------------------------------------------


def best_of(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def run(sizes: list[int], repeat: int) -> list[dict]:
    rows = []
    part = "3001"
    comp = mepnet.Component.primitive(part)
    for n in sizes:
        asm = grow_assembly(n, seed=n)
        ref = NumpyAssembly.from_assembly(asm)
        # Agreement first: the reference must produce the same answers.
        for yaw in range(4):
            ours, _ = asm.candidates(comp, yaw)
            theirs = ref.candidates(comp, yaw)
            assert np.array_equal(ours, theirs), f"candidate mismatch at {n} bricks, yaw {yaw}"
        rng = np.random.default_rng(0)
        (lo, hi) = asm.bounds()
        k = 4000
        poses = np.stack(
            [
                np.zeros(k, dtype=np.int64),
                rng.integers(lo[0], hi[0] + 1, k),
                rng.integers(0, hi[1] + 4, k),
                rng.integers(lo[2], hi[2] + 1, k),
            ],
            axis=1,
        )
        ours = asm.check_many(comp, poses)
        theirs = ref.check_many(comp, 0, poses[:, 1:])
        assert np.array_equal(ours, theirs), f"check mismatch at {n} bricks"

        def rust_cands(asm=asm):
            for yaw in range(4):
                asm.candidates(comp, yaw)

        def numpy_cands(ref=ref):
            for yaw in range(4):
                ref.candidates(comp, yaw)

        def rust_checks(asm=asm, poses=poses):
            asm.check_many(comp, poses)

        def numpy_checks(ref=ref, poses=poses):
            ref.check_many(comp, 0, poses[:, 1:])

        n_cands = sum(len(asm.candidates(comp, yaw)[0]) for yaw in range(4))
        for op, fr, fn, count in [
            ("candidates (2x4 brick, 4 yaws)", rust_cands, numpy_cands, n_cands),
            (f"check {k} poses (collision + connection)", rust_checks, numpy_checks, k),
        ]:
            tr, tn = best_of(fr, repeat), best_of(fn, repeat)
            rows.append(
                {
                    "bricks": len(asm),
                    "operation": op,
                    "results": int(count),
                    "rust_ms": tr * 1e3,
                    "numpy_ms": tn * 1e3,
                    "speedup": tn / tr,
                }
            )
            print(
                f"{len(asm):5d} bricks  {op:42s} rust {tr * 1e3:9.3f} ms  "
                f"numpy {tn * 1e3:9.3f} ms  x{tn / tr:7.1f}",
                flush=True,
            )
    return rows


def write_markdown(rows: list[dict], path: str) -> None:
    section = ["## Assembly checks: brickgeom vs NumPy reference", ""]
    section.append(
        f"Measured by `make bench` (`tests/benchmarks/bench_geom.py`) on this machine "
        f"({os.cpu_count()} cores), best of repeated runs, same assemblies for both sides, answers "
        "checked equal before timing. The reference is a vectorised NumPy implementation of the "
        "same rules written in the benchmark. Target: >= 20x on 500+ bricks."
    )
    section += ["", "| bricks | operation | results | brickgeom (ms) | NumPy (ms) | speed-up |"]
    section.append("|---:|---|---:|---:|---:|---:|")
    for r in rows:
        section.append(
            f"| {r['bricks']} | {r['operation']} | {r['results']} | {r['rust_ms']:.3f} | "
            f"{r['numpy_ms']:.3f} | {r['speedup']:.1f}x |"
        )
    replace_section(path, "bench_geom", "\n".join(section))


def replace_section(path: str, name: str, body: str) -> None:
    """Replace (or append) the section between ``<!-- name start/end -->`` markers of a markdown
    file, writing atomically; other sections are kept."""
    marker_start, marker_end = f"<!-- {name} start -->", f"<!-- {name} end -->"
    block = "\n".join([marker_start, body, marker_end])
    text = open(path).read() if os.path.exists(path) else "# Benchmarks\n"
    if marker_start in text:
        head, rest = text.split(marker_start, 1)
        tail = rest.split(marker_end, 1)[1] if marker_end in rest else ""
        text = head + block + tail
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    d = os.path.dirname(os.path.abspath(path))
    with tempfile.NamedTemporaryFile("w", dir=d, delete=False) as f:
        f.write(text)
    os.replace(f.name, path)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/benchmarks.md", help="markdown file to update")
    ap.add_argument("--sizes", default="10,100,500,1000", help="assembly sizes (bricks)")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    rows = run([int(s) for s in args.sizes.split(",")], args.repeat)
    write_markdown(rows, args.out)
    with open(os.path.splitext(args.out)[0] + "_geom.json", "w") as f:
        json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
