"""Real LDraw models as manuals (``python -m mepnet.ldraw to-manual``).

``0 STEP`` gives the steps; submodels become submodules with their own manuals; parts outside
the 72-part library are replaced by a library part of the same footprint and height when one
exists (measured on the real part geometry of an LDraw library), otherwise dropped, as the paper
did for its Classics and Architecture sets. Every substitution and drop is recorded in
``manual.json`` under ``source``. Images are rendered with brickgeom's renderer and a
manual-style camera (elevation 30, azimuth 225, framed to the shape after each step).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.geom import (
    LDU_PER_CELL,
    BrickGeomError,
    manual_camera,
    rotate_ldu,
    submodule_from_placed,
)
from mepnet.ldraw.io import LDrawFile, build_order, check
from mepnet.manual import write_manual

#: Library parts eligible as substitutes: rectangular bricks, plates and tiles.
RECTANGULAR = ("simple", "tile")
ROUND_NAMES = ("Round", "Cone", "Grille")


@dataclass(frozen=True)
class Box:
    """Axis-aligned bounds of a part's body in its own frame (LDU, y up), studs excluded."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    studs: bool

    @property
    def size(self) -> tuple[float, float, float]:
        return tuple(h - low for low, h in zip(self.lo, self.hi, strict=True))  # type: ignore[return-value]

    @property
    def anchor(self) -> np.ndarray:
        """Bottom centre."""
        return np.array([(self.lo[0] + self.hi[0]) / 2, self.lo[1], (self.lo[2] + self.hi[2]) / 2])


def library_box(part: str) -> Box:
    """Body bounds of a library part from its voxels."""
    v = _bg.part_info(part)["voxels"]
    lo, hi = v.min(axis=0), v.max(axis=0) + 1
    return Box(
        tuple(lo * LDU_PER_CELL), tuple(hi * LDU_PER_CELL), len(_bg.part_info(part)["studs"]) > 0
    )  # type: ignore[arg-type]


class Substitutes:
    """Finds library parts with the footprint and height of parts outside the library."""

    def __init__(self, ldraw_dir: str | None):
        self.ldraw_dir = ldraw_dir
        self.cache: dict[str, tuple[Box | None, str]] = {}
        self.library = []
        for p in _bg.part_ids():
            info = _bg.part_info(p)
            if info["category"] in RECTANGULAR and not any(w in info["name"] for w in ROUND_NAMES):
                box = library_box(p)
                # only parts whose voxels fill their box (true rectangles)
                if len(info["voxels"]) == int(np.prod(np.array(box.size) / [10, 8, 10])):
                    self.library.append((p, box))

    def measure(self, name: str) -> tuple[Box | None, str]:
        """Body bounds of a part from the LDraw library, or why it cannot be measured."""
        if name in self.cache:
            return self.cache[name]
        if self.ldraw_dir is None:
            result: tuple[Box | None, str] = (None, "no LDraw library to measure it (--ldraw-dir)")
        else:
            try:
                v, _, studs = _bg.load_part_mesh(self.ldraw_dir, name)
                lo, hi = v.min(axis=0), v.max(axis=0)
                top = hi[1] - (4.0 if studs > 0 else 0.0)
                result = (Box((lo[0], lo[1], lo[2]), (hi[0], top, hi[2]), studs > 0), "")
            except BrickGeomError as e:
                result = (None, f"geometry not loadable: {e}")
        self.cache[name] = result
        return result

    def find(
        self, name: str, yaw: int, t: tuple[int, int, int]
    ) -> tuple[tuple[str, int, tuple[int, int, int]] | None, str]:
        """A library part and pose covering the same body as part ``name`` at (yaw, t)."""
        box, why = self.measure(name)
        if box is None:
            return None, why
        sx, sy, sz = box.size
        if min(sx, sz) < 5 or sy < 4:
            return None, f"too thin to stand in for ({sx:.0f}x{sy:.0f}x{sz:.0f} LDU)"
        world = rotate_ldu(box.anchor, yaw) + np.array(t) * LDU_PER_CELL
        for part, lb in self.library:
            if lb.studs != box.studs:
                continue
            for turn in (0, 1):
                lx, ly, lz = lb.size if turn == 0 else (lb.size[2], lb.size[1], lb.size[0])
                if abs(lx - sx) > 2.0 or abs(lz - sz) > 2.0 or abs(ly - sy) > 2.0:
                    continue
                new_yaw = (yaw + turn) % 4
                origin = (world - rotate_ldu(lb.anchor, new_yaw)) / LDU_PER_CELL
                if np.all(np.abs(origin - np.round(origin)) < 0.05):
                    return (part, new_yaw, tuple(int(v) for v in np.round(origin))), ""  # type: ignore[return-value]
        return (
            None,
            f"no library part with its footprint and height ({sx:.0f}x{sy:.0f}x{sz:.0f} LDU)",
        )


