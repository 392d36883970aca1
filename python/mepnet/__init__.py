"""mepnet: LEGO building manuals to machine-executable build plans.

Users import from here (or the submodules ``mepnet.geom``, ``mepnet.ldraw``), never from
``mepnet._brickgeom``.
"""

from mepnet.geom import (
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

__version__ = "0.1.0"

__all__ = [
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
]
