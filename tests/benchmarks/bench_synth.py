"""Generation throughput: synthetic manual steps per second end to end (geometry, rendering,
PNG and JSON writing) with ``python -m mepnet.synth`` at 256 px, 1 and 2 worker processes.

Target (issue: synthetic manuals): the paper's 200,000 training steps in under an hour on this
2-core machine, i.e. >= 56 steps/s.

    python tests/benchmarks/bench_synth.py --out docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(__file__))
from bench_geom import replace_section  # noqa: E402

TARGET = 200_000 / 3600


def run(manuals: int, workers: int, size: int) -> tuple[int, float]:
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        r = subprocess.run(
            [
                sys.executable,
                "-m",
                "mepnet.synth",
                "--no-progress",
                "--out",
                d,
                "--manuals",
                str(manuals),
                "--seed",
                "1000",
                "--workers",
                str(workers),
                "--size",
                str(size),
            ],
            capture_output=True,
            text=True,
            check=True,
        )
        dt = time.perf_counter() - t0
    steps = int(re.search(r"\((\d+) steps\)", r.stdout).group(1))
    return steps, dt


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/benchmarks.md")
    ap.add_argument("--manuals", type=int, default=40)
    ap.add_argument("--size", type=int, default=256)
    args = ap.parse_args(argv)
    rows = []
    for workers in (1, 2):
        steps, dt = run(args.manuals, workers, args.size)
        rate = steps / dt
        rows.append((workers, steps, dt, rate))
        print(f"workers {workers}: {steps} steps in {dt:.1f}s = {rate:.1f} steps/s", flush=True)
    lines = [
        "## Synthetic manual generation",
        "",
        f"`python -m mepnet.synth --manuals {args.manuals} --size {args.size}` end to end (process start, "
        "generation, rendering, PNG and JSON writing), measured by `make bench` "
        "(`tests/benchmarks/bench_synth.py`) on this machine "
        f"({os.cpu_count()} cores). Target: >= {TARGET:.0f} steps/s (200,000 steps in an hour).",
        "",
        "| workers | steps | seconds | steps/s | vs target | 200k steps take |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for workers, steps, dt, rate in rows:
        lines.append(
            f"| {workers} | {steps} | {dt:.1f} | {rate:.1f} | {rate / TARGET:.2f}x | {200_000 / rate / 60:.0f} min |"
        )
    replace_section(args.out, "bench_synth", "\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
