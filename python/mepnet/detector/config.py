"""Model configuration: sizes are configuration, modules take keyword arguments."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

from mepnet.errors import ConfigError

#: The networks a configuration can build: ``mepnet`` (the detector: keypoint heatmaps, masks,
#: rotation classes) and ``direct3d`` (the paper's Direct3D baseline: the same encoders, each
#: instance's 3D translation and rotation regressed directly; :mod:`mepnet.detector.direct3d`).
HEADS = ("mepnet", "direct3d")


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
    #: Which network (:data:`HEADS`); weights stored before it existed are ``mepnet``'s.
    head: str = "mepnet"

    def __post_init__(self) -> None:
        """Every size checked, so a bad setting fails here with one line naming it, not later
        inside the network."""

        def bad(name: str, why: str) -> ConfigError:
            return ConfigError(f"model setting {name}={getattr(self, name)!r}: {why}")

        if not isinstance(self.name, str):
            raise bad("name", "must be a string")
        if self.head not in HEADS:
            raise bad("head", f"must be one of {', '.join(HEADS)}")
        for name in (
            "image_size",
            "in_channels",
            "state_channels",
            "comp_channels",
            "k_max",
            "hg_channels",
            "hg_stacks",
            "hg_depth",
            "emb_dim",
            "stride",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise bad(name, "must be a positive integer")
        for name in ("base_grid", "comp_grid"):
            v = getattr(self, name)
            if (
                not isinstance(v, tuple)
                or len(v) != 3
                or any(isinstance(x, bool) or not isinstance(x, int) or x < 2 or x % 2 for x in v)
            ):
                raise bad(name, "must be three even integers >= 2 (x, y, z cells)")
            if v[0] * v[1] * v[2] > 512**3:
                raise bad(name, "is too large")
        if self.in_channels != 4:
            raise bad("in_channels", "must be 4 (RGB and the edge channel)")
        if self.stride != 4:
            raise bad("stride", "must be 4 (the stem halves the image twice)")
        if self.hg_channels % 2 or self.hg_channels > 4096:
            raise bad("hg_channels", "must be an even number up to 4096")
        if self.hg_depth > 6 or self.hg_stacks > 8 or self.k_max > 32 or self.emb_dim > 64:
            raise bad("hg_depth", "hg_depth <= 6, hg_stacks <= 8, k_max <= 32, emb_dim <= 64")
        unit = self.stride * 2**self.hg_depth
        if not 16 <= self.image_size <= 4096 or self.image_size % unit:
            raise bad("image_size", f"must be within 16..4096 and a multiple of {unit}")
        for name in ("state_channels", "comp_channels"):
            if getattr(self, name) > 4096:
                raise bad(name, "must be at most 4096")

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
        try:
            d = json.loads(Path(name).read_text())
        except OSError as e:
            raise ConfigError(
                f"{name}: not slim, paper, tiny or a readable JSON file ({e.strerror or e})"
            ) from None
        except (ValueError, UnicodeDecodeError) as e:
            raise ConfigError(f"{name}: not valid JSON ({e})") from None
        if not isinstance(d, dict):
            raise ConfigError(f"{name}: a model configuration must be a JSON object")
        try:
            return cls.from_dict(d)
        except (ConfigError, TypeError) as e:
            raise ConfigError(f"{name}: {e}") from None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ModelConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        if not isinstance(d, dict):
            raise ConfigError(f"a model configuration must be an object, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ConfigError(f"unknown model settings: {', '.join(sorted(unknown))}")
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        return cls(**kw)
