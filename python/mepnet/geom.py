"""Brick geometry: the part library, components and assemblies (re-exported from the Rust core).

Units (DESIGN §2): lattice x and z in half-studs (10 LDU), y in plates (8 LDU), y up. A pose is
``(yaw, (x, y, z))``: ``yaw`` quarter turns about +y, then an integer lattice translation.
Meshes are in LDU, y up.
"""

from mepnet._brickgeom import (
    Assembly,
    BelowGroundError,
    BrickGeomError,
    Camera,
    CollisionError,
    Component,
    FileError,
    InvalidArgumentError,
    LDrawError,
    NoSuchInstanceError,
    NotConnectedError,
    OutOfRangeError,
    PlacementError,
    UnknownPartError,
    part_ids,
    part_info,
    part_mesh,
    render,
    resolve_part,
)


def rotate_lattice(
    p: tuple[int, int, int] | list[int], yaw: int, t: tuple[int, int, int] | list[int] = (0, 0, 0)
) -> tuple[int, int, int]:
    """A lattice point turned by ``yaw`` quarter turns about +y, then moved by ``t``:
    yaw 1 maps (x, y, z) to (z, y, -x) (as the Rust core's ``Pose``)."""
    x, y, z = p
    r = [(x, y, z), (z, y, -x), (-x, y, -z), (-z, y, x)][yaw % 4]
    return (int(r[0] + t[0]), int(r[1] + t[1]), int(r[2] + t[2]))


#: Attach-kind codes returned by :meth:`Assembly.candidates`.
ATTACH_KINDS = ("on_studs", "from_below", "ground")

__all__ = [
    "ATTACH_KINDS",
    "Assembly",
    "BelowGroundError",
    "Camera",
    "BrickGeomError",
    "CollisionError",
    "Component",
    "FileError",
    "InvalidArgumentError",
    "LDrawError",
    "NoSuchInstanceError",
    "NotConnectedError",
    "OutOfRangeError",
    "PlacementError",
    "UnknownPartError",
    "part_ids",
    "part_info",
    "part_mesh",
    "render",
    "resolve_part",
    "rotate_lattice",
]
