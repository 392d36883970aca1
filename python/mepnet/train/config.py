"""Training settings: :class:`TrainConfig` (every setting of a run, with its command-line help)
and the checks that run before training starts."""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import torch

from mepnet.detector.config import HEADS, ModelConfig
from mepnet.detector.net import DIRECT3D_FROM_DETECTOR
from mepnet.detector.weights import load_model_weights
from mepnet.errors import ConfigError
from mepnet.manual import iter_manual_dirs, load_manual
from mepnet.stage2.base import LIFTS
from mepnet.synth import check_generator_settings, read_generator_settings

#: ``--precision`` choices.
PRECISIONS = ("fp32", "bf16")


def _f(default: Any, help: str, resumable: bool = False) -> Any:
    """A config field with its command-line help; ``resumable`` fields may change on --resume."""
    return field(default=default, metadata={"help": help, "resumable": resumable})


@dataclass(frozen=True)
class TrainConfig:
    """Everything a training run depends on. The paper's LEGO setting: AdamW, lr 2.5e-4, batch
    16, 15 epochs (supplementary, hyper-parameter table); it gives no weight decay, so AdamW's
    default 0.01 is used."""

    data: tuple[str, ...] = _f((), "manual folders or folders of them; none: generate on the fly")
    generate_seeds: tuple[int, int] = _f(
        (1_000_000, 2_000_000), "seed range [start, end) of manuals generated on the fly"
    )
    generate_size: int = _f(0, "image side of generated manuals (0: the model's image_size)")
    generate_config: str | None = _f(None, "JSON file of generator settings (as mepnet.synth)")
    samples_per_manual: int = _f(8, "steps drawn from each generated manual")
    submodule_steps: bool = _f(True, "also train on the steps of submodule manuals")
    augment: bool = _f(True, "colour / blur / zoom augmentation")
    styles: float = _f(
        0.0,
        "share of samples whose step is drawn again in a random style (mepnet.styles, "
        "docs/styles.md; targets stay exact)",
    )
    model: str = _f("slim", "model config: slim, paper, tiny or a JSON file")
    head: str = _f(
        "mepnet",
        "the network: mepnet (the detector) or direct3d (the paper's Direct3D baseline: the "
        "same encoders, 3D translation and rotation regressed)",
    )
    model_set: tuple[str, ...] = _f((), "model config overrides KEY=VALUE (VALUE as JSON)")
    init: str | None = _f(
        None,
        "start from these weights (a model.safetensors, e.g. the shipped ones) with a fresh "
        "optimizer and schedule: fine-tuning; their model config must match --model",
    )
    batch_size: int = _f(16, "samples per step and process")
    lr: float = _f(2.5e-4, "peak learning rate (AdamW)")
    weight_decay: float = _f(0.01, "AdamW weight decay")
    grad_clip: float = _f(1.0, "clip the gradient norm to this (0: off)")
    steps: int = _f(0, "optimizer steps (0: epochs x steps per epoch)", resumable=True)
    epochs: int = _f(15, "epochs over folder data when steps is 0", resumable=True)
    schedule: str = _f("cosine", "learning-rate schedule: cosine or plateau")
    warmup_steps: int = _f(0, "linear warm-up steps (cosine)")
    plateau_factor: float = _f(0.5, "plateau: multiply the lr by this")
    plateau_patience: int = _f(2, "plateau: validations without improvement before reducing")
    workers: int = _f(2, "DataLoader worker processes (spawned) per process", resumable=True)
    val_dir: str | None = _f(None, "manual folders to validate on (pose accuracy)", True)
    val_every: int = _f(1000, "validate every N steps (and at the end)", resumable=True)
    val_lift: str = _f(
        "keypoint",
        "stage 2 in validation: keypoint (from the detector's keypoints and rotations, the "
        "paper's; measures the detector) or synthesis (mepnet.infer's default)",
        resumable=True,
    )
    val_cd_points: int = _f(500, "points per Chamfer distance in validation", resumable=True)
    checkpoint_every: int = _f(1000, "checkpoint every N steps (and at the end)", True)
    log_every: int = _f(50, "log training losses every N steps", resumable=True)
    out: str = _f("runs/mepnet", "output folder", resumable=True)
    seed: int = _f(0, "seed of initialisation, data order and augmentation")
    device: str = _f("auto", "auto, cpu or cuda", resumable=True)
    threads: int = _f(0, "torch CPU threads per process (0: torch's default)", resumable=True)
    precision: str = _f(
        "fp32",
        "arithmetic of the forward and backward passes: fp32, or bf16 (autocast: convolutions "
        "in bfloat16; weights, batch-norm statistics, losses and the optimizer in float32; "
        "about 1.6x faster on CPUs with avx512_bf16 or AMX and on GPUs; validation stays fp32)",
        resumable=True,
    )
    progress: bool = _f(True, "progress bar", resumable=True)

    def __post_init__(self) -> None:
        """Every setting has the type of its default (a config file can hold anything)."""
        for f in fields(self):
            v, default = getattr(self, f.name), f.default
            flag = "--" + f.name.replace("_", "-")
            if isinstance(default, bool):
                ok = isinstance(v, bool)
                want = "true or false"
            elif isinstance(default, int):
                ok = isinstance(v, int) and not isinstance(v, bool)
                want = "an integer"
            elif isinstance(default, float):
                ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                want = "a finite number"
            elif isinstance(default, tuple):
                kind = int if f.name == "generate_seeds" else str
                ok = isinstance(v, tuple) and all(
                    isinstance(x, kind) and not isinstance(x, bool) for x in v
                )
                if f.name == "generate_seeds":
                    ok = ok and len(v) == 2
                want = "two integers" if f.name == "generate_seeds" else "a list of strings"
            else:  # a string, or a path that may be None
                ok = isinstance(v, str) or (default is None and v is None)
                want = "a string"
            if not ok:
                raise ConfigError(f"setting {f.name} ({flag}) must be {want}, got {v!r}")

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """From a JSON object; unknown keys are an error, lists become tuples."""
        if not isinstance(d, dict):
            raise ConfigError(f"training settings must be a JSON object, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ConfigError(f"unknown training settings: {', '.join(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return asdict(self)


def model_config_of(cfg: TrainConfig) -> ModelConfig:
    """The model config named by ``cfg.model`` with ``cfg.model_set`` applied."""
    try:
        mc = ModelConfig.named(cfg.model)
    except TypeError as e:
        raise ConfigError(f"{cfg.model}: not a valid model config ({e})") from None
    d = mc.to_dict()
    d["head"] = cfg.head
    for item in cfg.model_set:
        key, sep, value = item.partition("=")
        if not sep or key not in d:
            raise ConfigError(f"--model-set {item}: expected KEY=VALUE with KEY one of {sorted(d)}")
        try:
            d[key] = json.loads(value)
        except json.JSONDecodeError:
            d[key] = value
    try:
        return ModelConfig.from_dict(d)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"--model-set {' '.join(cfg.model_set)}: {e}") from None


def config_diff(saved: dict[str, Any], now: ModelConfig, what: str) -> str:
    """The model-config fields where ``saved`` (a stored config, as JSON) differs from ``now``,
    as ``field: WHAT saved, now value; ...`` ('' when they agree)."""
    cur = json.loads(json.dumps(now.to_dict()))  # tuples as lists, as stored
    return "; ".join(
        f"{k}: {what} {v!r}, now {cur.get(k)!r}" for k, v in saved.items() if cur.get(k) != v
    )


def load_init(path: str, model_cfg: ModelConfig) -> dict[str, torch.Tensor]:
    """The weights of ``--init``, checked against the run's model config. A Direct3D run may
    start from the detector's weights: it takes the encoders, the hourglass and the centre
    heatmap (:data:`mepnet.detector.net.DIRECT3D_FROM_DETECTOR`, the tensors the two networks
    share), its regression heads start fresh."""
    tensors, saved = load_model_weights(path)
    head = saved.get("head", "mepnet")
    if head != model_cfg.head:
        if (head, model_cfg.head) != ("mepnet", "direct3d"):
            raise ConfigError(
                f"{path}: --init weights are a {head} network, the run trains "
                f"{model_cfg.head} (--head)"
            )
        saved = {k: v for k, v in saved.items() if k != "head"}
        tensors = {k: v for k, v in tensors.items() if k.startswith(DIRECT3D_FROM_DETECTOR)}
    diff = config_diff(saved, model_cfg, "weights")
    if diff:
        raise ConfigError(f"{path}: --init weights do not fit the model config ({diff})")
    return tensors


def check_resumable(saved: TrainConfig, now: TrainConfig, path: Path) -> None:
    """A resumed run may change only the fields marked resumable (output, logging, length...)."""
    for f in fields(TrainConfig):
        a, b = getattr(saved, f.name), getattr(now, f.name)
        if not f.metadata["resumable"] and a != b:
            raise ConfigError(
                f"{path}: the checkpoint was trained with {f.name}={a!r}, now {b!r}; resume "
                "with the same setting or start a new --out"
            )


def validate(cfg: TrainConfig) -> None:
    """Check every setting and input folder before anything starts."""
    if cfg.schedule not in ("cosine", "plateau"):
        raise ConfigError(f"--schedule must be cosine or plateau, got {cfg.schedule!r}")
    for name in ("batch_size", "val_every", "checkpoint_every", "log_every", "samples_per_manual"):
        if getattr(cfg, name) < 1:
            raise ConfigError(f"--{name.replace('_', '-')} must be at least 1")
    if cfg.steps < 0 or cfg.epochs < 0 or cfg.workers < 0 or cfg.threads < 0:
        raise ConfigError("--steps, --epochs, --workers and --threads must not be negative")
    if cfg.warmup_steps < 0 or cfg.plateau_patience < 0 or cfg.seed < 0:
        raise ConfigError("--warmup-steps, --plateau-patience and --seed must not be negative")
    if cfg.lr < 0:
        raise ConfigError(f"--lr must not be negative, got {cfg.lr}")
    if cfg.weight_decay < 0 or cfg.grad_clip < 0:
        raise ConfigError("--weight-decay and --grad-clip must not be negative")
    if not 0 <= cfg.styles <= 1:
        raise ConfigError(f"--styles must be within [0, 1], got {cfg.styles}")
    if not 0 < cfg.plateau_factor < 1:
        raise ConfigError(f"--plateau-factor must be within (0, 1), got {cfg.plateau_factor}")
    max_threads = 4 * (os.cpu_count() or 1)
    if cfg.threads > max_threads:
        raise ConfigError(
            f"--threads {cfg.threads}: at most {max_threads} on this machine (4 per CPU)"
        )
    if cfg.generate_size and not 16 <= cfg.generate_size <= 2048:
        raise ConfigError(f"--generate-size must be 0 or within 16..2048, got {cfg.generate_size}")
    if cfg.val_cd_points < 1:
        raise ConfigError(f"--val-cd-points must be at least 1, got {cfg.val_cd_points}")
    if not cfg.data and cfg.steps < 1:
        raise ConfigError("on-the-fly generation (no --data) needs --steps")
    if cfg.head not in HEADS:
        raise ConfigError(f"--head must be {' or '.join(HEADS)}, got {cfg.head!r}")
    if cfg.val_lift not in LIFTS:
        raise ConfigError(f"--val-lift must be {' or '.join(LIFTS)}, got {cfg.val_lift!r}")
    if cfg.init is not None and not Path(cfg.init).is_file():
        raise ConfigError(f"{cfg.init}: no such weights file (--init)")
    if cfg.precision not in PRECISIONS:
        raise ConfigError(f"--precision must be {' or '.join(PRECISIONS)}, got {cfg.precision!r}")
    if cfg.device not in ("auto", "cpu", "cuda"):
        raise ConfigError(f"--device must be auto, cpu or cuda, got {cfg.device!r}")
    if cfg.device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("--device cuda: no CUDA device available")
    lo, hi = cfg.generate_seeds
    if not 0 <= lo < hi:
        raise ConfigError(f"--generate-seeds must be 0 <= START < END, got {lo} {hi}")
    for d in cfg.data:
        if not Path(d).is_dir():
            raise ConfigError(f"{d}: no such data folder")
        if next(iter_manual_dirs(d), None) is None:
            raise ConfigError(f"{d}: no manual folders (manual.json) found")
    if cfg.val_dir is not None:
        if not Path(cfg.val_dir).is_dir():
            raise ConfigError(f"{cfg.val_dir}: no such validation folder")
        dirs = list(iter_manual_dirs(cfg.val_dir))
        if not dirs:
            raise ConfigError(f"{cfg.val_dir}: no manual folders (manual.json) found")
        for d in dirs:  # fail now rather than at the first validation
            load_manual(d)


def generator_settings(cfg: TrainConfig, model_cfg: ModelConfig) -> dict[str, Any]:
    """Settings of on-the-fly generation (``--generate-config``), checked."""
    settings: dict[str, Any] = {}
    if cfg.generate_config is not None:
        settings = read_generator_settings(Path(cfg.generate_config))
    settings["image_size"] = cfg.generate_size or model_cfg.image_size
    check_generator_settings(
        settings, Path(cfg.generate_config) if cfg.generate_config is not None else None
    )
    return settings
