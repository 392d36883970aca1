"""The MEPNet network (paper §4.1), read top to bottom:

1. State-manual encoder: 3D conv-BN-ReLU on the base shape's voxels; the feature volume is
   resampled along camera rays (a differentiable spatial transform, trilinear ``grid_sample``),
   composited front to back so each pixel takes the first occupied voxel it hits (soft first hit),
   giving a 2D feature map that is concatenated with the image features.
2. Component encoder: 3D convs + average pooling, one embedding per component type, K_max slots,
   zero padded.
3. Hourglass: encoder to H/32, the tiled component embeddings concatenated at the bottleneck,
   decoder back to H/4 with skip connections.
4. Heads per slot: centre heatmap + offset, semantic mask + associative embedding, 7-way
   symmetry-aware rotation.

Shapes in comments: B batch, K slots, H/W image, h/w = H/4.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from mepnet.model.config import ModelConfig


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
    """Base shape voxels -> 2D feature map in the camera frame (first-hit projection)."""

    def __init__(
        self, *, channels: int, grid: tuple[int, int, int], depth_samples: int, out_size: int
    ):
        super().__init__()
        self.grid = grid
        self.depth_samples = depth_samples
        self.out_size = out_size
        self.convs = nn.Sequential(
            conv_bn(1, channels, dims=3), conv_bn(channels, channels, dims=3)
        )

    def sample_rays(self, volume: torch.Tensor, cam: torch.Tensor) -> torch.Tensor:
        """Resample ``volume`` (B, C, Z, Y, X) over the window along the camera rays of an
        ``out_size`` image: (B, C, D, n, n), depth samples near to far."""
        b = volume.shape[0]
        dev, dt = volume.device, volume.dtype
        gx, gy, gz = self.grid
        n, d = self.out_size, self.depth_samples
        rot = cam[:, :9].view(b, 3, 3)  # rows u (right), v (up), w (into the scene)
        scale, trans = cam[:, 9], cam[:, 10:12]
        # pixel centres of the output grid in NDC (y up)
        lin = (torch.arange(n, device=dev, dtype=dt) + 0.5) / n * 2 - 1
        ndc_y, ndc_x = torch.meshgrid(-lin, lin, indexing="ij")  # (n, n)
        u = (ndc_x[None] - trans[:, 0, None, None]) / scale[:, None, None]  # (B, n, n) LDU
        v = (ndc_y[None] - trans[:, 1, None, None]) / scale[:, None, None]
        # depth range: the window's extent along the view direction
        half = torch.tensor([gx * 5.0, gy * 4.0, gz * 5.0], device=dev, dtype=dt)
        centre = torch.tensor([0.0, gy * 4.0, 0.0], device=dev, dtype=dt)
        w_dir = rot[:, 2]  # (B, 3)
        reach = (w_dir.abs() * half).sum(-1)  # (B,)
        mid = (w_dir * centre).sum(-1)
        t = torch.linspace(0, 1, d, device=dev, dtype=dt)
        depth = (mid - reach)[:, None] + 2 * reach[:, None] * t[None]  # (B, D)
        # world point = u r_u + v r_v + depth r_w (rows of an orthonormal rotation)
        world = (
            u[:, None, :, :, None] * rot[:, None, None, None, 0]
            + v[:, None, :, :, None] * rot[:, None, None, None, 1]
            + depth[:, :, None, None, None] * rot[:, None, None, None, 2]
        )  # (B, D, n, n, 3) LDU
        lattice = world / torch.tensor([10.0, 8.0, 10.0], device=dev, dtype=dt)
        grid = torch.stack(
            [
                lattice[..., 0] / (gx / 2),
                lattice[..., 1] / (gy / 2) - 1,
                lattice[..., 2] / (gz / 2),
            ],
            dim=-1,
        )  # normalised to [-1, 1] over the window; (x, y, z) index (W, H, D) of the volume
        return F.grid_sample(
            volume, grid, mode="bilinear", padding_mode="zeros", align_corners=False
        )

    @staticmethod
    def first_hit_weights(occupancy: torch.Tensor) -> torch.Tensor:
        """Front-to-back compositing weights of sampled occupancy (B, 1, D, n, n): the soft
        version of taking the first occupied voxel along each ray."""
        alpha = occupancy.clamp(0, 1)
        ones = torch.ones_like(alpha[:, :, :1])
        transmittance = torch.cumprod(torch.cat([ones, 1 - alpha[:, :, :-1]], dim=2), dim=2)
        return alpha * transmittance

    def forward(self, vox: torch.Tensor, cam: torch.Tensor) -> torch.Tensor:
        # vox: (B, 1, Z, Y, X) occupancy; cam: (B, 12) = rotation rows u, v, w (9), scale, tx, ty
        feats = self.convs(vox)  # (B, C, Z, Y, X)
        samples = self.sample_rays(torch.cat([vox, feats], dim=1), cam)  # (B, 1 + C, D, n, n)
        weight = self.first_hit_weights(samples[:, :1])
        return (weight * samples[:, 1:]).sum(dim=2)  # (B, C, n, n)


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
        f = self.convs(vox.flatten(0, 1)).mean(dim=(2, 3, 4)).view(b, k, -1)
        return f * valid[..., None]


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


class MEPNet(nn.Module):
    """The detector: heads per component slot at stride ``cfg.stride``."""

    def __init__(
        self,
        *,
        in_channels: int,
        hg_channels: int,
        hg_stacks: int,
        hg_depth: int,
        state_channels: int,
        base_grid: tuple[int, int, int],
        depth_samples: int,
        comp_channels: int,
        k_max: int,
        emb_dim: int,
        out_size: int,
    ):
        super().__init__()
        c = hg_channels
        self.k_max, self.emb_dim = k_max, emb_dim
        self.state = StateEncoder(
            channels=state_channels, grid=base_grid, depth_samples=depth_samples, out_size=out_size
        )
        self.components = ComponentEncoder(channels=comp_channels)
        # image stem: H -> H/2 -> H/4, then the projected state features join
        self.stem = nn.Sequential(
            conv_bn(in_channels, c // 2, stride=2),
            conv_bn(c // 2, c, stride=2),
            Residual(channels=c),
        )
        self.merge = nn.Sequential(nn.Conv2d(c + state_channels, c, 1), nn.ReLU(inplace=True))
        self.stacks = nn.ModuleList(
            [
                Hourglass(channels=c, depth=hg_depth, cond_channels=k_max * comp_channels)
                for _ in range(hg_stacks)
            ]
        )
        self.inter = nn.ModuleList([nn.Conv2d(c, c, 1) for _ in range(hg_stacks - 1)])

        def head(cout: int) -> nn.Sequential:
            return nn.Sequential(
                nn.Conv2d(c, c, 3, 1, 1), nn.ReLU(inplace=True), nn.Conv2d(c, cout, 1)
            )

        self.heatmap = head(k_max)
        self.offset = head(2 * k_max)
        self.mask = head(k_max)
        self.embedding = head(k_max * emb_dim)
        self.rotation = head(k_max * 7)
        # CenterNet's prior: heatmaps start near 0.01 so the focal loss is stable
        nn.init.constant_(self.heatmap[-1].bias, -4.6)

    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        image = batch["image"]  # (B, 4, H, W)
        b = image.shape[0]
        state = self.state(batch["base_voxels"], batch["camera"])  # (B, C1, h, w)
        emb = self.components(batch["comp_voxels"], batch["comp_valid"])  # (B, K, C2)
        x = self.stem(image)  # (B, c, h, w)
        if state.shape[2:] != x.shape[2:]:
            state = F.interpolate(state, size=x.shape[2:], mode="bilinear", align_corners=False)
        x = self.merge(torch.cat([x, state], dim=1))
        cond = emb.flatten(1)  # (B, K * C2)
        for i, hg in enumerate(self.stacks):
            y = hg(x, cond)
            x = x + self.inter[i](y) if i < len(self.inter) else y
        k = self.k_max
        h, w = x.shape[2:]
        return {
            "heatmap": self.heatmap(x),  # (B, K, h, w) logits
            "offset": self.offset(x).view(b, k, 2, h, w),
            "mask": self.mask(x),  # (B, K, h, w) logits
            "embedding": self.embedding(x).view(b, k, self.emb_dim, h, w),
            "rotation": self.rotation(x).view(b, k, 7, h, w),  # logits
        }


def build_model(cfg: ModelConfig) -> MEPNet:
    """The network for a configuration."""
    return MEPNet(
        in_channels=cfg.in_channels,
        hg_channels=cfg.hg_channels,
        hg_stacks=cfg.hg_stacks,
        hg_depth=cfg.hg_depth,
        state_channels=cfg.state_channels,
        base_grid=cfg.base_grid,
        depth_samples=cfg.depth_samples,
        comp_channels=cfg.comp_channels,
        k_max=cfg.k_max,
        emb_dim=cfg.emb_dim,
        out_size=cfg.out_size,
    )
