"""Repair speed: wall time per step that the consistency repair adds to the plan a user gets
(`mepnet.infer`, autoregressive: earlier placements re-checked and revised after every step, and
a poorly explained step predicted again on the ties of the steps before it), on fresh synthetic
manuals drawn by mepnet's renderer and the same manuals restyled (`mepnet.restyle`), plus any
other sets given with ``--data`` (e.g. manuals drawn by LeoCAD or POV-Ray). The reference,
measured in the same run on the same manuals: the same autoregressive plan with the repair off
(``repair=False``), its predictor time per step.

Target (issue 14): the repair adds at most 0.05 s per step on average on this CPU.

    python tests/benchmarks/bench_repair.py --out docs/benchmarks.md [--manuals 4] [--data DIR ...]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench_geom import replace_section  # noqa: E402
from conftest import generate_manuals  # noqa: E402
from mepnet.manual import iter_manual_dirs, load_manual  # noqa: E402
from mepnet.plan import run_manual  # noqa: E402
from mepnet.stage2 import make_predictor  # noqa: E402


def measure(data: Path, predictor) -> dict[str, float]:
    """Both plans over every manual of ``data``: per step, the predictor's seconds without the
    repair and with it, and the repair's own seconds (wall, ``StepRun.repair_seconds``)."""
    plain, with_repair, repair, revisions, wall = [], [], [], 0, [0.0, 0.0]
    for md in iter_manual_dirs(data):
        manual = load_manual(md)
        for on in (False, True):
            t0 = time.perf_counter()
            run = run_manual(manual, predictor, repair=on)
            wall[on] += time.perf_counter() - t0
            for b in run.builds:
                for s in b.steps:
                    if on:
                        with_repair.append(s.seconds)
                        repair.append(s.repair_seconds)
                        revisions += len(s.revisions)
                    else:
                        plain.append(s.seconds)
    return {
        "steps": len(repair),
        "plain": float(np.mean(plain)),
        "predictor": float(np.mean(with_repair)),
        "repair": float(np.mean(repair)),
        "repair_p95": float(np.percentile(repair, 95)),
        "revisions": revisions,
        "wall_plain": wall[False] / max(len(plain), 1),
        "wall_repair": wall[True] / max(len(repair), 1),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/benchmarks.md")
    ap.add_argument("--manuals", type=int, default=4)
    ap.add_argument("--data", action="append", default=[], help="another set of manuals (repeat)")
    args = ap.parse_args(argv)
    predictor = make_predictor("mepnet")
    rows = []
    with tempfile.TemporaryDirectory() as d:
        ours = generate_manuals(Path(d) / "ours", args.manuals, 900000)
        restyled = Path(d) / "restyled"
        r = subprocess.run(
            [sys.executable, "-m", "mepnet.restyle", "--data", str(ours), "--out", str(restyled)],
            capture_output=True,
            text=True,
        )
        assert r.returncode == 0, r.stderr
        sets = [(f"ours ({args.manuals} fresh, seed 900000)", ours)]
        sets.append(("the same, restyled (`mepnet.restyle`)", restyled))
        for extra in args.data:
            n = len(list(iter_manual_dirs(extra)))
            sets.append((f"`{Path(extra).name}` ({n} manuals)", Path(extra)))
        for name, data in sets:
            rows.append((name, measure(data, predictor)))
            print(name, rows[-1][1], flush=True)
    load = os.getloadavg()[0]
    steps = sum(m["steps"] for _, m in rows)
    mean_repair = sum(m["repair"] * m["steps"] for _, m in rows) / max(steps, 1)
    lines = [
        "## Repair across steps",
        "",
        "`tests/benchmarks/bench_repair.py`: the autoregressive plan (`mepnet.infer`'s loop, the "
        "shipped `mepnet` predictor) run twice over each manual, with the repair of "
        "`mepnet.consistency` and without it (the reference, same run, same manuals); one process, "
        f"this machine ({os.cpu_count()} cores, load average {load:.1f} when it finished: the "
        "machine is shared). The repair's seconds include a step predicted again on the ties of "
        "the steps before it. Target: the repair adds <= 0.05 s per step on average. Command: "
        f"`python tests/benchmarks/bench_repair.py {' '.join(sys.argv[1:] if argv is None else argv)}`.",
        "",
        "| manuals | steps | predictor s/step, no repair (reference) | predictor s/step, with repair | "
        "repair s/step (mean) | repair p95 | revisions | whole plan with / without repair |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, m in rows:
        lines.append(
            f"| {name} | {m['steps']} | {m['plain']:.3f} | {m['predictor']:.3f} | "
            f"{m['repair']:.4f} | {m['repair_p95']:.3f} | {m['revisions']} | "
            f"{m['wall_repair'] / max(m['wall_plain'], 1e-9):.2f}x |"
        )
    lines += [
        "",
        f"Over all {steps} steps the repair adds {mean_repair:.4f} s per step on average.",
    ]
    print("\n".join(lines))
    replace_section(args.out, "bench_repair", "\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