def convert(
    file: LDrawFile,
    out: str | os.PathLike[str],
    ldraw_dir: str | None = None,
    size: int = 256,
    supersample: int = 1,
) -> dict[str, Any]:
    """Convert a model to a manual folder at ``out``; returns a report (counts, substitutions)."""

    checks = check(file)
    # A main model that only places submodels, the biggest of them tilted or off the lattice
    # for display (or that places a single submodel), is a wrapper: the biggest submodel is the
    # model, and the rest (minifigures, stands) is left out.
    sizes: dict[int, int] = {}

    for m in build_order(checks):  # submodels before the models that use them
        sizes[m] = sum(
            sizes.get(it.submodel, 0) if it.submodel is not None else 1
            for st in checks[m].items
            for it in st
        )

    def size_of(m: int) -> int:
        return sizes.get(m, 0)

    root = 0
    while True:
        top = [it for step in checks[root].items for it in step]
        subs = [it.submodel for it in top if it.submodel is not None]
        if not top or len(subs) < len(top):
            break
        biggest = max(range(len(subs)), key=lambda i: size_of(subs[i]))
        if len(top) == 1 or top[biggest].off_lattice or top[biggest].non_yaw:
            root = subs[biggest]
        else:
            break
    subs_finder = Substitutes(ldraw_dir)
    substitutions: list[dict[str, Any]] = []
    dropped: list[dict[str, Any]] = []
    # model index -> (component, y shift of its frame, submodule slot)
    converted: dict[int, tuple[_bg.Component, int, int]] = {}
    submodules: list[dict[str, Any]] = []
    main_build: dict[str, Any] | None = None
    kept_parts = 0
    for m in build_order(checks, root):
        model = checks[m]
        lift = 1 << 10  # build high first: model frames may reach below y = 0
        placed: list[tuple[_bg.Component, Any, int, tuple[int, int, int], int]] = []
        steps: list[list[int]] = []
        for s, items in enumerate(model.items):
            ids = []
            for it in items:
                where = {
                    "model": model.name,
                    "step": s + 1,
                    "line": it.line,
                    "name": it.name,
                }
                yaw, t = it.yaw, it.t
                if it.off_lattice or it.non_yaw:
                    dropped.append(
                        {
                            **where,
                            "reason": "off the lattice"
                            if it.off_lattice
                            else "not a pure yaw rotation",
                        }
                    )
                    continue
                if it.submodel is not None:
                    if it.submodel not in converted:
                        dropped.append({**where, "reason": "submodel has no convertible parts"})
                        continue
                    comp, shift, slot = converted[it.submodel]
                    placed.append((comp, slot, yaw, (t[0], t[1] - shift + lift, t[2]), it.colour))
                elif it.part is not None:
                    placed.append(
                        (
                            _bg.Component.primitive(it.part),
                            it.part,
                            yaw,
                            (t[0], t[1] + lift, t[2]),
                            it.colour,
                        )
                    )
                else:
                    found, why = subs_finder.find(it.name.removesuffix(".dat"), yaw, t)
                    if found is None:
                        dropped.append({**where, "reason": why})
                        continue
                    part, yaw2, t2 = found
                    substitutions.append({**where, "replaced_by": part})
                    placed.append(
                        (
                            _bg.Component.primitive(part),
                            part,
                            yaw2,
                            (t2[0], t2[1] + lift, t2[2]),
                            it.colour,
                        )
                    )
                ids.append(len(placed) - 1)
            if ids:
                steps.append(ids)
        if not steps:
            continue
        # Drop the shape onto the ground (lowest voxel at y = 0), measuring with an assembly.
        probe = _bg.Assembly()
        keep = []
        for k, (comp, _ref, yaw, t, col) in enumerate(placed):
            try:
                probe.add(comp, yaw, t, col)
                keep.append(k)
            except BrickGeomError as e:
                dropped.append(
                    {
                        "model": model.name,
                        "name": comp.name,
                        "reason": f"overlaps another part ({e})",
                    }
                )
        keep_set = set(keep)
        steps = [[i for i in st if i in keep_set] for st in steps]
        steps = [st for st in steps if st]
        if not steps:
            continue
        drop = probe.bounds()[0][1]
        placed = [(c, r, y, (t[0], t[1] - drop, t[2]), col) for c, r, y, t, col in placed]
        shift = lift - drop  # frame y + shift = ground-based y
        asm = _bg.Assembly()
        cameras = []
        for st in steps:
            for i in st:
                c, _, yaw, t, col = placed[i]
                asm.add(c, yaw, t, col)
            cameras.append(manual_camera(asm))
        build = _bg.render_plan(placed, steps, cameras, size, supersample, ldraw_dir)
        if m == root:
            main_build = build
            # parts of the final shape, submodules expanded (comparable with the file's count)
            kept_parts = sum(len(placed[i][0].bricks) for i in sorted(keep_set))
            break
        comp = submodule_from_placed(
            model.name,
            [(c, yaw, t, col) for c, _, yaw, t, col in (placed[i] for i in sorted(keep_set))],
        )
        bricks = comp.bricks
        converted[m] = (comp, shift, len(submodules))
        submodules.append(
            {
                "name": model.name,
                "symmetry": comp.symmetry,
                "topmost": comp.topmost,
                "bricks": [
                    {"part": b[0], "yaw": b[1], "t": list(b[2]), "colour": b[3]} for b in bricks
                ],
                "build": build,
            }
        )
    if main_build is None:
        raise BrickGeomError(f"{file.name}: no part of the main model can be placed on the lattice")
    manual = {"image_size": size, "main": main_build, "submodules": submodules}
    total = len(file.flatten())
    report = {
        "file": file.name,
        "main_model": checks[root].name,
        "steps": len(main_build["steps"]) + sum(len(s["build"]["steps"]) for s in submodules),
        "submodules": len(submodules),
        "parts_in_file": total,
        "parts_kept": kept_parts,
        "substituted": len(substitutions),
        "dropped": len(dropped),
    }
    source = {
        "kind": "ldraw",
        "file": file.name,
        "renderer": "brickgeom",
        "part_geometry": "ldraw" if ldraw_dir else "builtin",
        "report": report,
        "substitutions": substitutions,
        "dropped": dropped,
    }
    write_manual(out, manual, source, writer="mepnet.ldraw to-manual")
    return report
