"""LDraw files (.ldr / .mpd): reading, writing, inspection.

``read(path)`` returns an :class:`LDrawFile` (models with their build steps, references in
LDraw's y-down frame); ``write(path, file)`` writes it back (read(write(x)) == x). The command
line::

    python -m mepnet.ldraw info FILE [FILE ...] [--steps] [--json OUT] [--markdown]

prints steps, submodels, part counts, library coverage, off-lattice / non-yaw parts and, for
steps whose parts are all library parts on the lattice, whether each part is physically valid
(connected, no collision).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mepnet import _brickgeom as _bg
from mepnet.geom import BrickGeomError

Matrix = tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]
IDENTITY: Matrix = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class LDrawRef:
    """A type-1 line: a part or submodel placed with a colour and a transform (LDraw frame)."""

    name: str
    colour: int = 16
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    matrix: Matrix = IDENTITY
    is_submodel: bool = False
    line: int = field(default=0, compare=False)


@dataclass
class LDrawModel:
    """The main model or a submodel: its name, description and non-empty build steps."""

    name: str
    steps: list[list[LDrawRef]] = field(default_factory=list)
    title: str = ""


@dataclass
class LDrawFile:
    """A parsed file: ``models[0]`` is the main model."""

    name: str
    models: list[LDrawModel] = field(default_factory=list)
    embedded_parts: list[tuple[str, str]] = field(default_factory=list)

    @property
    def main(self) -> LDrawModel:
        """The main model."""
        return self.models[0]

    def model(self, name: str) -> LDrawModel | None:
        """A model by name (case-insensitive)."""
        key = name.strip().lower().replace("\\", "/")
        for m in self.models:
            if m.name.strip().lower().replace("\\", "/") == key:
                return m
        return None

    def to_dict(self) -> dict[str, Any]:
        """The plain-dict form used by the Rust core."""
        return {
            "name": self.name,
            "models": [
                {
                    "name": m.name,
                    "title": m.title,
                    "steps": [
                        [
                            {
                                "line": r.line,
                                "colour": r.colour,
                                "position": list(r.position),
                                "matrix": [list(row) for row in r.matrix],
                                "name": r.name,
                                "is_submodel": r.is_submodel,
                            }
                            for r in step
                        ]
                        for step in m.steps
                    ],
                }
                for m in self.models
            ],
            "embedded_parts": list(self.embedded_parts),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LDrawFile:
        """Inverse of :meth:`to_dict`."""
        return cls(
            name=d["name"],
            models=[
                LDrawModel(
                    name=m["name"],
                    title=m.get("title", ""),
                    steps=[
                        [
                            LDrawRef(
                                name=r["name"],
                                colour=int(r["colour"]),
                                position=tuple(float(v) for v in r["position"]),  # type: ignore[arg-type]
                                matrix=tuple(tuple(float(v) for v in row) for row in r["matrix"]),  # type: ignore[arg-type]
                                is_submodel=bool(r["is_submodel"]),
                                line=int(r.get("line", 0)),
                            )
                            for r in step
                        ]
                        for step in m["steps"]
                    ],
                )
                for m in d["models"]
            ],
            embedded_parts=[tuple(e) for e in d.get("embedded_parts", [])],  # type: ignore[misc]
        )

    def flatten(self) -> list[dict[str, Any]]:
        """Every part of the main model with its world placement (LDraw frame)."""
        return _bg.flatten_ldraw(self.to_dict())

    def to_text(self) -> str:
        """The file as LDraw text."""
        return _bg.format_ldraw_dict(self.to_dict())


def read(path: str | os.PathLike[str]) -> LDrawFile:
    """Read an .ldr or .mpd file. Raises :class:`mepnet.LDrawError` naming file and line."""
    return LDrawFile.from_dict(_bg.read_ldraw_dict(os.fspath(path)))


def parse(data: bytes, file_name: str) -> LDrawFile:
    """Parse LDraw text."""
    return LDrawFile.from_dict(_bg.parse_ldraw_dict(data, file_name))


def write(path: str | os.PathLike[str], file: LDrawFile) -> None:
    """Write a file atomically (.mpd with ``0 FILE`` blocks when it has submodels)."""
    _bg.write_ldraw_dict(os.fspath(path), file.to_dict())


def lattice_pose(
    position: tuple[float, float, float], matrix: Matrix
) -> tuple[int, tuple[int, int, int], bool, bool]:
    """``(yaw, t, off_lattice, non_yaw)`` of an LDraw placement."""
    return _bg.lattice_pose_of(position, matrix)


def ldraw_placement(yaw: int, t: tuple[int, int, int]) -> tuple[list[float], list[list[float]]]:
    """``(position, matrix)`` in LDraw's frame of a lattice pose."""
    return _bg.ldraw_placement_of(yaw, t)


