"""Model configuration: sizes are configuration, modules take keyword arguments."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class ModelConfig:
    """Sizes of the detector. Grids are in lattice cells (x, y, z): x and z half-studs, y plates."""

    name: str = "slim"
    #: Manual image side (pixels) the network sees; other sizes are resized.
    image_size: int = 256
    #: Image channels: RGB plus an edge (Laplacian) channel.
    in_channels: int = 4
    #: Window of the base shape's voxel grid: x in [-gx/2, gx/2), y in [0, gy), z in [-gz/2, gz/2).
    base_grid: tuple[int, int, int] = (64, 48, 64)
    #: Grid a component is centred in.
    comp_grid: tuple[int, int, int] = (24, 24, 24)
    #: Channels of the 3D state features (C1) projected into the image.
    state_channels: int = 8
    #: Channels of a component embedding (C2).
    comp_channels: int = 32
    #: Component type slots (K_max).
    k_max: int = 5
    #: Hourglass width and number of stacks.
    hg_channels: int = 48
    hg_stacks: int = 1
    #: Down-sampling steps of the hourglass below the H/4 feature map (to H/32: 3).
    hg_depth: int = 3
    #: Associative embedding dimensions per slot.
    emb_dim: int = 1
    #: Output stride of the heads.
    stride: int = 4

    @property
    def out_size(self) -> int:
        """Side of the head outputs."""
        return self.image_size // self.stride

    @classmethod
    def slim(cls) -> ModelConfig:
        """Trains and runs on a 2-core CPU: 256 px, narrow single-stack hourglass."""
        return cls()

    @classmethod
    def paper(cls) -> ModelConfig:
        """The paper's sizes (512 px input, 2-stack 256-channel hourglass); for GPUs."""
        return cls(
            name="paper",
            image_size=512,
            base_grid=(128, 96, 128),
            comp_grid=(32, 32, 32),
            state_channels=16,
            comp_channels=64,
            hg_channels=256,
            hg_stacks=2,
            hg_depth=3,
        )

    @classmethod
    def tiny(cls) -> ModelConfig:
        """For tests: everything small."""
        return cls(
            name="tiny",
            image_size=64,
            base_grid=(32, 16, 32),
            comp_grid=(16, 16, 16),
            state_channels=4,
            comp_channels=8,
            hg_channels=16,
            hg_depth=2,
        )

    @classmethod
    def named(cls, name: str) -> ModelConfig:
        """``slim``, ``paper``, ``tiny``, or a JSON file."""
        if name in ("slim", "paper", "tiny"):
            return getattr(cls, name)()
        return cls.from_dict(json.loads(Path(name).read_text()))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ModelConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown model settings: {', '.join(sorted(unknown))}")
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        return cls(**kw)
