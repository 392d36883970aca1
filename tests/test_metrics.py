"""Tests of mepnet.metrics and its bindings: dtypes, shapes and errors of the bindings, and the
properties the evaluation relies on (the nearest-neighbour search itself is checked against brute
force in the Rust unit tests)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from mepnet import Component, InvalidArgumentError, _brickgeom
from mepnet import metrics as M


@pytest.fixture(scope="module")
def brick() -> Component:
    return Component.primitive("3001")  # 2x4 brick


def pts(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).random((n, 3), dtype=np.float32)


# --- bindings ---------------------------------------------------------------------------------


def test_chamfer_distance_of_single_points():
    a = np.array([[1.0, 2.0, 3.0]], np.float32)
    b = np.array([[4.0, -2.0, 3.0]], np.float32)
    assert _brickgeom.chamfer_distance(a, b) == 50.0
    assert _brickgeom.chamfer_distance(a, a) == 0.0


def test_chamfer_distance_matches_numpy_brute_force():
    a, b = pts(200, 1) * 3, pts(150, 2)
    d = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
    want = d.min(1).mean(dtype=np.float64) + d.min(0).mean(dtype=np.float64)
    got = _brickgeom.chamfer_distance(a, b)
    assert got == pytest.approx(want, rel=1e-6)
    assert _brickgeom.chamfer_distance(b, a) == got  # exactly symmetric


def test_chamfer_distance_accepts_non_contiguous_views():
    a = np.asfortranarray(pts(50, 3))
    b = pts(100, 4)[::2]
    want = _brickgeom.chamfer_distance(np.ascontiguousarray(a), np.ascontiguousarray(b))
    assert _brickgeom.chamfer_distance(a, b) == want


def test_chamfer_distance_errors():
    a = pts(10)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        _brickgeom.chamfer_distance(a[:, :2].copy(), a)
    with pytest.raises(ValueError, match=r"b must have shape \(N, 3\)"):
        _brickgeom.chamfer_distance(a, np.zeros((4, 4), np.float32))
    with pytest.raises(TypeError):
        _brickgeom.chamfer_distance(a.astype(np.float64), a)
    with pytest.raises(TypeError):
        _brickgeom.chamfer_distance(a.ravel(), a)
    with pytest.raises(InvalidArgumentError, match="empty"):
        _brickgeom.chamfer_distance(np.zeros((0, 3), np.float32), a)
    bad = a.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InvalidArgumentError, match="not finite"):
        _brickgeom.chamfer_distance(a, bad)


def brute_force_min_cost(cost: np.ndarray) -> float:
    n, m = cost.shape
    if n <= m:
        return min(
            sum(cost[i, j] for i, j in enumerate(p)) for p in itertools.permutations(range(m), n)
        )
    return brute_force_min_cost(cost.T)


@pytest.mark.parametrize("shape", [(5, 5), (4, 6), (6, 4), (1, 3), (3, 1)])
def test_linear_assignment_vs_brute_force(shape):
    rng = np.random.default_rng(sum(shape))
    for _ in range(5):
        cost = rng.normal(size=shape)
        rows, cols = _brickgeom.linear_assignment(cost)
        k = min(shape)
        assert len(rows) == len(cols) == k
        assert rows == sorted(rows) and len(set(rows)) == k and len(set(cols)) == k
        assert cost[rows, cols].sum() == pytest.approx(brute_force_min_cost(cost), abs=1e-9)


def test_linear_assignment_edge_cases_and_errors():
    assert _brickgeom.linear_assignment(np.zeros((0, 4))) == ([], [])
    assert _brickgeom.linear_assignment(np.zeros((3, 0))) == ([], [])
    assert _brickgeom.linear_assignment(np.array([[1.0, 0.0], [0.0, 1.0]])) == ([0, 1], [1, 0])
    with pytest.raises(TypeError):
        _brickgeom.linear_assignment(np.zeros((2, 2), np.int64))
    with pytest.raises(InvalidArgumentError, match="not finite"):
        _brickgeom.linear_assignment(np.array([[0.0, np.inf]]))
    # The Python wrapper converts dtypes and lists.
    assert M.linear_assignment([[3, 1], [1, 3]]) == ([0, 1], [1, 0])
    with pytest.raises(ValueError, match="2-D"):
        M.linear_assignment([1.0, 2.0])


# --- meshes and sampling ----------------------------------------------------------------------


def test_sample_surface_is_deterministic_and_on_the_mesh(brick):
    v, t = brick.mesh()
    p = M.sample_surface(v, t, n=500, seed=3)
    assert p.shape == (500, 3) and p.dtype == np.float32
    assert np.array_equal(p, M.sample_surface(v, t, n=500, seed=3))
    assert not np.array_equal(p, M.sample_surface(v, t, n=500, seed=4))
    assert (p >= v.min(0) - 1e-4).all() and (p <= v.max(0) + 1e-4).all()


def test_sample_surface_is_area_weighted():
    # Two unit-spaced squares in separate planes, one with 4x the area of the other.
    v = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 5], [2, 0, 5], [2, 2, 5], [0, 2, 5]],
        np.float32,
    )
    t = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], np.uint32)
    p = M.sample_surface(v, t, n=5000, seed=0)
    assert (p[:, 2] > 2.5).mean() == pytest.approx(0.8, abs=0.03)


def test_sample_surface_errors():
    v = np.zeros((3, 3), np.float32)
    with pytest.raises(ValueError, match="empty"):
        M.sample_surface(v, np.zeros((0, 3), np.uint32))
    with pytest.raises(ValueError, match="area"):
        M.sample_surface(v, np.array([[0, 1, 2]], np.uint32))
    with pytest.raises(ValueError, match="indices"):
        M.sample_surface(v, np.array([[0, 1, 3]], np.uint32))
    with pytest.raises(ValueError, match="positive"):
        M.sample_surface(v, np.array([[0, 1, 2]], np.uint32), n=0)


def test_component_mesh_applies_yaw_then_translation(brick):
    v0, t0 = brick.mesh()
    for yaw, rot in enumerate(
        [lambda x, y, z: (x, y, z), lambda x, y, z: (z, y, -x)]
        + [lambda x, y, z: (-x, y, -z), lambda x, y, z: (-z, y, x)]
    ):
        v, t = M.component_mesh(brick, yaw, (3, 2, -1))
        assert v.dtype == np.float32 and t.dtype == np.uint32
        assert np.array_equal(t, t0)
        want = np.stack(rot(v0[:, 0], v0[:, 1], v0[:, 2]), axis=1) + [30, 16, -10]
        np.testing.assert_allclose(v, want, atol=1e-4)
    with pytest.raises(ValueError, match="yaw"):
        M.component_mesh(brick, 4, (0, 0, 0))


def test_component_mesh_covers_the_placed_voxels(brick):
    # Footprint in x and z: the voxel cells of the brick, rotated and translated, in LDU.
    vox = brick.voxels
    v, _ = M.component_mesh(brick, 1, (2, 0, 4))
    # yaw 1: cell x range [x0, x1) -> z range [-x1, -x0); cell z range -> x range.
    x_lo, x_hi = vox[:, 2].min() + 2, vox[:, 2].max() + 1 + 2
    z_lo, z_hi = -(vox[:, 0].max() + 1) + 4, -vox[:, 0].min() + 4
    assert v[:, 0].min() == pytest.approx(10 * x_lo) and v[:, 0].max() == pytest.approx(10 * x_hi)
    assert v[:, 2].min() == pytest.approx(10 * z_lo) and v[:, 2].max() == pytest.approx(10 * z_hi)


def test_union_mesh(brick):
    v0, t0 = brick.mesh()
    v, t = M.union_mesh([(brick, 0, (0, 0, 0)), (brick, 1, (0, 3, 0))])
    assert v.shape == (2 * len(v0), 3) and t.shape == (2 * len(t0), 3)
    assert np.array_equal(t[: len(t0)], t0) and np.array_equal(t[len(t0) :], t0 + len(v0))
    assert np.array_equal(v[len(v0) :], M.component_mesh(brick, 1, (0, 3, 0))[0])
    ve, te = M.union_mesh([])
    assert ve.shape == (0, 3) and te.shape == (0, 3)


# --- Chamfer distance on meshes ---------------------------------------------------------------


def test_chamfer_of_a_mesh_with_itself(brick):
    mesh = M.component_mesh(brick, 0, (0, 0, 0))
    # The same seed samples the same points: exactly 0.
    assert M.chamfer(mesh, mesh, n=2000) == 0.0
    # Independent samplings of one surface differ only by sampling noise, far below the distance
    # of a one-stud error.
    v, t = mesh
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    a = M.sample_surface(v, t, n=2000, seed=0) / diag
    b = M.sample_surface(v, t, n=2000, seed=1) / diag
    noise = _brickgeom.chamfer_distance(a, b)
    moved = M.chamfer(M.component_mesh(brick, 0, (2, 0, 0)), mesh, n=2000)
    assert 0.0 < noise < moved / 10


def test_chamfer_grows_with_displacement(brick):
    gt = M.component_mesh(brick, 0, (0, 0, 0))
    for axis in range(3):
        step = [2, 3, 2][axis]  # one stud in x or z (2 half-studs), one brick height in y
        one = [0, 0, 0]
        two = [0, 0, 0]
        one[axis], two[axis] = step, 2 * step
        cd1 = M.chamfer(M.component_mesh(brick, 0, one), gt, n=2000)
        cd2 = M.chamfer(M.component_mesh(brick, 0, two), gt, n=2000)
        assert 0 < cd1 < cd2


def test_chamfer_is_symmetric_and_scale_free(brick):
    a = M.union_mesh([(brick, 0, (0, 0, 0)), (brick, 1, (0, 3, 0))])
    b = M.union_mesh([(brick, 0, (0, 0, 0)), (brick, 0, (2, 3, 0))])
    s = 123.0
    assert M.chamfer(a, b, n=2000, scale=s) == pytest.approx(
        M.chamfer(b, a, n=2000, scale=s), rel=1e-5
    )
    cd = M.chamfer(a, b, n=2000)
    big = lambda m: (m[0] * 4.0, m[1])  # noqa: E731
    assert M.chamfer(big(a), big(b), n=2000) == pytest.approx(cd, rel=1e-5)
    # Explicit scale = the GT diagonal gives the default normalisation.
    diag = float(np.linalg.norm(b[0].max(0) - b[0].min(0)))
    assert M.chamfer(a, b, n=2000, scale=diag) == pytest.approx(cd, rel=1e-6)


def test_chamfer_errors(brick):
    mesh = M.component_mesh(brick, 0, (0, 0, 0))
    empty = M.union_mesh([])
    with pytest.raises(ValueError, match="empty"):
        M.chamfer(empty, mesh)
    with pytest.raises(ValueError, match="empty"):
        M.chamfer(mesh, empty)
    with pytest.raises(ValueError, match="scale"):
        M.chamfer(mesh, mesh, scale=0.0)


# --- matching ---------------------------------------------------------------------------------


def test_match_instances():
    pred = [(0, 0, 5), (0, 0, 0), (9, 9, 9)]
    gt = [(0, 0, 1), (0, 0, 4)]

    def cost(p, g):
        return float(np.sum((np.array(p) - np.array(g)) ** 2))

    assert M.match_instances(pred, gt, cost) == [(0, 1), (1, 0)]
    assert M.match_instances(gt, pred, cost) == [(0, 1), (1, 0)]
    assert M.match_instances([], gt, cost) == []
