"""LDraw: reading and writing .ldr / .mpd files (:mod:`.io`), converting real models into
manuals (:mod:`.convert`) and ``python -m mepnet.ldraw`` (:mod:`.cli`)."""

from mepnet.ldraw.cli import main
from mepnet.ldraw.io import (
    IDENTITY,
    FlatPart,
    LDrawFile,
    LDrawModel,
    LDrawRef,
    ModelCheck,
    StepCheck,
    StepItem,
    build_order,
    check,
    inspect,
    lattice_pose,
    ldraw_placement,
    load_part_mesh,
    parse,
    read,
    write,
)

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
    "main",
    "parse",
    "read",
    "write",
]
