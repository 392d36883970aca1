"""Training samples: a manual step as tensors, with targets from ``manual.json`` and the
instance map.

A sample holds the network inputs (image + edge channel, base-shape voxels, camera, component
voxels per slot) and the targets at the head stride: Gaussian centre heatmaps per slot, the
keypoint offsets, semantic masks per slot, an instance map for the associative-embedding loss,
and per instance its slot, keypoint cell and rotation class. Augmentation (colour, outlines,
blur, scale) keeps image, camera and keypoints consistent.

The canonical view: a picture does not change when the world and the camera turn together about
+y, so every sample is presented to the network with the world turned by the quarter turns
(:func:`canonical_turn`) that bring the camera's azimuth into [180, 270) -- the base shape and
the camera turned, the picture untouched. The network therefore sees every azimuth as one of a
quarter-circle of views (front-left and front-right three-quarter views alike), and its rotation
classes are in the turned world: :func:`world_rotations` turns them back.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from mepnet import _brickgeom as _bg
from mepnet.detector.config import ModelConfig
from mepnet.geom import rotate_lattice
from mepnet.manual import ComponentRef, Step, StepTruth, make_camera
from mepnet.state import change_map, state_projection

#: Largest number of instances a step can add (the generator's limit).
MAX_INSTANCES = 10


@dataclass
class StepSample:
    """Network inputs and targets of one step (no batch dimension)."""

    tensors: dict[str, torch.Tensor]


def edge_channel(rgb: np.ndarray) -> np.ndarray:
    """|Laplacian| of the grey image, scaled to [0, 1] (the paper feeds an edge image)."""
    g = rgb.astype(np.float32).mean(axis=2) / 255.0
    p = np.pad(g, 1, mode="edge")
    lap = 4 * g - p[:-2, 1:-1] - p[2:, 1:-1] - p[1:-1, :-2] - p[1:-1, 2:]
    return np.clip(np.abs(lap) * 4.0, 0.0, 1.0)


def canonical_turn(camera: dict[str, Any]) -> int:
    """Quarter turns about +y (0..3) that bring the camera's azimuth into [180, 270)."""
    return int(np.ceil((180.0 - float(camera["azimuth"]) % 360.0) / 90.0)) % 4


def turned_view(
    base: _bg.Assembly, camera: dict[str, Any], turn: int
) -> tuple[_bg.Assembly, dict[str, Any]]:
    """The base shape and camera with the world turned by ``turn`` quarter turns about +y (the
    picture is the same)."""
    if turn % 4 == 0:
        return base, camera
    turned = _bg.Assembly()
    for iid, comp, yaw, t in base.instances():
        turned.add(comp, (yaw + turn) % 4, rotate_lattice(t, turn), base.colour(iid))
    return turned, {**camera, "azimuth": float(camera["azimuth"]) + 90.0 * turn}


def world_rotations(rotations: np.ndarray, turn: int) -> np.ndarray:
    """Rotation-class probabilities (..., 7) of the turned world (:func:`turned_view`) in the
    manual's world: yaw ``c`` there is yaw ``c - turn`` here (class 0: 4-fold symmetric; 1-2:
    2-fold, yaw mod 2; 3-6: no symmetry, yaw mod 4)."""
    if turn % 4 == 0:
        return rotations
    out = np.empty_like(rotations)
    out[..., 0] = rotations[..., 0]
    for k in range(2):
        out[..., 1 + (k - turn) % 2] = rotations[..., 1 + k]
    for k in range(4):
        out[..., 3 + (k - turn) % 4] = rotations[..., 3 + k]
    return out


def camera_vector(camera: dict[str, Any]) -> np.ndarray:
    """(12,) rotation rows u, v, w, scale, tx, ty."""
    cam = make_camera(camera)
    return np.concatenate(
        [cam.rotation().ravel(), [camera["scale"]], camera["translation"]]
    ).astype(np.float32)


