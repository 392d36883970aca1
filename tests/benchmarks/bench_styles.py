"""Cost of training pictures in many styles: training-sample preparation (``training_sample``,
slim model, augmentation on) per second with every step drawn again in a random style
(``styles=1``), against the same steps from the page (``styles=0``, the reference), in the same
run; and ``mepnet.synth`` with and without ``--styles``.

    python tests/benchmarks/bench_styles.py --out docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import os
import platform
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
from mepnet.detector.config import ModelConfig  # noqa: E402
from mepnet.manual import answers_of, iter_manual_dirs, load_manual  # noqa: E402
from mepnet.styles import restyled_step  # noqa: E402
from mepnet.train.data import training_sample  # noqa: E402


def sample_seconds(steps, cfg, rounds: int) -> tuple[float, float, float]:  # type: ignore[no-untyped-def]
    """CPU seconds (this process, all threads) per ``training_sample`` without styles, with
    every step drawn again in a style, and of the redrawing alone (``restyled_step``). The
    three are timed step after step, interleaved, so that the load of a shared machine hits them
    alike; CPU time rather than wall time for the same reason."""
    ref = styled = redraw = 0.0
    for r in range(rounds):
        for n, (m, comps, k) in enumerate(steps):
            t0 = time.process_time()
            training_sample(m, (None, k), cfg, True, np.random.default_rng([r, n]), comps)
            t1 = time.process_time()
            training_sample(m, (None, k), cfg, True, np.random.default_rng([r, n]), comps, 1.0)
            t2 = time.process_time()
            restyled_step(m, (None, k), np.random.default_rng([r, n]), comps)
            t3 = time.process_time()
            ref, styled, redraw = ref + t1 - t0, styled + t2 - t1, redraw + t3 - t2
    count = rounds * len(steps)
    return ref / count, styled / count, redraw / count


def synth_seconds(out: Path, manuals: int, styles: bool) -> float:
    """Wall seconds of one ``mepnet.synth`` run (one worker)."""
    env = {k: v for k, v in os.environ.items() if k != "LDRAWDIR"}
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "mepnet.synth", "--no-progress", "--out", str(out)]
    cmd += ["--manuals", str(manuals), "--seed", "900000"] + (["--styles"] if styles else [])
    subprocess.run(cmd, check=True, capture_output=True, env=env)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/benchmarks.md")
    ap.add_argument("--manuals", type=int, default=3)
    ap.add_argument("--steps", type=int, default=48, help="training samples per pass")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args(argv)
    cfg = ModelConfig.slim()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        generate_manuals(Path(d), args.manuals, 900000)
        manuals = [load_manual(m) for m in iter_manual_dirs(d)]
        steps = [
            (m, answers_of(m).components(m), k) for m in manuals for k in range(len(m.main.steps))
        ][: args.steps]
        ref_s, styled_s, redraw_s = sample_seconds(steps, cfg, args.rounds)
        rows.append(
            f"| training sample (slim, augmented, 256 px pages) | {1 / ref_s:.1f} samples/s | "
            f"{1 / styled_s:.1f} samples/s | {ref_s / styled_s:.2f}x |"
        )
        rows.append(
            f"| of which the redrawing (`restyled_step`) | - | {redraw_s * 1000:.1f} ms/sample "
            "| - |"
        )
        plain_t = synth_seconds(Path(d) / "plain", args.manuals, False)
        styles_t = synth_seconds(Path(d) / "styles", args.manuals, True)
        rows.append(
            f"| `mepnet.synth` ({args.manuals} manuals, 256 px, 1 worker) | {plain_t:.1f} s | "
            f"{styles_t:.1f} s | {plain_t / styles_t:.2f}x |"
        )
    body = "\n".join(
        [
            "## Styles (docs/styles.md)",
            "",
            f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs "
            "(shared machine); `python tests/benchmarks/bench_styles.py`. Training samples: "
            "`training_sample` with every step drawn again in a random style (`--styles 1`) "
            "against the page's own picture, the same steps interleaved, CPU time of this "
            f"process ({args.rounds} passes of {len(steps)} samples); synth: wall time.",
            "",
            "| work | without styles (reference) | with styles | speed vs reference |",
            "|---|---:|---:|---:|",
            *rows,
        ]
    )
    replace_section(args.out, "styles", body)
    print(body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
