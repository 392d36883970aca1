"""LDraw inspection and conversion from the command line.

    python -m mepnet.ldraw info FILE [FILE ...] [--steps] [--json OUT] [--markdown]
    python -m mepnet.ldraw to-manual FILE --out DIR [--ldraw-dir DIR] [--size PX]

``info`` prints steps, submodels, part counts, library coverage, off-lattice / non-yaw parts
and, for steps whose parts are all library parts on the lattice, whether each part is
physically valid (connected, no collision). ``to-manual`` converts a model into a manual
folder (:mod:`mepnet.ldraw.convert`).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

from mepnet.cli import ArgumentParser, run
from mepnet.errors import ConfigError
from mepnet.files import atomic_write_text, check_output_file
from mepnet.ldraw.io import inspect, read


def _print_info(info: dict[str, Any], steps: bool) -> None:
    pct = 100.0 * info["known_parts"] / max(info["parts"], 1)
    print(f"{info['file']}")
    print(
        f"  models {info['models']} (submodels {info['submodels']}), steps {info['steps']} "
        f"(main model {info['main_steps']}), parts {info['parts']}, distinct parts "
        f"{info['distinct_parts']}"
    )
    print(
        f"  library coverage: {info['known_parts']}/{info['parts']} parts ({pct:.1f}%), "
        f"{info['known_distinct']}/{info['distinct_parts']} distinct"
    )
    print(f"  off-lattice references: {info['off_lattice']}, non-yaw rotations: {info['non_yaw']}")
    if info["unknown"]:
        shown = ", ".join(f"{n} x{c}" for n, c in info["unknown"][:8])
        more = f" and {len(info['unknown']) - 8} more" if len(info["unknown"]) > 8 else ""
        print(f"  outside the library: {shown}{more}")
    print(
        f"  steps with all parts placeable: {info['steps_checked']}/{info['steps']}: "
        f"valid {info['steps_valid']}, invalid {info['steps_invalid']}, unverified "
        f"{info['steps_unverified']} (may rest on parts outside the library)"
    )
    if steps:
        for s in info["step_checks"]:
            if s["results"] is None:
                state = f"not checked ({s['items'] - s['placeable']} items not placeable)"
            else:
                bad = [msg for ok, msg in s["results"] if not ok]
                state = s["verdict"]
                if bad:
                    state += f": {bad[0]}" + (f" (+{len(bad) - 1})" if len(bad) > 1 else "")
            print(f"    {s['model']} step {s['step']:3d}: {s['items']:3d} items  {state}")


def _markdown(infos: list[dict[str, Any]]) -> str:
    rows = [
        "| model | submodels | steps | parts | distinct | library coverage (parts) | "
        "distinct covered | off-lattice | non-yaw | steps checkable | valid | invalid | "
        "unverified |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i in infos:
        pct = 100.0 * i["known_parts"] / max(i["parts"], 1)
        rows.append(
            f"| {i['file']} | {i['submodels']} | {i['steps']} | {i['parts']} | "
            f"{i['distinct_parts']} | {i['known_parts']} ({pct:.0f}%) | {i['known_distinct']} | "
            f"{i['off_lattice']} | {i['non_yaw']} | {i['steps_checked']} | {i['steps_valid']} | "
            f"{i['steps_invalid']} | {i['steps_unverified']} |"
        )
    return "\n".join(rows) + "\n"


#: The ``written_by`` mark of ``info --json`` reports (the files it may replace).
INFO_WRITER = "mepnet.ldraw info"


def _cmd_info(args: argparse.Namespace) -> int:
    if args.json:
        check_output_file(args.json, INFO_WRITER)
    infos = []
    for path in args.files:
        info = inspect(read(path))
        infos.append(info)
        if not args.markdown:
            _print_info(info, args.steps)
    if args.markdown:
        print(_markdown(infos), end="")
    if args.json:
        doc = {"written_by": INFO_WRITER, "files": infos}
        atomic_write_text(args.json, json.dumps(doc, indent=1) + "\n")
    return 0


def _cmd_to_manual(args: argparse.Namespace) -> int:
    from mepnet.ldraw.convert import convert

    out = Path(args.out)
    if out.exists():
        raise ConfigError(f"{out}: already exists (choose a new folder)")
    if not 16 <= args.size <= 2048:
        raise ConfigError(f"--size must be within 16..2048 pixels, got {args.size}")
    if args.ldraw_dir is not None and not (Path(args.ldraw_dir) / "parts").is_dir():
        raise ConfigError(f"--ldraw-dir {args.ldraw_dir}: not an LDraw library (no parts/ folder)")
    r = convert(read(args.file), out, args.ldraw_dir, args.size, args.supersample)
    print(
        f"{r['file']}: {r['steps']} steps ({r['submodules']} submodules), parts kept "
        f"{r['parts_kept']}/{r['parts_in_file']} ({r['substituted']} substituted, {r['dropped']} "
        f"references dropped) -> {out}"
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m mepnet.ldraw`` argument parser."""
    ap = ArgumentParser(
        prog="python -m mepnet.ldraw", description="LDraw inspection and conversion."
    )
    sub = ap.add_subparsers(dest="command", required=True)
    info = sub.add_parser("info", help="steps, submodels, coverage and validity of LDraw files")
    info.add_argument("files", nargs="+", metavar="FILE", help=".ldr or .mpd file(s)")
    info.add_argument("--steps", action="store_true", help="print the validity of every step")
    info.add_argument("--json", metavar="OUT", help="also write the full report as JSON")
    info.add_argument(
        "--markdown", action="store_true", help="print one markdown table row per file"
    )
    info.set_defaults(run=_cmd_info)
    conv = sub.add_parser(
        "to-manual", help="convert a model into a manual folder (images + manual.json)"
    )
    conv.add_argument("file", metavar="FILE", help=".ldr or .mpd file")
    conv.add_argument("--out", required=True, help="manual folder to write (must not exist)")
    conv.add_argument(
        "--ldraw-dir",
        default=os.environ.get("LDRAWDIR"),
        help="LDraw library used to measure parts outside the library for substitution and to "
        "render real part geometry (default: $LDRAWDIR; without it such parts are dropped)",
    )
    conv.add_argument("--size", type=int, default=256, help="image side in pixels (default 256)")
    conv.add_argument(
        "--supersample", type=int, default=1, choices=(1, 3), help="anti-aliasing (3)"
    )
    conv.set_defaults(run=_cmd_to_manual)
    return ap


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (2 on bad input, with one line on stderr)."""
    args = build_parser().parse_args(argv)
    return run("mepnet.ldraw", lambda: int(args.run(args)))
