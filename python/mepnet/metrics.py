"""Geometric evaluation metrics (DESIGN §7): Chamfer distance on sampled surfaces and Hungarian
matching of instances.

Chamfer distance (CD) follows the paper and Pixel2Mesh: ``n`` = 10000 points are sampled
uniformly (area-weighted) on each surface, and CD is the mean squared distance from each
predicted point to its nearest ground-truth point plus the mean squared distance from each
ground-truth point to its nearest predicted point. Units: before the distance is taken both point
sets are centred on the ground truth's bounding-box centre and divided by the ground truth's
bounding-box diagonal, so CD is scale-free (the CD of shapes scaled so the ground-truth bounding
box diagonal is 1). Tables report ``1e5 * CD`` like the paper.

Meshes are ``(vertices (V, 3) float, triangles (T, 3) int)`` pairs in world LDU, y up (DESIGN §2).
The nearest-neighbour search and the assignment run in the Rust core (``mepnet._brickgeom``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt
import trimesh

from mepnet import _brickgeom
from mepnet.geom import LDU_PER_CELL

__all__ = [
    "CD_REPORT_SCALE",
    "Mesh",
    "chamfer",
    "component_mesh",
    "linear_assignment",
    "match_instances",
    "sample_surface",
    "union_mesh",
]

#: A triangle mesh: ``(vertices (V, 3) float32 LDU, triangles (T, 3) uint32)``.
Mesh = tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32]]

#: Factor applied to :func:`chamfer` values in reported tables (the paper's x1e5).
CD_REPORT_SCALE = 1e5


P = TypeVar("P")
G = TypeVar("G")


def _check_mesh(vertices: Any, triangles: Any) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), got {v.shape}")
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"triangles must have shape (T, 3), got {t.shape}")
    if t.size and (t.min() < 0 or t.max() >= len(v)):
        raise ValueError(f"triangle indices must lie in [0, {len(v)}), got [{t.min()}, {t.max()}]")
    return v.astype(np.float64, copy=False), t.astype(np.int64, copy=False)


def sample_surface(
    vertices: npt.ArrayLike, triangles: npt.ArrayLike, n: int = 10000, seed: int = 0
) -> npt.NDArray[np.float32]:
    """Sample ``n`` points uniformly on a triangle mesh's surface (area-weighted).

    Args:
        vertices: (V, 3) vertex positions.
        triangles: (T, 3) vertex indices.
        n: number of points (> 0).
        seed: random seed; the same mesh, ``n`` and seed always give the same points.

    Returns:
        (n, 3) float32 points, in the units of ``vertices``.

    Raises:
        ValueError: on bad shapes or indices, ``n <= 0``, or a mesh with no triangles or zero
            surface area.
    """
    if n <= 0:
        raise ValueError(f"n must be positive, got {n}")
    v, t = _check_mesh(vertices, triangles)
    if len(t) == 0:
        raise ValueError("cannot sample an empty mesh (no triangles)")
    mesh = trimesh.Trimesh(vertices=v, faces=t, process=False)
    if not np.isfinite(mesh.area) or mesh.area <= 0.0:
        raise ValueError(f"cannot sample a mesh with surface area {mesh.area}")
    points, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.ascontiguousarray(points, dtype=np.float32)


def component_mesh(component: _brickgeom.Component, yaw: int, t: Sequence[int]) -> Mesh:
    """The mesh of a placed component in world LDU, y up.

    Args:
        component: a :class:`mepnet.Component` (primitive part or submodule).
        yaw: quarter turns about +y (0..3); one turn maps (x, y, z) to (z, y, -x).
        t: lattice translation (x, y, z) in half-studs, plates, half-studs; added as
            (10 x, 8 y, 10 z) LDU after the rotation.

    Returns:
        ``(vertices (V, 3) float32, triangles (T, 3) uint32)``.

    Raises:
        ValueError: if ``yaw`` is not in 0..3 or ``t`` does not have three entries.
    """
    if yaw not in (0, 1, 2, 3):
        raise ValueError(f"yaw must be 0..3 quarter turns, got {yaw}")
    tt = np.asarray(t, dtype=np.float64)
    if tt.shape != (3,):
        raise ValueError(f"t must be a lattice point (x, y, z), got {t!r}")
    v, tri = component.mesh()
    p = v.astype(np.float64)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if yaw == 1:
        p = np.stack([z, y, -x], axis=1)
    elif yaw == 2:
        p = np.stack([-x, y, -z], axis=1)
    elif yaw == 3:
        p = np.stack([-z, y, x], axis=1)
    p = p + tt * LDU_PER_CELL
    return p.astype(np.float32), np.asarray(tri, dtype=np.uint32)


def union_mesh(placements: Sequence[tuple[_brickgeom.Component, int, Sequence[int]]]) -> Mesh:
    """The union (concatenation, no boolean operation) of placed components' meshes.

    Args:
        placements: ``(component, yaw, t)`` triples, as for :func:`component_mesh`.

    Returns:
        ``(vertices, triangles)`` in world LDU; an empty mesh ((0, 3) arrays) for no placements.
    """
    vs: list[np.ndarray] = []
    ts: list[np.ndarray] = []
    offset = 0
    for component, yaw, t in placements:
        v, tri = component_mesh(component, yaw, t)
        vs.append(v)
        ts.append(tri.astype(np.uint32) + np.uint32(offset))
        offset += len(v)
    if not vs:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32)
    return np.concatenate(vs), np.concatenate(ts)


def chamfer(
    pred_mesh: tuple[npt.ArrayLike, npt.ArrayLike],
    gt_mesh: tuple[npt.ArrayLike, npt.ArrayLike],
    n: int = 10000,
    seed: int = 0,
    scale: float | None = None,
) -> float:
    """Chamfer distance between a predicted and a ground-truth mesh (the paper's metric).

    CD on shapes scaled so the ground-truth bounding box diagonal is 1; reported x1e5 like the
    paper (:data:`CD_REPORT_SCALE`). Precisely: ``n`` points are sampled on each surface with
    :func:`sample_surface` (the same ``seed`` for both, so identical meshes give exactly 0);
    both point sets are translated by minus the centre of the ground truth's vertex bounding box
    and divided by its diagonal (or by ``scale``, in the meshes' units, when given); the result
    is the mean squared nearest-neighbour distance from the predicted points to the
    ground-truth points plus that from the ground-truth points to the predicted points.

    Args:
        pred_mesh: ``(vertices, triangles)`` of the prediction (world LDU).
        gt_mesh: ``(vertices, triangles)`` of the ground truth (world LDU).
        n: points sampled per surface (the paper: 10000).
        seed: sampling seed.
        scale: normalisation length; None uses the ground truth's bounding-box diagonal.

    Returns:
        The Chamfer distance (unitless when ``scale`` is None). Symmetric in the two meshes when
        ``scale`` is given; otherwise the ground truth sets the scale.

    Raises:
        ValueError: for an empty or zero-area mesh, or a non-positive scale.
    """
    pv, pt = pred_mesh
    gv, gt = gt_mesh
    pred_pts = sample_surface(pv, pt, n=n, seed=seed)
    gt_pts = sample_surface(gv, gt, n=n, seed=seed)
    g = np.asarray(gv, dtype=np.float64)
    lo, hi = g.min(axis=0), g.max(axis=0)
    centre = (lo + hi) / 2.0
    if scale is None:
        scale = float(np.linalg.norm(hi - lo))
    if not np.isfinite(scale) or scale <= 0.0:
        raise ValueError(f"normalisation scale must be positive, got {scale}")

    def normalise(p: np.ndarray) -> npt.NDArray[np.float32]:
        return np.ascontiguousarray((p.astype(np.float64) - centre) / scale, dtype=np.float32)

    return float(_brickgeom.chamfer_distance(normalise(pred_pts), normalise(gt_pts)))


def linear_assignment(cost: npt.ArrayLike) -> tuple[list[int], list[int]]:
    """Minimum-cost assignment of a rectangular cost matrix (like scipy's
    ``linear_sum_assignment``).

    Args:
        cost: (n, m) finite costs.

    Returns:
        ``(rows, cols)``: ``min(n, m)`` pairs sorted by row, minimising the summed cost.

    Raises:
        ValueError: if ``cost`` is not 2-D.
        mepnet.InvalidArgumentError: for a non-finite cost.
    """
    c = np.ascontiguousarray(cost, dtype=np.float64)
    if c.ndim != 2:
        raise ValueError(f"cost must be a 2-D matrix, got shape {c.shape}")
    return _brickgeom.linear_assignment(c)


def match_instances(
    pred: Sequence[P], gt: Sequence[G], cost_fn: Callable[[P, G], float]
) -> list[tuple[int, int]]:
    """Match predicted to ground-truth instances by minimum total cost (Hungarian algorithm).

    Args:
        pred: predicted items.
        gt: ground-truth items.
        cost_fn: ``cost_fn(pred_item, gt_item)``, a finite cost (lower is a better match).

    Returns:
        ``min(len(pred), len(gt))`` pairs ``(pred_index, gt_index)`` sorted by ``pred_index``;
        unmatched items (when the lists differ in length) appear in no pair.
    """
    if not pred or not gt:
        return []
    cost = np.array([[float(cost_fn(p, g)) for g in gt] for p in pred], dtype=np.float64)
    rows, cols = _brickgeom.linear_assignment(cost)
    return list(zip(rows, cols, strict=True))
