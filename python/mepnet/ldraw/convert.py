"""Real LDraw models as manuals (``python -m mepnet.ldraw to-manual``).

``0 STEP`` gives the steps; submodels become submodules with their own manuals; parts outside
the 72-part library are replaced by a library part of the same footprint and height when one
exists (measured on the real part geometry of an LDraw library), otherwise dropped, as the paper
did for its Classics and Architecture sets. Every substitution and drop is recorded in
``manual.json`` under ``source``. Images are rendered with brickgeom's renderer and a
manual-style camera (one view per model, the front-left three-quarter view of LDraw tools:
elevation 30, azimuth 315; framed to the shape after each step).

Colours follow LDraw's inheritance (:func:`mepnet.ldraw.io.resolve_colour`): a line in colour 16
takes the colour of the reference placing its model, through any depth of submodels, starting
from the main model of the file (so a wrapper's colour reaches the model inside it); 24 is that
colour's edge colour. A submodel whose parts inherit a colour becomes one submodule per colour it
is placed in, each built in its real colours.
"""

from __future__ import annotations

import collections
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
from mepnet.ldraw.io import LDrawFile, ModelCheck, build_order, check, resolve_colour
from mepnet.manual import MAIN_COLOUR, write_manual

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


#: A model to convert: (model index, the colour it inherits; MAIN_COLOUR when none of its parts
#: inherits one, so that it is converted once whatever places it).
Variant = tuple[int, int]


@dataclass(frozen=True)
class Variants:
    """The models under a root with the colours they inherit (:func:`variants`)."""

    #: every variant, submodels before the models that use them, the root last
    order: list[Variant]
    #: models whose lines (their own, or those of the submodels they place) use 16 or 24
    inherits: frozenset[int]

    def key(self, model: int, colour: int) -> Variant:
        """The variant of ``model`` placed in ``colour``."""
        return (model, colour if model in self.inherits else MAIN_COLOUR)


def variants(checks: list[ModelCheck], root: int, colour: int) -> Variants:
    """The models under ``root`` (placed in ``colour``) with the colours they inherit. A model
    whose lines (its own, or those of the submodels it places) use 16 or 24 is one variant per
    colour it is placed in; any other model is one variant. Walked with an explicit stack, like
    :func:`build_order`."""
    inherits: set[int] = set()
    for m in build_order(checks, root):
        if any(
            it.submodel in inherits if it.submodel is not None else it.colour in (MAIN_COLOUR, 24)
            for step in checks[m].items
            for it in step
        ):
            inherits.add(m)
    found = Variants([], frozenset(inherits))

    def children(v: Variant) -> list[Variant]:
        m, c = v
        return [
            found.key(it.submodel, resolve_colour(it.colour, c))
            for step in checks[m].items
            for it in step
            if it.submodel is not None
        ]

    top = found.key(root, colour)
    seen = {top}
    stack = [(top, iter(children(top)))]
    while stack:
        v, rest = stack[-1]
        child = next(rest, None)
        if child is None:
            stack.pop()
            found.order.append(v)
        elif child not in seen:
            seen.add(child)
            stack.append((child, iter(children(child))))
    return found


def variant_name(name: str, colour: int) -> str:
    """A submodule's name for one of several colour variants of model ``name``."""
    stem, ext = os.path.splitext(name)
    shown = f"{colour:#x}" if colour >= 0x2000000 else str(colour)
    return f"{stem} (colour {shown}){ext}"


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

    root, root_colour = 0, MAIN_COLOUR  # the main model: nothing places it
    while True:
        top = [it for step in checks[root].items for it in step]
        subs = [it.submodel for it in top if it.submodel is not None]
        if not top or len(subs) < len(top):
            break
        biggest = max(range(len(subs)), key=lambda i: size_of(subs[i]))
        if len(top) == 1 or top[biggest].off_lattice or top[biggest].non_yaw:
            root = subs[biggest]
            # the wrapper's reference gives the model its colour
            root_colour = resolve_colour(top[biggest].colour, root_colour)
        else:
            break
    subs_finder = Substitutes(ldraw_dir)
    substitutions: list[dict[str, Any]] = []
    dropped: list[dict[str, Any]] = []
    # (model, inherited colour) -> (component, y shift of its frame, submodule slot)
    converted: dict[Variant, tuple[_bg.Component, int, int]] = {}
    submodules: list[dict[str, Any]] = []
    main_build: dict[str, Any] | None = None
    kept_parts = 0
    tree = variants(checks, root, root_colour)
    per_model = collections.Counter(m for m, _ in tree.order)
    for m, inherited in tree.order:
        model = checks[m]
        lift = 1 << 10  # build high first: model frames may reach below y = 0
        placed: list[tuple[_bg.Component, Any, int, tuple[int, int, int], int]] = []
        origin: list[dict[str, Any]] = []  # where each placed item comes from
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
                colour = resolve_colour(it.colour, inherited)
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
                    sub = tree.key(it.submodel, colour)
                    if sub not in converted:
                        dropped.append({**where, "reason": "submodel has no convertible parts"})
                        continue
                    comp, shift, slot = converted[sub]
                    placed.append((comp, slot, yaw, (t[0], t[1] - shift + lift, t[2]), colour))
                elif it.part is not None:
                    placed.append(
                        (
                            _bg.Component.primitive(it.part),
                            it.part,
                            yaw,
                            (t[0], t[1] + lift, t[2]),
                            colour,
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
                            colour,
                        )
                    )
                origin.append(where)
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
                dropped.append({**origin[k], "reason": f"overlaps another part ({e})"})
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
        name = model.name if per_model[m] == 1 else variant_name(model.name, inherited)
        comp = submodule_from_placed(
            name,
            [(c, yaw, t, col) for c, _, yaw, t, col in (placed[i] for i in sorted(keep_set))],
        )
        bricks = comp.bricks
        converted[(m, inherited)] = (comp, shift, len(submodules))
        submodules.append(
            {
                "name": name,
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
