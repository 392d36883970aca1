"""Binding tests for mepnet.geom: dtypes, shapes, errors and GIL release (not the geometry again:
that is covered by the Rust property tests)."""

from __future__ import annotations

import threading
import time

import mepnet
import numpy as np
import pytest
from mepnet import Assembly, Component


def brick() -> Component:
    return Component.primitive("3001")


def test_part_ids_are_the_library():
    ids = mepnet.part_ids()
    assert len(ids) == len(set(ids))
    assert "3001" in ids
    for pid in ids:
        assert mepnet.resolve_part(pid) == pid


def test_aliases_resolve_case_and_suffix_insensitively():
    assert mepnet.resolve_part("3001.DAT") == "3001"
    assert mepnet.resolve_part("parts\\3001.dat") == "3001"
    assert mepnet.resolve_part("no-such-part") is None


def test_part_info_dtypes():
    info = mepnet.part_info("3001")
    for key in ("voxels", "studs", "anti_studs"):
        arr = info[key]
        assert arr.dtype == np.int32 and arr.ndim == 2 and arr.shape[1] == 3
    assert info["symmetry"] in (1, 2, 4)
    v, t = mepnet.part_mesh("3001")
    assert v.dtype == np.float32 and v.shape[1] == 3
    assert t.dtype == np.uint32 and t.shape[1] == 3
    assert t.max() < len(v)


def test_unknown_part_raises_typed_error():
    with pytest.raises(mepnet.UnknownPartError, match="unknown part id 'xyz'"):
        Component.primitive("xyz")
    with pytest.raises(mepnet.BrickGeomError):
        mepnet.part_info("xyz")


def test_assembly_arrays_and_codes():
    asm = Assembly()
    c = brick()
    assert asm.add(c, 0, (0, 3, 0)) == 0
    assert len(asm) == 1
    occ, origin = asm.occupancy()
    assert occ.dtype == np.uint8 and occ.ndim == 3
    assert int(occ.sum()) == len(c.voxels)
    ids, origin2 = asm.brick_ids()
    assert ids.dtype == np.int32 and origin2 == origin
    assert set(np.unique(ids)) == {-1, 0} or set(np.unique(ids)) == {0}
    fs = asm.free_studs()
    assert fs.dtype == np.int32 and fs.shape == (len(c.studs), 3)
    ts, kinds = asm.candidates(c, 0)
    assert ts.dtype == np.int32 and kinds.dtype == np.uint8 and len(ts) == len(kinds) > 0
    assert set(kinds.tolist()) <= {0, 1, 2}
    poses = np.array([[0, 0, 6, 0], [0, 0, 3, 0], [0, 100, 30, 0], [0, 0, 1, 0]], dtype=np.int64)
    codes = asm.check_many(c, poses)
    assert codes.dtype == np.int8
    assert codes.tolist() == [0, -1, -2, -3]


def test_placement_errors_are_typed():
    asm = Assembly()
    c = brick()
    asm.add(c, 0, (0, 3, 0))
    with pytest.raises(mepnet.CollisionError, match="collides with instance 0"):
        asm.check(c, 0, (0, 3, 0))
    with pytest.raises(mepnet.NotConnectedError):
        asm.check(c, 0, (100, 30, 0))
    with pytest.raises(mepnet.BelowGroundError):
        asm.add(c, 0, (50, 0, 0))
    with pytest.raises(mepnet.OutOfRangeError):
        asm.check(c, 0, (10**6, 3, 0))
    with pytest.raises(mepnet.InvalidArgumentError, match="yaw"):
        asm.check(c, 7, (0, 6, 0))
    with pytest.raises(mepnet.NoSuchInstanceError):
        asm.remove(42)
    with pytest.raises(ValueError, match=r"\(N, 4\)"):
        asm.check_many(c, np.zeros((3, 3), dtype=np.int64))
    with pytest.raises(ValueError, match="ground"):
        asm.candidates(c, 0, "sideways")
    # all of them share the base class
    assert issubclass(mepnet.CollisionError, mepnet.PlacementError)
    assert issubclass(mepnet.PlacementError, mepnet.BrickGeomError)


def test_add_remove_restores_state():
    asm = Assembly()
    c = brick()
    asm.add(c, 0, (0, 3, 0))
    before = asm.copy()
    i = asm.add(c, 1, (1, 6, 1))
    assert not asm.same_state(before)
    comp, yaw, t = asm.remove(i)
    assert comp.name == "3001" and yaw == 1 and t == (1, 6, 1)
    assert asm.same_state(before)


def test_submodule_from_bricks_and_assembly():
    poses = np.array([[0, -2, 3, 0], [0, 2, 3, 0]], dtype=np.int64)
    sub = Component.from_bricks("pair", ["3003", "3003"], poses)
    assert sub.is_submodule and sub.symmetry == 2 and len(sub.topmost) == 2
    assert sub.keypoints.dtype == np.float32 and sub.keypoints.shape == (2, 3)
    asm = Assembly()
    asm.add(Component.primitive("3003"), 0, (-2, 3, 0))
    asm.add(Component.primitive("3003"), 0, (2, 3, 0))
    same = asm.to_component("pair")
    assert np.array_equal(same.voxels, sub.voxels)
    with pytest.raises(ValueError, match=r"\(2, 4\)"):
        Component.from_bricks("bad", ["3003", "3003"], poses[:1])
    with pytest.raises(mepnet.InvalidArgumentError, match="no bricks"):
        Assembly().to_component("empty")


def test_check_step_reports_each_component():
    asm = Assembly()
    c = brick()
    asm.add(c, 0, (0, 3, 0))
    res = asm.check_step([(c, 0, (0, 9, 0)), (c, 0, (0, 6, 0)), (c, 0, (0, 6, 0))])
    assert res[0] == (True, "on_studs") and res[1] == (True, "on_studs")
    assert res[2][0] is False and "collides" in res[2][1]
    assert len(asm) == 1


def test_long_call_releases_the_gil():
    """While one thread enumerates a huge ground region in Rust, another keeps running Python."""
    asm = Assembly()
    c = Component.primitive("3024")
    region = (-1000, 1000, -1000, 1000)  # 4 million ground positions
    t0 = time.perf_counter()
    asm.candidates(c, 0, region)
    single = time.perf_counter() - t0
    ticks: list[float] = []
    done = threading.Event()

    def work() -> None:
        asm.candidates(c, 0, region)
        done.set()

    th = threading.Thread(target=work)
    th.start()
    while not done.is_set():
        ticks.append(time.perf_counter())
        time.sleep(0.001)
    th.join()
    # With the GIL held for the whole call the main thread would be frozen: one huge gap.
    gaps = np.diff(ticks) if len(ticks) > 1 else np.array([single])
    assert len(ticks) >= 5, f"main thread ran only {len(ticks)} times during a {single:.2f}s call"
    assert gaps.max() < max(0.5 * single, 0.05)
