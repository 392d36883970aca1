"""LDraw files (.ldr / .mpd): reading, writing, inspection.

``read(path)`` returns an :class:`LDrawFile` (models with their build steps, references in
LDraw's y-down frame); ``write(path, file)`` writes it back (read(write(x)) == x). The file,
model and reference types are the binding's frozen classes (built in Python as
``LDrawFile(name, models)``, ``LDrawModel(name, steps, title)``, ``LDrawRef(name, colour,
position, matrix, is_submodel)``; values the reader would not read back raise
:class:`mepnet.LDrawError`). ``file.flatten()`` gives :class:`FlatPart` s, :func:`check` one
:class:`ModelCheck` per model (its :class:`StepItem` s and :class:`StepCheck` s).
:func:`resolve_colour` is LDraw's colour inheritance (16 and 24).
:func:`inspect` summarises a file (steps, submodels, part counts, library coverage, off-lattice
/ non-yaw parts, per-step physical validity); :func:`build_order` lists models submodels first.
"""

from __future__ import annotations

import collections
import os
from collections.abc import Iterator, Sequence
from typing import Any

from mepnet import _brickgeom as _bg
from mepnet._brickgeom import (
    FlatPart,
    LDrawFile,
    LDrawModel,
    LDrawRef,
    ModelCheck,
    StepCheck,
    StepItem,
)
from mepnet.files import regular_input

Matrix = tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]
IDENTITY: Matrix = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def read(path: str | os.PathLike[str]) -> LDrawFile:
    """Read an .ldr or .mpd file. Raises :class:`mepnet.LDrawError` naming file and line."""
    return _bg.read_ldraw(os.fspath(regular_input(path, "LDraw file")))


def parse(data: bytes, file_name: str) -> LDrawFile:
    """Parse LDraw text."""
    return _bg.parse_ldraw(data, file_name)


def write(path: str | os.PathLike[str], file: LDrawFile) -> None:
    """Write a file atomically (.mpd with ``0 FILE`` blocks when it has submodels)."""
    _bg.write_ldraw(os.fspath(path), file)


def check(file: LDrawFile) -> list[ModelCheck]:
    """Every model resolved against the library (its :class:`StepItem` s, step by step) and the
    physical validity of each of its steps, one :class:`ModelCheck` per model of the file."""
    return _bg.check_ldraw(file)


def resolve_colour(code: int, inherited: int) -> int:
    """LDraw's colour inheritance: the colour of a line written in ``code`` inside a model placed
    in colour ``inherited``. 16 is ``inherited`` (16 at the top level: nothing places the main
    model); 24 is the edge colour of ``inherited`` as a direct colour ``0x2RRGGBB`` (from
    LDConfig.ldr's edges; ``#333333`` for colours without one) and stays 24 while ``inherited``
    is 16; any other code, direct colours ``0x2RRGGBB`` included, is the line's own. Applied
    level by level it resolves any depth of submodels (``FlatPart.colour`` is resolved so)."""
    return _bg.resolve_colour(code, inherited)


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
    """Summary of a file: counts, library coverage, lattice flags and per-step validity (a
    plain report, written as JSON by ``python -m mepnet.ldraw info --json``)."""
    flat = file.flatten()
    checks = check(file)
    counts = collections.Counter(p.name for p in flat)
    known = {n: _bg.resolve_part(n) for n in counts}
    placed = [it for it in _all_items(checks) if it.kind != "submodel"]
    step_checks = [_step_report(m.name, s) for m in checks for s in m.steps]
    checked = [s for s in step_checks if s["results"] is not None]
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
        "off_lattice": sum(1 for it in placed if it.off_lattice),
        "non_yaw": sum(1 for it in placed if it.non_yaw),
        "steps_checked": len(checked),
        "steps_valid": len(valid),
        "steps_unverified": len(unverified),
        "steps_invalid": len(checked) - len(valid) - len(unverified),
        "step_checks": step_checks,
    }


def _all_items(checks: Sequence[ModelCheck]) -> Iterator[StepItem]:
    return (it for m in checks for step in m.items for it in step)


def _step_report(model: str, step: StepCheck) -> dict[str, Any]:
    """One step of :func:`inspect`'s report; ``verdict`` only for checked steps."""
    report: dict[str, Any] = {
        "model": model,
        "step": step.step,
        "items": step.items,
        "placeable": step.placeable,
        "results": None if step.results is None else list(step.results),
        "complete_base": step.complete_base,
    }
    if step.results is not None:
        report["verdict"] = _verdict(step)
    return report


def _verdict(step: StepCheck) -> str:
    """A checked step's verdict: valid; invalid (a collision, or unsupported although everything
    below is known); or unverified (only "not connected" while earlier parts are outside the
    library)."""
    bad = [msg for ok, msg in step.results or () if not ok]
    if not bad:
        return "valid"
    if not step.complete_base and all("not connected" in m for m in bad):
        return "unverified"
    return "invalid"


def build_order(checks: Sequence[ModelCheck], root: int = 0) -> list[int]:
    """Model indices (of :func:`check`) with every submodel before the models that use it,
    ``root`` last. Walked with an explicit stack: nesting depth is data, not recursion."""
    order: list[int] = []
    if not checks:
        return order
    seen = {root}
    stack: list[tuple[int, Iterator[int]]] = [(root, iter(_submodels(checks, root)))]
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


def _submodels(checks: Sequence[ModelCheck], m: int) -> list[int]:
    return [it.submodel for step in checks[m].items for it in step if it.submodel is not None]


__all__ = [
    "IDENTITY",
    "FlatPart",
    "LDrawFile",
    "LDrawModel",
    "LDrawRef",
    "ModelCheck",
    "StepCheck",
    "StepItem",
    "build_order",
    "check",
    "inspect",
    "lattice_pose",
    "ldraw_placement",
    "load_part_mesh",
    "parse",
    "read",
    "resolve_colour",
    "write",
]
