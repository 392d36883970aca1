"""Comparing a plan with the truth up to the frame no picture can fix.

With cameras estimated from the pictures (:mod:`mepnet.cameras`), a build's first step has
nothing built to anchor it: a quarter turn of the whole build about the vertical axis and any
lattice shift of it give the same pictures under other cameras, so mepnet fixes the frame by
convention. A plan is therefore compared with the truth up to one rigid lattice motion
(:class:`Motion`, a quarter turn and a shift) per build, chosen to align the first step's
predicted placements with the true ones (among the motions that do, the one that makes most of
the build right). Under teacher forcing every later step is predicted on the true shape, in the
true frame, and is compared as it is, up to the motions that map the true base onto itself
(parts, colours and voxels): those give identical pictures too. With the cameras the manual
states, every motion is the identity and nothing changes.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.geom import rotate_lattice

#: A placed component: (component, yaw, t, colour).
Placed = tuple[_bg.Component, int, tuple[int, int, int], int]


@dataclass(frozen=True)
class Motion:
    """A rigid lattice motion of a whole build: ``turn`` quarter turns about +y through the
    lattice origin, then ``shift``."""

    turn: int = 0
    shift: tuple[int, int, int] = (0, 0, 0)

    def apply(self, yaw: int, t: Sequence[int]) -> tuple[int, tuple[int, int, int]]:
        """A placement ``(yaw, t)`` moved."""
        return (int(yaw) + self.turn) % 4, rotate_lattice(tuple(t), self.turn, self.shift)  # type: ignore[arg-type]

    def inverse(self) -> Motion:
        """The motion undoing this one."""
        back = (4 - self.turn) % 4
        return Motion(back, tuple(-v for v in rotate_lattice(self.shift, back)))  # type: ignore[arg-type]

    def after(self, first: Motion) -> Motion:
        """This motion applied after ``first``."""
        return Motion(
            (self.turn + first.turn) % 4,
            rotate_lattice(first.shift, self.turn, self.shift),  # type: ignore[arg-type]
        )

    @property
    def is_identity(self) -> bool:
        return self.turn % 4 == 0 and self.shift == (0, 0, 0)

    def yaw_matrix(self) -> np.ndarray:
        """The 3x3 rotation of world points (LDU, y up) by the turn."""
        return np.array([rotate_lattice(e, self.turn) for e in np.eye(3, dtype=int)]).T

    def to_json(self) -> dict[str, object]:
        return {"turn": self.turn, "shift": list(self.shift)}


IDENTITY = Motion()


def placement_key(placed: Placed) -> tuple[tuple[str, int, tuple[tuple[int, ...], ...]], ...]:
    """A placed component as comparable data: per brick (a submodule expanded) its part,
    colour and occupied voxels, sorted (so symmetric parts placed either way compare equal)."""
    comp, yaw, t, colour = placed
    whole = _bg.Component.from_placed("key", [(comp, int(yaw), tuple(int(v) for v in t), colour)])
    keys = []
    for part, b_yaw, b_t, b_colour in whole.bricks:
        cells = _bg.Component.from_placed(
            "brick", [(_bg.Component.primitive(part), b_yaw, b_t, 16)]
        ).voxels
        keys.append((part, int(b_colour), tuple(sorted(tuple(int(x) for x in v) for v in cells))))
    return tuple(sorted(keys))


def moved(placed: Placed, motion: Motion) -> Placed:
    """A placed component moved by ``motion``."""
    comp, yaw, t, colour = placed
    y, mt = motion.apply(yaw, t)
    return comp, y, mt, colour


def candidate_motions(predicted: Iterable[Placed], true: Sequence[Placed]) -> list[Motion]:
    """Motions that put one of the ``predicted`` placements exactly onto a ``true`` one of the
    same component (every quarter turn), the identity first."""
    out = [IDENTITY]
    for comp, yaw, t, _ in predicted:
        for t_comp, t_yaw, t_t, _ in true:
            if t_comp.name != comp.name or t_comp.is_submodule != comp.is_submodule:
                continue
            for turn in range(4):
                rt = rotate_lattice(tuple(t), turn)
                m = Motion(turn, tuple(int(a - b) for a, b in zip(t_t, rt, strict=True)))  # type: ignore[arg-type]
                if m not in out and (t_comp.symmetry != 1 or (yaw + turn) % 4 == t_yaw % 4):
                    out.append(m)
    return out


def matches(predicted: Sequence[Placed], true: Sequence[Placed], motion: Motion = IDENTITY) -> int:
    """How many of the ``true`` placements a moved prediction places exactly (bricks, colours
    and voxels; each prediction counts once)."""
    want = [placement_key(p) for p in true]
    hits = 0
    for p in predicted:
        k = placement_key(moved(p, motion))
        if k in want:
            want.remove(k)
            hits += 1
    return hits


def best_motion(
    predicted: Sequence[Placed], true: Sequence[Placed], candidates: Iterable[Motion]
) -> tuple[Motion, int]:
    """The candidate motion under which most ``true`` placements are predicted exactly (the
    first of equals), and that count."""
    best, hits = IDENTITY, -1
    for m in candidates:
        h = matches(predicted, true, m)
        if h > hits:
            best, hits = m, h
    return best, max(hits, 0)


def symmetries(base: Sequence[Placed]) -> list[Motion]:
    """The motions other than the identity that map a shape onto itself (parts, colours and
    voxels)."""
    if not base:
        return []
    cells = np.array(
        [v for comp, yaw, t, _ in base for v in _placed_voxels(comp, yaw, t)], dtype=np.int64
    )
    key = sorted(k for p in base for k in placement_key(p))
    out = []
    for turn in (1, 2, 3):
        turned = [moved(p, Motion(turn)) for p in base]
        turned_cells = np.array(
            [v for comp, yaw, t, _ in turned for v in _placed_voxels(comp, yaw, t)], dtype=np.int64
        )
        shift = tuple(int(v) for v in cells.min(axis=0) - turned_cells.min(axis=0))
        m = Motion(turn, shift)  # type: ignore[arg-type]
        if sorted(k for p in base for k in placement_key(moved(p, m))) == key:
            out.append(m)
    return out


def _placed_voxels(
    comp: _bg.Component, yaw: int, t: tuple[int, int, int]
) -> list[tuple[int, int, int]]:
    whole = _bg.Component.from_placed("cells", [(comp, int(yaw), tuple(int(v) for v in t), 16)])
    return [tuple(int(x) for x in v) for v in whole.voxels]  # type: ignore[misc]
