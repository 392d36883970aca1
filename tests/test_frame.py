"""The real frame (DESIGN §2): a model read from LDraw is drawn as LDraw tools draw it.

LDraw's front view has the camera on LDraw's -z side with LDraw's -y up and LDraw's +x to the
right of the picture; its top view looks down with LDraw's front (-z) at the bottom of the
picture. mepnet's lattice is LDraw turned half a turn about x, so its front view is azimuth 0
(the camera on the lattice's +z side). A mirrored world (y flipped alone) puts every part of an
asymmetric model on the wrong side of one of these pictures.
"""

from __future__ import annotations

import numpy as np
import pytest
from mepnet import _brickgeom as _bg
from mepnet.ldraw import io

#: An asymmetric model (LDraw units, y down): a red 2x4 brick, a yellow 1x1 brick on its right
#: (+x) front (-z) end, a blue 2x2 brick on its left (-x) back (+z) end, and a green 1x2 plate
#: on top of the yellow brick. LDraw's identity matrix throughout.
MODEL = """0 FILE hand.ldr
1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
1 14 30 -24 -10 1 0 0 0 1 0 0 0 1 3005.dat
1 1 -30 -24 10 1 0 0 0 1 0 0 0 1 3003.dat
1 2 30 -48 -10 0 0 1 0 1 0 -1 0 0 3023.dat
0 NOFILE
"""


def _assembly() -> tuple[_bg.Assembly, list[int]]:
    """The model placed through mepnet's LDraw conversion; instance ids in file order."""
    f = io.parse(MODEL.encode(), "hand.ldr")
    asm = _bg.Assembly()
    ids = []
    for ref in f.models[0].steps[0]:
        yaw, t, off_lattice, non_yaw = io.lattice_pose(ref.position, ref.matrix)
        assert not off_lattice and not non_yaw
        part = _bg.Component.primitive(ref.name.removesuffix(".dat"))
        ids.append(asm.add(part, yaw, (t[0], t[1] + 3, t[2]), ref.colour))  # brick on the ground
    return asm, ids


def _centroids(elevation: float, azimuth: float) -> list[tuple[float, float, float, float]]:
    """(column, row, visible pixels, mean depth) of each part in a picture from this view."""
    asm, ids = _assembly()
    corners = np.array(
        [[x, y, z] for x in (-60.0, 60.0) for y in (0.0, 60.0) for z in (-30.0, 30.0)]
    )
    cam = _bg.Camera(elevation, azimuth).fitted(corners, 0.9)
    r = _bg.render(asm, cam, 200, 200)
    out = []
    for i in ids:
        hit = np.asarray(r.ids) == i
        rows, cols = np.nonzero(hit)
        if len(rows) == 0:
            out.append((float("nan"), float("nan"), 0.0, float("nan")))
        else:
            depth = float(np.asarray(r.depth)[hit].mean())
            out.append((float(cols.mean()), float(rows.mean()), float(len(rows)), depth))
    return out


def test_front_view_has_ldraw_plus_x_on_the_right_and_minus_y_up() -> None:
    red, yellow, blue, green = _centroids(0.0, 0.0)
    assert yellow[0] > red[0] + 40 > blue[0] + 80, "LDraw +x must be on the right"
    assert yellow[1] < red[1] and blue[1] < red[1], "LDraw -y must be up"
    assert green[1] < yellow[1], "the plate sits on top of the yellow brick"
    # The yellow brick stands at the front (LDraw -z), the blue one at the back.
    assert yellow[2] > 0 and blue[2] > 0
    assert yellow[3] + 8 < blue[3], "LDraw -z must be nearer the camera in the front view"


def test_top_view_has_ldraw_front_at_the_bottom() -> None:
    red, yellow, blue, green = _centroids(89.0, 0.0)
    assert green[2] > 0 and yellow[2] == 0, "from above the plate covers the 1x1 brick"
    assert green[0] > blue[0] + 80, "LDraw +x must be on the right"
    assert green[1] > blue[1] + 10, "LDraw -z (the front) must be at the bottom"


def test_the_plate_turned_in_ldraw_turns_the_same_way() -> None:
    """The 1x2 plate is turned a quarter turn in LDraw (its long side along LDraw's z): it must
    be long along the picture's vertical in the top view, not the horizontal."""
    asm, ids = _assembly()
    cam = _bg.Camera(89.0, 0.0).fitted(
        np.array([[x, y, z] for x in (-60.0, 60.0) for y in (0.0, 60.0) for z in (-30.0, 30.0)]),
        0.9,
    )
    r = _bg.render(asm, cam, 200, 200)
    rows, cols = np.nonzero(np.asarray(r.ids) == ids[3])
    assert np.ptp(rows) > 1.6 * np.ptp(cols)


@pytest.mark.parametrize("yaw", range(4))
def test_ldraw_placement_round_trip_is_a_rotation(yaw: int) -> None:
    """The lattice pose of an LDraw placement and back; the LDraw matrix of a lattice yaw is a
    proper rotation turning the other way about y (the frames differ by half a turn about x)."""
    pos, m = io.ldraw_placement(yaw, (3, 2, -5))
    m = np.array(m)
    assert np.isclose(np.linalg.det(m), 1.0)
    assert pos == [30.0, -16.0, 50.0]
    back = io.lattice_pose(pos, m.tolist())
    assert back[0] == yaw and tuple(back[1]) == (3, 2, -5)
    # lattice yaw 1 maps lattice +x to lattice -z, which is LDraw +z: LDraw's matrix must too.
    turned = m @ np.array([1.0, 0.0, 0.0])
    expected = {0: (1, 0, 0), 1: (0, 0, 1), 2: (-1, 0, 0), 3: (0, 0, -1)}[yaw]
    assert np.allclose(turned, expected)
