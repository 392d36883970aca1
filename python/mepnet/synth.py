"""Synthetic manuals on the command line.

    python -m mepnet.synth --out DIR --manuals N --seed S [--workers W] [--size PX] [--styles]

writes N manual folders ``DIR/manual_<seed>`` for seeds S .. S+N-1 (see ``docs/dataset.md``).
With ``--styles`` every manual is drawn in its own style (``mepnet.styles``, ``docs/styles.md``),
recorded in ``manual.json`` under ``source.style``; the manual, its answers and instance maps
are those of the same seed without it.
The same seed gives byte-identical files whatever the number of workers, so shards made on
different machines with disjoint seed ranges never collide. Each manual is written to a
temporary folder and renamed when complete: an interrupted run (Ctrl-C, kill) leaves no
half-written manual, and running the same command again generates only what is missing.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from pathlib import Path
from typing import Any

from mepnet.cli import (
    INTERRUPTED,
    ArgumentParser,
    note,
    quiet_interrupts_in_workers,
    run,
    workers_ignore_interrupts,
)
from mepnet.errors import ConfigError, OutputError
from mepnet.files import remove_stale_temporaries
from mepnet.geom import BrickGeomError
from mepnet.manual.io import write_manual

MAX_SIZE = 2048
#: Worker processes per CPU at most (``--workers`` above it is capped, with a note).
MAX_WORKERS_PER_CPU = 4


def read_generator_settings(path: Path) -> dict[str, Any]:
    """Generator settings from a JSON file (``--config``): an object whose ranges (``[lo,
    hi]``) become the pairs the generator takes. Checked by :func:`check_generator_settings`."""
    try:
        config = json.loads(path.read_text())
    except OSError as e:
        raise ConfigError(f"{path}: {e.strerror or e}") from None
    except (ValueError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(config, dict):
        raise ConfigError(f"{path}: expected a JSON object of generator settings")
    return {k: tuple(v) if isinstance(v, list) else v for k, v in config.items()}


def check_generator_settings(config: dict[str, Any], source: Path | None = None) -> None:
    """The one probe of generator settings: generate a tiny manual with them, in this process,
    before any worker starts; a bad setting is a :class:`~mepnet.errors.ConfigError`."""
    from mepnet import _brickgeom as _bg

    probe = {**config, "image_size": 16}
    try:
        _bg.synth_manual(0, probe)
    except (BrickGeomError, ValueError, TypeError, OverflowError) as e:
        where = f"{source}: " if source is not None else ""
        raise ConfigError(f"{where}generator settings: {e}") from None


def manual_dir(out: Path, seed: int) -> Path:
    """Folder of the manual with this seed."""
    return out / f"manual_{seed:08d}"


def generate_one(
    seed: int, out: Path, config: dict[str, Any], ldraw_dir: str | None, styles: bool = False
) -> int:
    """Generate, render and write one manual (``styles``: in its own style); returns its number
    of steps (main + submodules)."""
    from mepnet import _brickgeom as _bg

    source: dict[str, Any] = {
        "kind": "synthetic",
        "seed": seed,
        "generator": config,
        "renderer": "brickgeom",
    }
    if styles:
        from mepnet.styles import manual_style, render_style, style_generated

        style = manual_style(seed, int(config["image_size"]), ldraw_dir is not None)
        ldraw_dir = ldraw_dir if style["meshes"] == "ldraw" else None
        manual = _bg.synth_manual(seed, config, ldraw_dir, style=render_style(style))
        style_generated(manual, style, seed)
        source["style"] = style
    else:
        manual = _bg.synth_manual(seed, config, ldraw_dir)
    if ldraw_dir is not None:
        source["part_geometry"] = "ldraw"
    try:
        write_manual(manual_dir(out, seed), manual, source, writer="mepnet.synth")
    except OutputError:
        pass  # another run into the same folder wrote this manual meanwhile (the same bytes)
    return len(manual["main"]["steps"]) + sum(
        len(s["build"]["steps"]) for s in manual["submodules"]
    )


def _worker_init() -> None:
    # Several worker processes already use every core; one rayon thread each avoids
    # oversubscription. Set before the extension's thread pool starts in this process.
    os.environ.setdefault("RAYON_NUM_THREADS", "1")
    quiet_interrupts_in_workers()


def _job(args: tuple[int, str, dict[str, Any], str | None, bool]) -> tuple[int, int]:
    seed, out, config, ldraw_dir, styles = args
    return seed, generate_one(seed, Path(out), config, ldraw_dir, styles)


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m mepnet.synth`` argument parser."""
    ap = ArgumentParser(prog="python -m mepnet.synth", description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path, help="output folder")
    ap.add_argument("--manuals", required=True, type=int, help="number of manuals")
    ap.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    ap.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--size", type=int, default=256, help="image side in pixels (default 256)")
    ap.add_argument("--supersample", type=int, default=1, choices=(1, 3), help="anti-aliasing (3)")
    ap.add_argument(
        "--ldraw-dir",
        default=os.environ.get("LDRAWDIR"),
        help="render with real part geometry from this LDraw library (default: $LDRAWDIR, else built-in meshes)",
    )
    ap.add_argument(
        "--config", type=Path, help="JSON file of generator settings (see docs/dataset.md)"
    )
    ap.add_argument(
        "--styles",
        action="store_true",
        help="draw every manual in its own style (docs/styles.md); with an LDraw library, a "
        "share of the manuals uses its part geometry and the rest the built-in meshes",
    )
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    return ap


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (2 on bad input, with one line on stderr; 130 on
    Ctrl-C, after which the same command finishes the job)."""
    args = build_parser().parse_args(argv)
    return run("mepnet.synth", lambda: _main(args))


def _main(args: argparse.Namespace) -> int:
    if args.manuals < 1:
        raise ConfigError(f"--manuals must be at least 1, got {args.manuals}")
    if args.seed < 0 or args.seed + args.manuals > 2**63:
        raise ConfigError(f"--seed must be a non-negative 64-bit integer, got {args.seed}")
    if not 16 <= args.size <= MAX_SIZE:
        raise ConfigError(f"--size must be within 16..{MAX_SIZE} pixels, got {args.size}")
    if args.workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {args.workers}")
    if args.ldraw_dir is not None and not (Path(args.ldraw_dir) / "parts").is_dir():
        raise ConfigError(f"--ldraw-dir {args.ldraw_dir}: not an LDraw library (no parts/ folder)")
    config = read_generator_settings(args.config) if args.config is not None else {}
    config["image_size"] = args.size
    config["supersample"] = args.supersample
    if args.out.exists() and not args.out.is_dir():
        raise ConfigError(f"{args.out}: exists and is not a folder")
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        probe = args.out / f".write-test-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        raise ConfigError(f"{args.out}: cannot write there ({e.strerror or e})") from None
    check_generator_settings(config, args.config)
    # leftovers of killed runs (never those of a run still going into the same folder)
    remove_stale_temporaries(args.out)
    seeds = [
        s
        for s in range(args.seed, args.seed + args.manuals)
        if not manual_dir(args.out, s).is_dir()
    ]
    done = args.manuals - len(seeds)
    from tqdm import tqdm

    bar = tqdm(
        total=args.manuals,
        initial=done,
        unit="manual",
        disable=args.no_progress,
        leave=False,  # an error then stays one line
        file=sys.stderr,
    )
    steps = 0
    t0 = time.perf_counter()
    jobs = [(s, str(args.out), config, args.ldraw_dir, args.styles) for s in seeds]
    # no more worker processes than manuals to write, nor than a few per core: each is an
    # interpreter with the extension (tens of MB), and a thousand would exhaust the memory
    workers = min(args.workers, max(len(jobs), 1), MAX_WORKERS_PER_CPU * (os.cpu_count() or 1))
    if workers < args.workers and len(jobs) > workers:
        note(
            f"using {workers} worker processes, not {args.workers} "
            f"({MAX_WORKERS_PER_CPU} per CPU at most)"
        )
    try:
        if workers == 1:
            for job in jobs:
                steps += _job(job)[1]
                bar.update(1)
        else:
            # spawn, not fork: the parent has already started the extension's thread pool
            ctx = multiprocessing.get_context("spawn")
            with workers_ignore_interrupts():
                pool = ctx.Pool(workers, initializer=_worker_init)
            with pool:
                for _, n in pool.imap_unordered(_job, jobs):
                    steps += n
                    bar.update(1)
    except KeyboardInterrupt:
        bar.close()
        print("mepnet.synth: interrupted; run the same command again to finish", file=sys.stderr)
        return INTERRUPTED
    finally:
        bar.close()
    dt = time.perf_counter() - t0
    rate = steps / dt if dt > 0 else 0.0
    print(
        f"wrote {len(seeds)} manuals ({steps} steps) to {args.out} in {dt:.1f}s "
        f"({rate:.1f} steps/s); {done} already there"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
