"""The MEPNet network (paper §4.1), read top to bottom:

1. State-manual encoder: 3D conv-BN-ReLU on the base shape's voxels; each pixel gathers the
   features of the first occupied voxel its camera ray hits (the transform into the camera frame,
   found by rasterizing the base shape), giving a full-resolution 2D feature map that is
   concatenated with the image, the rendered state maps (hit, depth, outlines, world
   coordinates) and the camera planes.
2. Component encoder: 3D convs + average pooling, one embedding per component type, K_max slots,
   zero padded.
3. Hourglass: encoder to H/32, the tiled component embeddings concatenated at the bottleneck,
   decoder back to H/4 with skip connections.
4. Heads per slot: centre heatmap + offset, semantic mask + associative embedding, 7-way
   symmetry-aware rotation.

1-3 are :class:`Trunk`; :class:`MEPNet` adds the heads of 4. :class:`Direct3DNet` (the paper's
Direct3D baseline, ``ModelConfig.head = "direct3d"``) adds instead a centre heatmap and, on the
features with CoordConv channels beside them, heads that regress each instance's 3D translation
and its rotation class directly.

Shapes in comments: B batch, K slots, H/W image, h/w = H/4.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from mepnet.detector.config import ModelConfig
from mepnet.state import STATE_MAPS
from torch import nn


def conv_bn(cin: int, cout: int, stride: int = 1, dims: int = 2) -> nn.Sequential:
    """conv 3x3(x3) - batch norm - ReLU."""
    conv = nn.Conv2d if dims == 2 else nn.Conv3d
    bn = nn.BatchNorm2d if dims == 2 else nn.BatchNorm3d
    return nn.Sequential(conv(cin, cout, 3, stride, 1, bias=False), bn(cout), nn.ReLU(inplace=True))


class Residual(nn.Module):
    """Two 3x3 convs with a skip connection."""

    def __init__(self, *, channels: int):
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(channels, channels, 3, 1, 1, bias=False),
            nn.BatchNorm2d(channels),
            nn.ReLU(inplace=True),
            nn.Conv2d(channels, channels, 3, 1, 1, bias=False),
            nn.BatchNorm2d(channels),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.body(x))


class StateEncoder(nn.Module):
    """Base shape voxels -> 2D feature map in the camera frame (first-hit projection).

    The 3D features of the first occupied voxel each pixel's ray hits are gathered into the
    image: the per-pixel voxel index comes from rasterizing the base shape with the step's camera
    (:func:`mepnet.state.state_projection`, brickgeom's renderer), so the transform is
    exact and the gather passes gradients to every voxel feature it reads."""

    def __init__(self, *, channels: int):
        super().__init__()
        self.convs = conv_bn(1, channels, dims=3)

    def forward(self, vox: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
        # vox: (B, 1, Z, Y, X) occupancy; index: (B, H, W) flat voxel index, -1 where no hit
        b = vox.shape[0]
        _, _, gz, gy, gx = vox.shape
        # convolve only the box around what is occupied in the batch (the window is mostly
        # empty; a hit voxel is always occupied, so always inside)
        occ = vox[:, 0].amax(dim=0) > 0
        if occ.any():
            lo = [int(torch.nonzero(occ.any(dim=o)).min()) for o in ((1, 2), (0, 2), (0, 1))]
            hi = [int(torch.nonzero(occ.any(dim=o)).max()) for o in ((1, 2), (0, 2), (0, 1))]
        else:
            lo, hi = [0, 0, 0], [0, 0, 0]
        lo = [max(v - 1, 0) for v in lo]
        hi = [min(v + 2, n) for v, n in zip(hi, (gz, gy, gx), strict=True)]
        crop = vox[:, :, lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        feats = self.convs(crop).flatten(2)  # (B, C, z*y*x)
        c = feats.shape[1]
        cz, cy, cx = (h - v for h, v in zip(hi, lo, strict=True))
        flat = index.flatten(1)  # (B, H*W)
        hit = flat >= 0
        f = flat.clamp(min=0)
        z, y, x = f // (gy * gx) - lo[0], (f // gx) % gy - lo[1], f % gx - lo[2]
        hit = hit & (z >= 0) & (z < cz) & (y >= 0) & (y < cy) & (x >= 0) & (x < cx)
        local = torch.where(hit, (z * cy + y) * cx + x, torch.zeros_like(f))
        g = feats.gather(2, local[:, None, :].expand(b, c, -1))
        return (g * hit[:, None].to(g.dtype)).view(b, c, *index.shape[1:])


def camera_planes(cam: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """The camera's image axes in world coordinates (rows u and v of its rotation) as constant
    planes: the world frame the rotation classes are defined in."""
    return cam[:, :6, None, None].expand(-1, -1, *size)


#: Constant camera planes fed to the stem.
CAMERA_PLANES = 6


class ComponentEncoder(nn.Module):
    """Component voxels -> one embedding per component (five 3D conv layers + average pool)."""

    def __init__(self, *, channels: int):
        super().__init__()
        c = channels
        self.convs = nn.Sequential(
            conv_bn(1, c // 2, dims=3),
            conv_bn(c // 2, c // 2, stride=2, dims=3),
            conv_bn(c // 2, c, dims=3),
            conv_bn(c, c, stride=2, dims=3),
            conv_bn(c, c, dims=3),
        )

    def forward(self, vox: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        # vox: (B, K, 1, cz, cy, cx); valid: (B, K) -> (B, K, C2), zero for empty slots
        b, k = vox.shape[:2]
        # A batch holds few distinct grids (most slots are empty, common parts repeat): each
        # is encoded once, its batch-norm statistics counted as often as it occurs, so the
        # result is the function of the whole batch (tests/test_detector.py).
        flat = vox.flatten(0, 1)
        grids, inverse, counts = torch.unique(
            flat.flatten(1), dim=0, return_inverse=True, return_counts=True
        )
        x = grids.view(-1, *flat.shape[1:])
        for layer in self.convs:
            conv, bn, relu = tuple(layer.children())
            assert isinstance(bn, nn.modules.batchnorm._BatchNorm)
            x = relu(_counted_batch_norm(bn, conv(x), counts))
        f = x.mean(dim=(2, 3, 4))[inverse].view(b, k, -1)
        return f * valid[..., None]


def _counted_batch_norm(
    bn: nn.modules.batchnorm._BatchNorm, x: torch.Tensor, counts: torch.Tensor
) -> torch.Tensor:
    """``bn`` applied to a batch in which sample ``i`` of ``x`` occurs ``counts[i]`` times, as
    ``bn`` on that batch would (its running statistics updated alike in training)."""
    if not (bn.training or bn.running_mean is None):
        return bn(x)
    w = counts.to(torch.float32).view(-1, *([1] * (x.ndim - 1)))
    per = x[0, 0].numel()
    n = float(counts.sum()) * per
    xf = x.to(torch.float32)
    dims = [0] + list(range(2, x.ndim))
    mean = (xf * w).sum(dim=dims) / n
    shape = (1, -1) + (1,) * (x.ndim - 2)
    var = ((xf - mean.view(shape)) ** 2 * w).sum(dim=dims) / n
    if bn.training and bn.track_running_stats and bn.running_mean is not None:
        assert bn.running_var is not None and bn.num_batches_tracked is not None
        with torch.no_grad():
            bn.num_batches_tracked += 1
            m = bn.momentum if bn.momentum is not None else 1 / float(bn.num_batches_tracked)
            bn.running_mean.mul_(1 - m).add_(mean.detach(), alpha=m)
            bn.running_var.mul_(1 - m).add_(var.detach() * n / max(n - 1, 1), alpha=m)
    y = (xf - mean.view(shape)) * torch.rsqrt(var.view(shape) + bn.eps)
    if bn.affine:
        y = y * bn.weight.view(shape) + bn.bias.view(shape)
    return y.to(x.dtype)


class Hourglass(nn.Module):
    """Encoder to the bottleneck, condition on the component embeddings, decoder back up."""

    def __init__(self, *, channels: int, depth: int, cond_channels: int):
        super().__init__()
        self.down = nn.ModuleList(
            [
                nn.Sequential(conv_bn(channels, channels, stride=2), Residual(channels=channels))
                for _ in range(depth)
            ]
        )
        self.skip = nn.ModuleList([Residual(channels=channels) for _ in range(depth)])
        self.fuse = nn.Sequential(
            nn.Conv2d(channels + cond_channels, channels, 1),
            nn.ReLU(inplace=True),
            Residual(channels=channels),
        )
        self.up = nn.ModuleList([Residual(channels=channels) for _ in range(depth)])

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        skips = []
        for down, skip in zip(self.down, self.skip, strict=True):
            skips.append(skip(x))
            x = down(x)
        tiled = cond[:, :, None, None].expand(-1, -1, x.shape[2], x.shape[3])
        x = self.fuse(torch.cat([x, tiled], dim=1))
        for up, s in zip(self.up, reversed(skips), strict=True):
            x = up(F.interpolate(x, size=s.shape[2:], mode="nearest") + s)
        return x


def _head(channels: int, cout: int) -> nn.Sequential:
    """A head: 3x3 conv - ReLU - 1x1 conv to ``cout`` maps."""
    return nn.Sequential(
        nn.Conv2d(channels, channels, 3, 1, 1), nn.ReLU(inplace=True), nn.Conv2d(channels, cout, 1)
    )


class Trunk(nn.Module):
    """The encoders and the hourglass, shared by the detector and the Direct3D baseline:
    ``features(batch)`` is the (B, c, h, w) map the heads read."""

    def __init__(
        self,
        *,
        in_channels: int,
        hg_channels: int,
        hg_stacks: int,
        hg_depth: int,
        state_channels: int,
        comp_channels: int,
        k_max: int,
    ):
        super().__init__()
        c = hg_channels
        self.k_max = k_max
        self.state = StateEncoder(channels=state_channels)
        self.components = ComponentEncoder(channels=comp_channels)
        # stem on the image, the rendered state maps, the projected state features and the
        # camera planes, all at full resolution: H -> H/2 -> H/4
        stem_in = in_channels + STATE_MAPS + state_channels + CAMERA_PLANES
        self.stem = nn.Sequential(
            conv_bn(stem_in, c // 2, stride=2),
            conv_bn(c // 2, c, stride=2),
            Residual(channels=c),
        )
        self.stacks = nn.ModuleList(
            [
                Hourglass(channels=c, depth=hg_depth, cond_channels=k_max * comp_channels)
                for _ in range(hg_stacks)
            ]
        )
        self.inter = nn.ModuleList([nn.Conv2d(c, c, 1) for _ in range(hg_stacks - 1)])

    def _stem_in(
        self, image: torch.Tensor, maps: torch.Tensor, state: torch.Tensor, planes: torch.Tensor
    ) -> torch.Tensor:
        """The stem's first conv-BN-ReLU on the channels ``[image, maps, state, planes]``. The
        conv is linear in its input channels, so it runs as two: the state features, the only
        input with a gradient, apart from the rest, whose input gradient is never needed (a
        third of a training step's backward pass otherwise)."""
        first = self.stem[0]
        assert isinstance(first, nn.Sequential)
        conv, rest = first[0], first[1:]
        assert isinstance(conv, nn.Conv2d)
        if not state.requires_grad:
            return rest(conv(torch.cat([image, maps, state, planes], dim=1)))
        w = conv.weight
        a, b = image.shape[1] + maps.shape[1], image.shape[1] + maps.shape[1] + state.shape[1]
        fixed = torch.cat([image, maps, planes], dim=1)
        y = F.conv2d(fixed, torch.cat([w[:, :a], w[:, b:]], dim=1), None, conv.stride, conv.padding)
        y = y + F.conv2d(state, w[:, a:b], conv.bias, conv.stride, conv.padding)
        return rest(y)

    def features(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """The hourglass output, (B, c, h, w)."""
        image = batch["image"]  # (B, 4, H, W)
        state = self.state(batch["base_voxels"], batch["state_index"])  # (B, C1, H, W)
        emb = self.components(batch["comp_voxels"], batch["comp_valid"])  # (B, K, C2)
        planes = camera_planes(batch["camera"], image.shape[2:])
        x = self.stem[1:](self._stem_in(image, batch["state_maps"], state, planes))  # (B, c, h, w)
        cond = emb.flatten(1)  # (B, K * C2)
        for i, hg in enumerate(self.stacks):
            y = hg(x, cond)
            x = x + self.inter[i](y) if i < len(self.inter) else y
        return x


class MEPNet(Trunk):
    """The detector: heads per component slot at stride ``cfg.stride``."""

    def __init__(
        self,
        *,
        in_channels: int,
        hg_channels: int,
        hg_stacks: int,
        hg_depth: int,
        state_channels: int,
        comp_channels: int,
        k_max: int,
        emb_dim: int,
    ):
        super().__init__(
            in_channels=in_channels,
            hg_channels=hg_channels,
            hg_stacks=hg_stacks,
            hg_depth=hg_depth,
            state_channels=state_channels,
            comp_channels=comp_channels,
            k_max=k_max,
        )
        c = hg_channels
        self.emb_dim = emb_dim
        self.heatmap = _head(c, k_max)
        self.offset = _head(c, 2 * k_max)
        self.mask = _head(c, k_max)
        self.embedding = _head(c, k_max * emb_dim)
        self.rotation = _head(c, k_max * 7)
        # CenterNet's prior: heatmaps start near 0.01 so the focal loss is stable
        nn.init.constant_(self.heatmap[-1].bias, -4.6)

    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        x = self.features(batch)
        b, k = x.shape[0], self.k_max
        h, w = x.shape[2:]
        return {
            "heatmap": self.heatmap(x),  # (B, K, h, w) logits
            "offset": self.offset(x).view(b, k, 2, h, w),
            "mask": self.mask(x),  # (B, K, h, w) logits
            "embedding": self.embedding(x).view(b, k, self.emb_dim, h, w),
            "rotation": self.rotation(x).view(b, k, 7, h, w),  # logits
        }


#: Direct3D's CoordConv channels: the cell centre in NDC (2), the point of the world that
#: projects there on the view plane through the world origin, in lattice cells / COORD_NORM (3),
#: and the view direction (3).
COORD_CHANNELS = 8
#: Lattice cells per unit of Direct3D's coordinate channels and of its translation residual.
COORD_NORM, TRANSLATION_NORM = 32.0, 16.0
#: LDU per lattice cell (x, y, z), as :data:`mepnet.geom.LDU_PER_CELL`.
_CELL_LDU = (10.0, 8.0, 10.0)


def coord_channels(cam: torch.Tensor, h: int, w: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Direct3D's CoordConv input (B, COORD_CHANNELS, h, w) for the cameras ``cam`` (B, 12:
    rotation rows u, v, w, scale, tx, ty; :func:`mepnet.detector.targets.camera_vector`), and
    the view-plane point of every cell in lattice cells, (B, 3, h, w). Under weak perspective a
    cell's pixel fixes a world point up to depth along the view direction: that point plus a
    regressed offset is the translation (the network still has to find the depth and the
    offset of the component's origin from it)."""
    rot = cam[:, :9].view(-1, 3, 3)
    scale, t = cam[:, 9, None, None], cam[:, 10:12]
    nx = (torch.arange(w, dtype=cam.dtype, device=cam.device) + 0.5) / w * 2 - 1
    ny = 1 - (torch.arange(h, dtype=cam.dtype, device=cam.device) + 0.5) / h * 2
    u = (nx[None, None, :] - t[:, 0, None, None]) / scale  # (B, 1, w) LDU along the image's u
    v = (ny[None, :, None] - t[:, 1, None, None]) / scale  # (B, h, 1) LDU along v
    ldu = u[:, None] * rot[:, 0, :, None, None] + v[:, None] * rot[:, 1, :, None, None]
    cells = ldu / torch.tensor(_CELL_LDU, dtype=cam.dtype, device=cam.device)[None, :, None, None]
    b = cam.shape[0]
    planes = [
        nx[None, None, None, :].expand(b, 1, h, w),
        ny[None, None, :, None].expand(b, 1, h, w),
        cells / COORD_NORM,
        rot[:, 2, :, None, None].expand(b, 3, h, w),
    ]
    return torch.cat(planes, dim=1), cells


# The tensors a Direct3D network shares with the detector (``--init`` from the detector's
# weights): the encoders, the hourglass and the centre heatmap; the regression heads are its own.
DIRECT3D_FROM_DETECTOR = ("state.", "components.", "stem.", "stacks.", "inter.", "heatmap.")


class Direct3DNet(Trunk):
    """The paper's Direct3D baseline: the detector's encoders and hourglass, and heads that
    regress each instance's 3D translation and rotation directly, read at its centre cell (a
    centre heatmap says where the instances are; the counts are the manual's). CoordConv: the
    heads see :func:`coord_channels` beside the features."""

    def __init__(
        self,
        *,
        in_channels: int,
        hg_channels: int,
        hg_stacks: int,
        hg_depth: int,
        state_channels: int,
        comp_channels: int,
        k_max: int,
    ):
        super().__init__(
            in_channels=in_channels,
            hg_channels=hg_channels,
            hg_stacks=hg_stacks,
            hg_depth=hg_depth,
            state_channels=state_channels,
            comp_channels=comp_channels,
            k_max=k_max,
        )
        c = hg_channels
        self.heatmap = _head(c, k_max)
        self.translation = _head(c + COORD_CHANNELS, 3 * k_max)
        self.rotation = _head(c + COORD_CHANNELS, 7 * k_max)
        nn.init.constant_(self.heatmap[-1].bias, -4.6)

    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        x = self.features(batch)
        b, k = x.shape[0], self.k_max
        h, w = x.shape[2:]
        coords, cells = coord_channels(batch["camera"], h, w)
        xc = torch.cat([x, coords.to(x.dtype)], dim=1)
        residual = self.translation(xc).view(b, k, 3, h, w)
        return {
            "heatmap": self.heatmap(x),  # (B, K, h, w) logits
            # (B, K, 3, h, w): lattice cells (x, z half-studs, y plates) of the turned world
            "translation": cells[:, None].to(x.dtype) + TRANSLATION_NORM * residual,
            "rotation": self.rotation(xc).view(b, k, 7, h, w),  # logits
        }


def build_model(cfg: ModelConfig) -> MEPNet | Direct3DNet:
    """The network for a configuration (its ``head``: the detector or Direct3D)."""
    if cfg.head == "direct3d":
        return Direct3DNet(
            in_channels=cfg.in_channels,
            hg_channels=cfg.hg_channels,
            hg_stacks=cfg.hg_stacks,
            hg_depth=cfg.hg_depth,
            state_channels=cfg.state_channels,
            comp_channels=cfg.comp_channels,
            k_max=cfg.k_max,
        )
    return MEPNet(
        in_channels=cfg.in_channels,
        hg_channels=cfg.hg_channels,
        hg_stacks=cfg.hg_stacks,
        hg_depth=cfg.hg_depth,
        state_channels=cfg.state_channels,
        comp_channels=cfg.comp_channels,
        k_max=cfg.k_max,
        emb_dim=cfg.emb_dim,
    )