def load_part_mesh(root: str | os.PathLike[str], part: str) -> tuple[Any, Any, int]:
    """Real geometry of a part from an LDraw library: ``(vertices, triangles, stud_count)``."""
    return _bg.load_part_mesh(os.fspath(root), part)


# ---------------------------------------------------------------------------------------------
# Inspection


def inspect(file: LDrawFile) -> dict[str, Any]:
    """Summary of a file: counts, library coverage, lattice flags and per-step validity."""
    flat = file.flatten()
    checks = _bg.check_ldraw(file.to_dict())
    counts = collections.Counter(p["name"] for p in flat)
    known = {n: _bg.resolve_part(n) for n in counts}
    off = sum(
        1
        for m in checks
        for step in m["items"]
        for it in step
        if it["kind"] != "submodel" and it["off_lattice"]
    )
    non_yaw = sum(
        1
        for m in checks
        for step in m["items"]
        for it in step
        if it["kind"] != "submodel" and it["non_yaw"]
    )
    steps = [s for m in checks for s in m["steps"]]
    checked = [s for s in steps if s["results"] is not None]
    for s in checked:
        s["verdict"] = _verdict(s)
    valid = [s for s in checked if s["verdict"] == "valid"]
    unverified = [s for s in checked if s["verdict"] == "unverified"]
    return {
        "file": file.name,
        "models": len(file.models),
        "submodels": len(file.models) - 1,
        "steps": sum(len(m.steps) for m in file.models),
        "main_steps": len(file.main.steps) if file.models else 0,
        "parts": len(flat),
        "distinct_parts": len(counts),
        "known_parts": sum(c for n, c in counts.items() if known[n]),
        "known_distinct": sum(1 for n in counts if known[n]),
        "unknown": sorted(((n, c) for n, c in counts.items() if not known[n]), key=lambda x: -x[1]),
        "off_lattice": off,
        "non_yaw": non_yaw,
        "steps_checked": len(checked),
        "steps_valid": len(valid),
        "steps_unverified": len(unverified),
        "steps_invalid": len(checked) - len(valid) - len(unverified),
        "step_checks": [{"model": m["name"], **s} for m in checks for s in m["steps"]],
    }


def _verdict(step: dict[str, Any]) -> str:
    """valid; invalid (a collision, or unsupported although everything below is known); or
    unverified (only "not connected" while earlier parts are outside the library)."""
    bad = [msg for ok, msg in step["results"] if not ok]
    if not bad:
        return "valid"
    if not step["complete_base"] and all("not connected" in m for m in bad):
        return "unverified"
    return "invalid"


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


def _write_atomic(path: str, text: str) -> None:
    d = os.path.dirname(os.path.abspath(path)) or "."
    with tempfile.NamedTemporaryFile("w", dir=d, delete=False, suffix=".tmp") as f:
        f.write(text)
    os.replace(f.name, path)


def _cmd_info(args: argparse.Namespace) -> int:
    infos = []
    for path in args.files:
        info = inspect(read(path))
        infos.append(info)
        if not args.markdown:
            _print_info(info, args.steps)
    if args.markdown:
        print(_markdown(infos), end="")
    if args.json:
        _write_atomic(args.json, json.dumps(infos, indent=1))
    return 0


def _cmd_to_manual(args: argparse.Namespace) -> int:
    from mepnet.convert import convert

    out = Path(args.out)
    if out.exists():
        raise BrickGeomError(f"{out}: already exists (choose a new folder)")
    if not 16 <= args.size <= 2048:
        raise BrickGeomError(f"--size must be within 16..2048 pixels, got {args.size}")
    if args.ldraw_dir is not None and not (Path(args.ldraw_dir) / "parts").is_dir():
        raise BrickGeomError(
            f"--ldraw-dir {args.ldraw_dir}: not an LDraw library (no parts/ folder)"
        )
    r = convert(read(args.file), out, args.ldraw_dir, args.size, args.supersample)
    print(
        f"{r['file']}: {r['steps']} steps ({r['submodules']} submodules), parts kept "
        f"{r['parts_kept']}/{r['parts_in_file']} ({r['substituted']} substituted, {r['dropped']} "
        f"references dropped) -> {out}"
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m mepnet.ldraw`` argument parser."""
    ap = argparse.ArgumentParser(
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
    try:
        return int(args.run(args))
    except BrickGeomError as e:
        print(f"mepnet.ldraw: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        name = e.filename if e.filename is not None else ""
        print(f"mepnet.ldraw: error: {name}: {e.strerror or e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = [
    "LDrawFile",
    "LDrawModel",
    "LDrawRef",
    "inspect",
    "lattice_pose",
    "ldraw_placement",
    "load_part_mesh",
    "main",
    "parse",
    "read",
    "write",
]
