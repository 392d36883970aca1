"""LDraw files (.ldr / .mpd): reading, writing, inspection.

``read(path)`` returns an :class:`LDrawFile` (models with their build steps, references in
LDraw's y-down frame); ``write(path, file)`` writes it back (read(write(x)) == x);
:func:`inspect` summarises a file (steps, submodels, part counts, library coverage, off-lattice
/ non-yaw parts, per-step physical validity); :func:`build_order` lists models submodels first.
"""

from __future__ import annotations

import collections
import os
from dataclasses import dataclass, field
from typing import Any

from mepnet import _brickgeom as _bg

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


def build_order(checks: list[dict[str, Any]], root: int = 0) -> list[int]:
    """Model indices (of ``_brickgeom.check_ldraw``) with every submodel before the models that
    use it, ``root`` last. Walked with an explicit stack: nesting depth is data, not recursion."""
    order: list[int] = []
    if not checks:
        return order
    seen = {root}
    stack: list[tuple[int, Any]] = [(root, iter(_submodels(checks, root)))]
    while stack:
        m, children = stack[-1]
        child = next(children, None)
        if child is None:
            stack.pop()
            order.append(m)
        elif child not in seen:
            seen.add(child)
            stack.append((child, iter(_submodels(checks, child))))
    return order


def _submodels(checks: list[dict[str, Any]], m: int) -> list[int]:
    return [
        it["submodel"] for step in checks[m]["items"] for it in step if it["kind"] == "submodel"
    ]


__all__ = [
    "LDrawFile",
    "LDrawModel",
    "LDrawRef",
    "inspect",
    "lattice_pose",
    "ldraw_placement",
    "load_part_mesh",
    "parse",
    "read",
    "write",
]