def base_voxels(asm: _bg.Assembly, grid: tuple[int, int, int]) -> np.ndarray:
    """Occupancy of the window (Z, Y, X) of the config's base grid."""
    gx, gy, gz = grid
    occ, _ = asm.occupancy((-gx // 2, 0, -gz // 2), (gx // 2 - 1, gy - 1, gz // 2 - 1))
    return np.ascontiguousarray(occ.transpose(2, 1, 0), dtype=np.float32)  # (X,Y,Z) -> (Z,Y,X)


def component_voxels(comp: _bg.Component, grid: tuple[int, int, int]) -> np.ndarray:
    """The component's voxels centred in the component grid, (Z, Y, X)."""
    gx, gy, gz = grid
    v = comp.voxels.astype(np.int64)
    centre = (v.min(axis=0) + v.max(axis=0) + 1) // 2
    idx = v - centre + np.array([gx // 2, gy // 2, gz // 2])
    keep = np.all((idx >= 0) & (idx < np.array(grid)), axis=1)
    out = np.zeros((gz, gy, gx), dtype=np.float32)
    idx = idx[keep]
    out[idx[:, 2], idx[:, 1], idx[:, 0]] = 1.0
    return out


def _gaussian(heat: np.ndarray, cx: float, cy: float, sigma: float) -> None:
    h, w = heat.shape
    ys, xs = np.arange(h)[:, None] + 0.5, np.arange(w)[None, :] + 0.5
    np.maximum(heat, np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / (2 * sigma**2)), out=heat)


def component_slots(step: Step) -> list[tuple[ComponentRef, list[int]]]:
    """The detector's component types of a step, in callout order: each distinct component
    with the callout entries that name it (the same part in two colours is one type to the
    detector, whose component encoder sees geometry only; stage 2 tells the colours apart)."""
    slots: dict[ComponentRef, list[int]] = {}
    for k, c in enumerate(step.components):
        slots.setdefault(c.component, []).append(k)
    return list(slots.items())


def make_sample(
    step: Step,
    cfg: ModelConfig,
    *,
    base: _bg.Assembly,
    components: dict[ComponentRef, _bg.Component],
    truth: StepTruth | None = None,
    augment: bool = False,
    rng: np.random.Generator | None = None,
    slot_types: Sequence[int] | None = None,
    change: np.ndarray | None = None,
    image: tuple[np.ndarray, np.ndarray] | None = None,
) -> StepSample:
    """Network inputs of a page ``step`` (its image, camera and callout) on the shape ``base``,
    and, with ``truth`` (the step's answers: training), the targets. Without ``truth`` (a
    predictor: it never sees the answers) the targets are zeros and there is no augmentation.
    ``slot_types``: which of the step's component types (:func:`component_slots`) fill the K_max
    slots (default: the first K_max); a step with more types takes several samples.
    ``change``: the step's change map at any resolution (``mepnet.stage2.synthesis.step_change``,
    which also reads the previous step's picture), else computed here from the base as mepnet
    renders it.
    ``image``: a picture (H, W, 3) uint8 and its instance map (H, W) int32 at the manual's size
    to use instead of the page's (the step drawn again in another style,
    :func:`mepnet.styles.draw_step`); needs ``truth``."""
    rng = rng or np.random.default_rng(0)
    slots = component_slots(step)
    types = list(slot_types) if slot_types is not None else list(range(len(slots)))
    types = types[: cfg.k_max]
    if image is not None and truth is None:
        raise ValueError("a redrawn step image needs the step's answers (truth)")
    rgb = step.image() if image is None else image[0]
    step.camera_object()  # a clear error when the page states no camera
    cam = dict(step.camera)  # type: ignore[arg-type]
    ids = (truth.ids() if image is None else image[1]) if truth is not None else None
    kps = (
        {v.id: np.array(v.keypoint, dtype=np.float64) for v in truth.answers.views}
        if truth is not None
        else {}
    )
    if augment and ids is not None:
        rgb, ids, cam, kps = _augment(rgb, ids, cam, kps, rng)
    turn = canonical_turn(cam)
    base, cam = turned_view(base, cam, turn)
    # keypoints at the network's resolution
    kps = {k: v * (cfg.image_size / rgb.shape[1]) for k, v in kps.items()}
    # resize to the network's size (nearest for ids)
    img_t = torch.from_numpy(np.array(rgb)).permute(2, 0, 1).float()[None] / 255.0
    if img_t.shape[-1] != cfg.image_size or img_t.shape[-2] != cfg.image_size:
        img_t = F.interpolate(
            img_t, size=(cfg.image_size, cfg.image_size), mode="bilinear", align_corners=False
        )
    img = img_t[0].numpy()
    edge = edge_channel((img.transpose(1, 2, 0) * 255).astype(np.uint8))
    image = np.concatenate([img, edge[None]], axis=0).astype(np.float32)
    n = cfg.out_size
    stride = cfg.image_size / n
    heat = np.zeros((cfg.k_max, n, n), np.float32)
    seg = np.zeros((cfg.k_max, n, n), np.float32)
    inst_map = np.zeros((n, n), np.int64)  # 0 background, i + 1 instance i
    inst_slot = np.zeros(MAX_INSTANCES, np.int64)
    inst_cell = np.zeros((MAX_INSTANCES, 2), np.int64)  # (x, y) at head resolution
    inst_off = np.zeros((MAX_INSTANCES, 2), np.float32)
    inst_rot = np.zeros(MAX_INSTANCES, np.int64)
    inst_valid = np.zeros(MAX_INSTANCES, np.float32)
    comp_vox = np.zeros((cfg.k_max, 1, *cfg.comp_grid[::-1]), np.float32)
    comp_valid = np.zeros(cfg.k_max, np.float32)
    ids_small = (
        ids[
            (np.arange(n) * ids.shape[0] // n)[:, None], (np.arange(n) * ids.shape[1] // n)[None, :]
        ]
        if ids is not None
        else None
    )
    k_inst = 0
    for s, slot in enumerate(types):
        ref, entries = slots[slot]
        comp = components[ref]
        comp_vox[s, 0] = component_voxels(comp, cfg.comp_grid)
        comp_valid[s] = 1.0
        if truth is None or ids_small is None:
            continue
        for iid in (i for e in entries for i in truth.instances_of[e]):
            if k_inst >= MAX_INSTANCES:
                break
            kp = kps[iid] / stride  # in head cells
            cx, cy = float(kp[0]), float(kp[1])
            cell = np.clip(np.floor([cx, cy]).astype(np.int64), 0, n - 1)
            # the peak (exactly 1) sits on the keypoint's cell; the offset carries the rest
            _gaussian(heat[s], cell[0] + 0.5, cell[1] + 0.5, sigma=1.5)
            m = ids_small == iid
            seg[s][m] = 1.0
            inst_map[m] = k_inst + 1
            inst_slot[k_inst] = s
            inst_cell[k_inst] = cell
            inst_off[k_inst] = (cx - cell[0], cy - cell[1])
            yaw = (truth.instances[iid].yaw + turn) % 4
            inst_rot[k_inst] = _bg.rotation_class(comp.symmetry, yaw)
            inst_valid[k_inst] = 1.0
            k_inst += 1
    state_index, state_maps = state_projection(base, cam, cfg.image_size, cfg.base_grid)
    if change is None:
        state_maps[9] = change_map(image[:3], state_maps[6:9])
    else:
        state_maps[9] = _resized(change, cfg.image_size)
    t = {
        "image": torch.from_numpy(image),
        "base_voxels": torch.from_numpy(base_voxels(base, cfg.base_grid))[None],
        "state_index": torch.from_numpy(state_index),
        "state_maps": torch.from_numpy(state_maps),
        "camera": torch.from_numpy(camera_vector(cam)),
        "comp_voxels": torch.from_numpy(comp_vox),
        "comp_valid": torch.from_numpy(comp_valid),
        "heatmap": torch.from_numpy(heat),
        "seg": torch.from_numpy(seg),
        "inst_map": torch.from_numpy(inst_map),
        "inst_slot": torch.from_numpy(inst_slot),
        "inst_cell": torch.from_numpy(inst_cell),
        "inst_offset": torch.from_numpy(inst_off),
        "inst_rot": torch.from_numpy(inst_rot),
        "inst_valid": torch.from_numpy(inst_valid),
        "turn": torch.tensor(turn, dtype=torch.int64),
    }
    return StepSample(tensors=t)


def _resized(a: np.ndarray, size: int) -> np.ndarray:
    """An (H, W) map resized to (size, size) (bilinear)."""
    if a.shape == (size, size):
        return a.astype(np.float32)
    t = torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))[None, None]
    return F.interpolate(t, size=(size, size), mode="bilinear", align_corners=False)[0, 0].numpy()


#: Line restyling: probability of heavier outlines, and of fainter ones.
THICK_LINES, FAINT_LINES = 0.2, 0.15


def restyle_lines(
    img: np.ndarray, ids: np.ndarray, rng: np.random.Generator, mode: str | None = None
) -> np.ndarray:
    """Outlines as another renderer might draw them: where the instance map changes (part and
    silhouette edges), ``thick`` paints 2 or 4 px lines centred on the edge (the pixels either
    side of it, widened by one more on each side half the time) in a random dark grey,
    ``faint`` blends the edge pixels toward their 3x3 neighbourhood mean (thin or missing
    lines); ``mode`` None draws one of them or nothing (:data:`THICK_LINES`,
    :data:`FAINT_LINES`). ``img`` (H, W, 3) float.

    (Thick lines were once the pixel right of or below each edge, widened right and down: the
    drawing moved 0.5-1.5 px right and down, which no renderer does, and a camera fitted to it
    moved with it.)"""
    if mode is None:
        u = rng.random()
        mode = "thick" if u < THICK_LINES else "faint" if u < THICK_LINES + FAINT_LINES else ""
    if not mode:
        return img
    edge = np.zeros(ids.shape, dtype=bool)
    edge[:, 1:] |= ids[:, 1:] != ids[:, :-1]
    edge[1:, :] |= ids[1:, :] != ids[:-1, :]
    if mode == "thick":
        edge = _grown(edge, 1 + int(rng.integers(0, 2)))
        alpha = float(rng.uniform(0.6, 1.0))
        ink = float(rng.uniform(0.0, 70.0))
        out = img.copy()
        out[edge] = (1 - alpha) * img[edge] + alpha * ink
        return out
    if mode == "faint":
        p = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
        h, w = ids.shape
        mean = sum(p[dy : dy + h, dx : dx + w] for dy in range(3) for dx in range(3)) / 9
        alpha = float(rng.uniform(0.4, 0.9))
        out = img.copy()
        out[edge] = (1 - alpha) * img[edge] + alpha * mean[edge]
        return out
    raise ValueError(f"unknown line mode {mode!r}")


def _grown(edge: np.ndarray, steps: int) -> np.ndarray:
    """``edge`` (the pixel right of or below each change) grown ``steps`` pixels left and up and
    ``steps - 1`` right and down: a band centred on the changes."""
    out = edge.copy()
    for k in range(steps):
        grown = out.copy()
        grown[:, :-1] |= out[:, 1:]
        grown[:-1, :] |= out[1:, :]
        if k:
            grown[:, 1:] |= out[:, :-1]
            grown[1:, :] |= out[:-1, :]
        out = grown
    return out


def blur(img: np.ndarray) -> np.ndarray:
    """A light blur of an (H, W, 3) float image: each pixel half itself, half its 4-neighbours'
    mean (edges padded)."""
    p = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    return (p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:] + 4 * img) / 8


def _augment(
    rgb: np.ndarray,
    ids: np.ndarray,
    cam: dict[str, Any],
    kps: dict[int, np.ndarray],
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any], dict[int, np.ndarray]]:
    """Colour gain/bias, restyled outlines, optional blur, and a zoom about the image centre
    (camera and keypoints follow), so the detector does not depend on our renderer's exact
    look."""
    h, w = ids.shape
    img = rgb.astype(np.float32)
    img = img * rng.uniform(0.8, 1.2, size=3) + rng.uniform(-20, 20, size=3)
    img = restyle_lines(img, ids, rng)
    if rng.random() < 0.3:
        img = blur(img)
    zoom = float(rng.uniform(0.9, 1.1))
    if abs(zoom - 1) > 1e-3:
        ys = np.clip(((np.arange(h) + 0.5 - h / 2) / zoom + h / 2).astype(np.int64), 0, h - 1)
        xs = np.clip(((np.arange(w) + 0.5 - w / 2) / zoom + w / 2).astype(np.int64), 0, w - 1)
        img = img[ys[:, None], xs[None, :]]
        ids = ids[ys[:, None], xs[None, :]]
        cam = {
            **cam,
            "scale": cam["scale"] * zoom,
            "translation": [t * zoom for t in cam["translation"]],
        }
        centre = np.array([w / 2, h / 2])
        kps = {k: (v - centre) * zoom + centre for k, v in kps.items()}
    return np.clip(img, 0, 255).astype(np.uint8), ids, cam, kps


def collate(samples: list[StepSample]) -> dict[str, torch.Tensor]:
    """Stack samples into a batch."""
    return {k: torch.stack([s.tensors[k] for s in samples]) for k in samples[0].tensors}
