"""Manual folders from the command line.

    python -m mepnet.manual strip MANUAL_DIR --out DIR [--no-cameras]

``strip`` writes the manual as a user would have it: the step images and the page (per step the
parts callout and, unless ``--no-cameras``, the camera), without the answers (poses, keypoints,
instance maps). Every command that does not score runs on such a manual.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mepnet.cli import ArgumentParser, run
from mepnet.manual.io import strip_manual

PROG = "python -m mepnet.manual"


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m mepnet.manual`` argument parser."""
    ap = ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    st = sub.add_parser("strip", help="write the manual without its answers (as users have it)")
    st.add_argument("manual", type=Path, metavar="MANUAL_DIR", help="a manual folder")
    st.add_argument("--out", required=True, type=Path, help="folder to write (must not exist)")
    st.add_argument("--no-cameras", action="store_true", help="leave out the cameras as well")
    return ap


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (2 on bad input, with one line on stderr)."""
    args = build_parser().parse_args(argv)

    def work() -> int:
        m = strip_manual(args.manual, args.out, cameras=not args.no_cameras)
        what = "page only" + ("" if not args.no_cameras else ", no cameras")
        print(f"wrote {args.out} ({len(m.all_steps())} steps, {what})")
        return 0

    return run("mepnet.manual", work)
