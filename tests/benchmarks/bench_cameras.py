"""Camera estimation speed: wall time per step of mepnet.cameras (every hypothesis made and
checked, the pictures' preparation included) inside the teacher-forced plan loop with stage 2
by synthesis, on fresh synthetic manuals whose cameras are dropped; split into first steps and
later steps, with the predictor's own time per step measured in the same run as the reference.
Also the CPU time of the same work (one core's worth: the renderer's threads counted).

Target (issue 12): <= 20 ms per step on this 2-core CPU.

    python tests/benchmarks/bench_cameras.py --out docs/benchmarks.md [--manuals 5]
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
from bench_geom import replace_section  # noqa: E402
from conftest import generate_manuals  # noqa: E402
from mepnet.cameras import drop_cameras  # noqa: E402
from mepnet.manual import iter_manual_dirs, load_manual  # noqa: E402
from mepnet.plan import run_manual  # noqa: E402
from mepnet.stage2 import make_predictor  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/benchmarks.md")
    ap.add_argument("--manuals", type=int, default=5)
    args = ap.parse_args(argv)
    first, later, predictor_s = [], [], []
    by_kept: dict[str, list[float]] = {}  # later steps by the hypothesis they kept
    cpu0 = time.process_time()
    with tempfile.TemporaryDirectory() as d:
        generate_manuals(Path(d), args.manuals, 900000)
        synthesis = make_predictor("synthesis")
        for md in iter_manual_dirs(d):
            run = run_manual(drop_cameras(load_manual(md)), synthesis, teacher_forced=True)
            for b in run.builds:
                for s in b.steps:
                    assert s.camera is not None
                    predictor_s.append(s.seconds)
                    if s.index == 1:
                        first.append(s.camera.seconds)
                    else:
                        later.append(s.camera.seconds)
                        by_kept.setdefault(s.camera.how, []).append(s.camera.seconds)
    cpu = time.process_time() - cpu0
    wall_all = np.array(first + later)
    cpu_share = cpu / max(wall_all.sum() + np.sum(predictor_s), 1e-9)
    ms = lambda x, q: 1e3 * float(np.percentile(x, q))  # noqa: E731
    load = os.getloadavg()[0]
    lines = [
        "## Camera estimation",
        "",
        f"`tests/benchmarks/bench_cameras.py` on {args.manuals} fresh synthetic manuals (seed 900000, "
        "256 px) with their cameras dropped, teacher-forced, stage 2 by synthesis; wall time of "
        "`mepnet.cameras` per step (every hypothesis made and checked after prediction, the "
        f"picture's preparation included); this machine ({os.cpu_count()} cores, load average "
        f"{load:.1f} when it finished: the machine is shared). Target: <= 20 ms per step.",
        "",
        "| steps | count | median (ms) | mean (ms) | p95 (ms) |",
        "|---|---:|---:|---:|---:|",
        f"| first steps | {len(first)} | {ms(first, 50):.1f} | {1e3 * np.mean(first):.1f} | {ms(first, 95):.1f} |",
        f"| later steps | {len(later)} | {ms(later, 50):.1f} | {1e3 * np.mean(later):.1f} | {ms(later, 95):.1f} |",
        f"| all | {len(wall_all)} | {ms(wall_all, 50):.1f} | {1e3 * np.mean(wall_all):.1f} | {ms(wall_all, 95):.1f} |",
        f"| reference: stage 2 by synthesis, same steps | {len(predictor_s)} | {ms(predictor_s, 50):.1f} | "
        f"{1e3 * np.mean(predictor_s):.1f} | {ms(predictor_s, 95):.1f} |",
        "",
        f"Camera estimation takes {np.sum(wall_all) / np.sum(predictor_s):.2f}x the predictor's time "
        f"(totals; predictions repeated for a second hypothesis count as the predictor's). CPU time "
        f"over wall time for the whole run: {cpu_share:.2f}.",
    ]
    lines += [
        "",
        "Later steps by the hypothesis they kept (the first, `carried`, is the common case; the "
        "others are made only when the ones before do not explain the picture):",
        "",
        "| kept | steps | median (ms) | mean (ms) | share of later steps' camera time |",
        "|---|---:|---:|---:|---:|",
    ]
    total = max(float(np.sum(later)), 1e-9)
    for how, secs in sorted(by_kept.items(), key=lambda kv: -sum(kv[1])):
        lines.append(
            f"| {how} | {len(secs)} | {ms(secs, 50):.1f} | {1e3 * np.mean(secs):.1f} | "
            f"{sum(secs) / total:.0%} |"
        )
    print("\n".join(lines))
    replace_section(args.out, "bench_cameras", "\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
