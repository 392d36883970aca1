"""Brick geometry: the part library, components and assemblies (re-exported from the Rust core).

Units (DESIGN §2): lattice x and z in half-studs (10 LDU), y in plates (8 LDU), y up. A pose is
``(yaw, (x, y, z))``: ``yaw`` quarter turns about +y, then an integer lattice translation.
Meshes are in LDU, y up.
"""

import numpy as np

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
    Rendering,
    RenderStyle,
    UnknownPartError,
    part_ids,
    part_info,
    part_mesh,
    render,
    resolve_part,
)


def placement_box(
    component: Component, yaw: int, t: tuple[int, int, int]
) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """The lattice box ``component`` fills at ``(yaw, t)``: its lowest and highest cells."""
    alone = Assembly()
    alone.add(component, yaw, t, 0)
    box = alone.bounds()
    assert box is not None  # every component fills a cell
    return box


#: How high :func:`component_box` places a component: no part reaches the ground from there.
_LIFT = 1 << 10


def component_box(
    component: Component, yaw: int
) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """The lattice box ``component`` fills turned by ``yaw``, about its origin (as
    :func:`placement_box` at ``t`` = 0, where a part reaching below its origin would be
    below the ground)."""
    lo, hi = placement_box(component, yaw, (0, _LIFT, 0))
    return (lo[0], lo[1] - _LIFT, lo[2]), (hi[0], hi[1] - _LIFT, hi[2])


def rotate_lattice(
    p: tuple[int, int, int] | list[int], yaw: int, t: tuple[int, int, int] | list[int] = (0, 0, 0)
) -> tuple[int, int, int]:
    """A lattice point turned by ``yaw`` quarter turns about +y, then moved by ``t``:
    yaw 1 maps (x, y, z) to (z, y, -x) (as the Rust core's ``Pose``)."""
    x, y, z = p
    r = [(x, y, z), (z, y, -x), (-x, y, -z), (-z, y, x)][yaw % 4]
    return (int(r[0] + t[0]), int(r[1] + t[1]), int(r[2] + t[2]))


#: LDU per lattice cell along x, y and z.
LDU_PER_CELL = np.array([10.0, 8.0, 10.0])


def rotate_ldu(p: tuple[float, float, float] | np.ndarray, yaw: int) -> np.ndarray:
    """A point in LDU turned by ``yaw`` quarter turns about +y (as :func:`rotate_lattice`)."""
    x, y, z = p
    return np.array([(x, y, z), (z, y, -x), (-x, y, -z), (-z, y, x)][yaw % 4], dtype=float)


def bounds_corners(assembly: Assembly, drop: int = 0) -> list[list[float]]:
    """The 8 corners (LDU, y up) of an assembly's occupied voxel bounds, lowered by ``drop``
    plates."""
    (lo, hi) = assembly.bounds() or ((0, 0, 0), (0, 0, 0))
    return [
        [x * 10.0, (y - drop) * 8.0, z * 10.0]
        for x in (lo[0], hi[0] + 1)
        for y in (lo[1], hi[1] + 1)
        for z in (lo[2], hi[2] + 1)
    ]


def manual_camera(
    assembly: Assembly,
    elevation: float = 30.0,
    azimuth: float = 315.0,
    fill: float = 0.85,
    drop: int = 0,
) -> Camera:
    """A manual-style camera framing an assembly (the shape fills ``fill`` of the frame). The
    default view is LDraw tools' front-left three-quarter view: the camera on LDraw's front
    (-z, the lattice's +z) and left (-x), 30 degrees up."""
    corners = np.array(bounds_corners(assembly, drop), dtype=np.float64)
    return Camera(elevation, azimuth).fitted(corners, fill)


def submodule_from_placed(
    name: str, placed: list[tuple[Component, int, tuple[int, int, int], int]]
) -> Component:
    """A submodule as one component from its placed components ``(component, yaw, t, colour)``
    in its own frame (:meth:`Component.from_placed`, in the core: every brick placed with its
    component; a brick in LDraw's main colour 16 takes the colour its component is placed
    with, any other colour is the brick's own)."""
    return Component.from_placed(
        name, [(c, int(y), tuple(int(v) for v in t), int(col)) for c, y, t, col in placed]
    )


#: Attach-kind codes returned by :meth:`Assembly.candidates`.
ATTACH_KINDS = ("on_studs", "from_below", "ground")

__all__ = [
    "component_box",
    "placement_box",
    "ATTACH_KINDS",
    "LDU_PER_CELL",
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
    "Rendering",
    "RenderStyle",
    "UnknownPartError",
    "part_ids",
    "part_info",
    "part_mesh",
    "render",
    "bounds_corners",
    "manual_camera",
    "resolve_part",
    "rotate_ldu",
    "rotate_lattice",
    "submodule_from_placed",
]
