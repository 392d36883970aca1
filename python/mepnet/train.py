"""Train the MEPNet detector (stage 1).

    python -m mepnet.train --data DIR [DIR ...] --out OUT [--model slim|paper|tiny|FILE.json]
                           [--val-dir DIR] [--config FILE.json] [--resume] [--<setting> VALUE ...]
    python -m mepnet.train --out OUT --steps N            # manuals generated on the fly
    torchrun --nproc_per_node=N -m mepnet.train ...       # DistributedDataParallel

Settings are the fields of :class:`TrainConfig`: defaults, then ``--config FILE.json``, then
flags (``--print-config`` shows the result). Outputs in OUT: ``checkpoint.safetensors`` +
``checkpoint.json`` (everything needed to resume: ``--resume`` continues bit for bit, with the
same data order), ``model.safetensors`` + ``model.json`` (weights + model config, to ship),
``metrics.csv`` / ``metrics.json`` and ``curves.png``. Validation runs the whole pipeline
(detector + stage 2) on ``--val-dir`` and reports pose accuracy. Bad input (missing or empty
data folder, unusable checkpoint) exits 2 with one line on stderr naming the file.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import math
import os
import signal
import sys
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import torch
from torch import nn

from mepnet.checkpoint import CheckpointError, atomic_write_json, load_checkpoint
from mepnet.data import ManualFormatError, iter_manual_dirs, load_manual
from mepnet.lift import LIFTS
from mepnet.model.config import ModelConfig


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
    model: str = _f("slim", "model config: slim, paper, tiny or a JSON file")
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
    progress: bool = _f(True, "progress bar", resumable=True)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """From a JSON object; unknown keys are an error, lists become tuples."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown training settings: {', '.join(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return asdict(self)


class SetupError(ValueError):
    """Bad input found before training starts (exit status 2)."""


# ---------------------------------------------------------------------------------------------
# Configuration


def model_config_of(cfg: TrainConfig) -> ModelConfig:
    """The model config named by ``cfg.model`` with ``cfg.model_set`` applied."""
    try:
        mc = ModelConfig.named(cfg.model)
    except FileNotFoundError:
        raise SetupError(
            f"{cfg.model}: no such model config (slim, paper, tiny or a JSON file)"
        ) from None
    except (json.JSONDecodeError, TypeError, ValueError) as e:
        raise SetupError(f"{cfg.model}: not a valid model config ({e})") from None
    d = mc.to_dict()
    for item in cfg.model_set:
        key, sep, value = item.partition("=")
        if not sep or key not in d:
            raise SetupError(f"--model-set {item}: expected KEY=VALUE with KEY one of {sorted(d)}")
        try:
            d[key] = json.loads(value)
        except json.JSONDecodeError:
            d[key] = value
    try:
        return ModelConfig.from_dict(d)
    except (TypeError, ValueError) as e:
        raise SetupError(f"--model-set: {e}") from None


def config_diff(saved: dict[str, Any], now: ModelConfig, what: str) -> str:
    """The model-config fields where ``saved`` (a stored config, as JSON) differs from ``now``,
    as ``field: WHAT saved, now value; ...`` ('' when they agree)."""
    cur = json.loads(json.dumps(now.to_dict()))  # tuples as lists, as stored
    return "; ".join(
        f"{k}: {what} {v!r}, now {cur.get(k)!r}" for k, v in saved.items() if cur.get(k) != v
    )


def load_init(path: str, model_cfg: ModelConfig) -> dict[str, torch.Tensor]:
    """The weights of ``--init``, checked against the run's model config."""
    from mepnet.checkpoint import load_model_weights

    tensors, saved = load_model_weights(path)
    diff = config_diff(saved, model_cfg, "weights")
    if diff:
        raise SetupError(f"{path}: --init weights do not fit the model config ({diff})")
    return tensors


def check_resumable(saved: TrainConfig, now: TrainConfig, path: Path) -> None:
    """A resumed run may change only the fields marked resumable (output, logging, length...)."""
    for f in fields(TrainConfig):
        a, b = getattr(saved, f.name), getattr(now, f.name)
        if not f.metadata["resumable"] and a != b:
            raise SetupError(
                f"{path}: the checkpoint was trained with {f.name}={a!r}, now {b!r}; resume "
                "with the same setting or start a new --out"
            )


def _validate(cfg: TrainConfig) -> None:
    if cfg.schedule not in ("cosine", "plateau"):
        raise SetupError(f"--schedule must be cosine or plateau, got {cfg.schedule!r}")
    for name in ("batch_size", "val_every", "checkpoint_every", "log_every", "samples_per_manual"):
        if getattr(cfg, name) < 1:
            raise SetupError(f"--{name.replace('_', '-')} must be at least 1")
    if cfg.steps < 0 or cfg.epochs < 0 or cfg.workers < 0 or cfg.threads < 0:
        raise SetupError("--steps, --epochs, --workers and --threads must not be negative")
    if not cfg.data and cfg.steps < 1:
        raise SetupError("on-the-fly generation (no --data) needs --steps")
    if cfg.val_lift not in LIFTS:
        raise SetupError(f"--val-lift must be {' or '.join(LIFTS)}, got {cfg.val_lift!r}")
    if cfg.init is not None and not Path(cfg.init).is_file():
        raise SetupError(f"{cfg.init}: no such weights file (--init)")
    if cfg.device not in ("auto", "cpu", "cuda"):
        raise SetupError(f"--device must be auto, cpu or cuda, got {cfg.device!r}")
    if cfg.device == "cuda" and not torch.cuda.is_available():
        raise SetupError("--device cuda: no CUDA device available")
    lo, hi = cfg.generate_seeds
    if not 0 <= lo < hi:
        raise SetupError(f"--generate-seeds must be 0 <= START < END, got {lo} {hi}")
    for d in cfg.data:
        if not Path(d).is_dir():
            raise SetupError(f"{d}: no such data folder")
        if next(iter_manual_dirs(d), None) is None:
            raise SetupError(f"{d}: no manual folders (manual.json) found")
    if cfg.val_dir is not None:
        if not Path(cfg.val_dir).is_dir():
            raise SetupError(f"{cfg.val_dir}: no such validation folder")
        dirs = list(iter_manual_dirs(cfg.val_dir))
        if not dirs:
            raise SetupError(f"{cfg.val_dir}: no manual folders (manual.json) found")
        for d in dirs:  # fail now rather than at the first validation
            load_manual(d)


def generator_settings(cfg: TrainConfig, model_cfg: ModelConfig) -> dict[str, Any]:
    """Settings of on-the-fly generation, checked with a tiny manual."""
    settings: dict[str, Any] = {}
    if cfg.generate_config is not None:
        path = Path(cfg.generate_config)
        try:
            settings = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise SetupError(f"{path}: {e}") from None
        if not isinstance(settings, dict):
            raise SetupError(f"{path}: expected a JSON object of generator settings")
    settings["image_size"] = cfg.generate_size or model_cfg.image_size
    from mepnet import _brickgeom as _bg
    from mepnet.geom import BrickGeomError

    probe = {**settings, "image_size": 16, "components": (1, 2), "p_submodule": 0.0}
    try:
        _bg.synth_manual(0, probe)
    except (BrickGeomError, ValueError, TypeError) as e:
        raise SetupError(f"generator settings: {e}") from None
    return settings


# ---------------------------------------------------------------------------------------------
# Distributed setup


@dataclass(frozen=True)
class Dist:
    """This process's place in the job."""

    rank: int
    world_size: int
    local_rank: int
    device: torch.device

    @property
    def main(self) -> bool:
        """Rank 0 logs, validates and writes files."""
        return self.rank == 0


def setup_distributed(cfg: TrainConfig) -> Dist:
    """Join the torchrun job if there is one (nccl on CUDA, gloo on CPU) and pick the device."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    cuda = cfg.device == "cuda" or (cfg.device == "auto" and torch.cuda.is_available())
    device = torch.device(f"cuda:{local}" if cuda else "cpu")
    if cuda:
        torch.cuda.set_device(device)
    if world > 1:
        import torch.distributed as td

        # rank 0 validates while the others wait: allow an hour
        td.init_process_group(
            backend="nccl" if cuda else "gloo", timeout=datetime.timedelta(hours=1)
        )
    return Dist(rank=rank, world_size=world, local_rank=local, device=device)


def _barrier(d: Dist) -> None:
    if d.world_size > 1:
        import torch.distributed as td

        td.barrier()


def _all_mean(d: Dist, values: list[float]) -> list[float]:
    if d.world_size == 1:
        return values
    import torch.distributed as td

    t = torch.tensor(values, dtype=torch.float64, device=d.device)
    td.all_reduce(t)
    return (t / d.world_size).tolist()


def _broadcast(d: Dist, obj: Any) -> Any:
    if d.world_size == 1:
        return obj
    import torch.distributed as td

    box = [obj]
    td.broadcast_object_list(box, src=0)
    return box[0]


def _gather(d: Dist, obj: Any) -> list[Any]:
    if d.world_size == 1:
        return [obj]
    import torch.distributed as td

    out: list[Any] = [None] * d.world_size
    td.all_gather_object(out, obj)
    return out


def param_checksum(model: nn.Module) -> str:
    """SHA-256 of all parameters (names, shapes and bytes), to compare processes."""
    h = hashlib.sha256()
    for name, p in model.named_parameters():
        t = p.detach().to("cpu").contiguous()
        h.update(name.encode())
        h.update(str(tuple(t.shape)).encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()


# ---------------------------------------------------------------------------------------------
# The loop


def _lr_factor(step: int, total: int, warmup: int) -> float:
    """Cosine decay to 0 over ``total`` steps after a linear warm-up."""
    if step < warmup:
        return (step + 1) / warmup
    progress = min(1.0, (step - warmup) / max(1, total - warmup))
    return 0.5 * (1.0 + math.cos(math.pi * progress))


class _OnDevice(nn.Module):
    """Runs ``net`` on ``device`` for callers that pass CPU batches (validation's predictor)."""

    def __init__(self, net: nn.Module, device: torch.device):
        super().__init__()
        self.net = net
        self.device = device

    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        out = self.net({k: v.to(self.device) for k, v in batch.items()})
        return {k: v.float().cpu() for k, v in out.items()}


def _new_window() -> dict[str, float]:
    return {"n": 0.0, "loss": 0.0, "grad_norm": 0.0}


def run(
    cfg: TrainConfig,
    model_cfg: ModelConfig,
    ckpt: tuple[dict[str, torch.Tensor], dict[str, Any], dict[str, Any]] | None,
    *,
    generator: dict[str, Any] | None,
    init: dict[str, torch.Tensor] | None = None,
    debug_checksums: bool = False,
    kill_at_step: int | None = None,
) -> int:
    """Train (in this process, or as one rank of a torchrun job) from the ``--init`` weights
    ``init`` (when given and not resuming); returns the exit status."""
    d = setup_distributed(cfg)
    try:
        return _train(cfg, model_cfg, ckpt, d, generator, init, debug_checksums, kill_at_step)
    finally:
        if d.world_size > 1:
            import torch.distributed as td

            td.destroy_process_group()


def _train(
    cfg: TrainConfig,
    model_cfg: ModelConfig,
    ckpt: tuple[dict[str, torch.Tensor], dict[str, Any], dict[str, Any]] | None,
    d: Dist,
    generator: dict[str, Any] | None,
    init: dict[str, torch.Tensor] | None,
    debug_checksums: bool,
    kill_at_step: int | None,
) -> int:
    import numpy as np
    from torch.nn.parallel import DistributedDataParallel
    from torch.utils.data import DataLoader
    from tqdm import tqdm

    from mepnet.checkpoint import load_state_strict, save_checkpoint, save_model
    from mepnet.model.losses import total_loss
    from mepnet.model.net import build_model
    from mepnet.model.targets import collate
    from mepnet.train_data import FolderSteps, GeneratedSteps, ResumableSampler, worker_init
    from mepnet.train_log import MetricsLog

    out = Path(cfg.out)
    ckpt_path = out / "checkpoint.safetensors"
    cuda = d.device.type == "cuda"
    if cfg.threads:
        torch.set_num_threads(cfg.threads)

    # --- model, optimizer, schedule --------------------------------------------------------
    torch.manual_seed(cfg.seed)  # the same initial weights on every rank
    model = build_model(model_cfg).to(d.device)
    if init is not None and ckpt is None:
        load_state_strict(model, init, Path(str(cfg.init)))
    params = list(model.parameters())
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay)

    # --- data --------------------------------------------------------------------------------
    start = int(ckpt[2]["step"]) if ckpt is not None else 0
    loader_kw: dict[str, Any] = {"num_workers": cfg.workers, "pin_memory": cuda}
    if cfg.workers > 0:
        # spawn, not fork: validation runs the extension's thread pool in this process, and a
        # pool started before a fork is unusable in the child; workers persist across epochs
        loader_kw.update(
            multiprocessing_context="spawn",
            persistent_workers=True,
            worker_init_fn=worker_init,
            prefetch_factor=2,
        )
    sampler = None
    if cfg.data:
        folder = FolderSteps(
            cfg.data,
            model_config=model_cfg,
            seed=cfg.seed,
            augment=cfg.augment,
            submodules=cfg.submodule_steps,
        )
        if len(folder) == 0:
            raise SetupError(f"{cfg.data[0]}: the manuals have no steps")
        sampler = ResumableSampler(folder, num_replicas=d.world_size, rank=d.rank, seed=cfg.seed)
        steps_per_epoch = len(sampler) // cfg.batch_size
        if steps_per_epoch == 0:
            raise SetupError(
                f"{cfg.data[0]}: {len(folder)} steps, fewer than batch_size x processes "
                f"({cfg.batch_size} x {d.world_size})"
            )
        loader = DataLoader(
            folder,
            batch_size=cfg.batch_size,
            sampler=sampler,
            drop_last=True,
            collate_fn=collate,
            **loader_kw,
        )
    else:
        assert generator is not None
        steps_per_epoch = 0
        stream = GeneratedSteps(
            model_config=model_cfg,
            seed=cfg.seed,
            seed_range=cfg.generate_seeds,
            generator=generator,
            batch_size=cfg.batch_size,
            samples_per_manual=cfg.samples_per_manual,
            augment=cfg.augment,
            submodules=cfg.submodule_steps,
            rank=d.rank,
            world_size=d.world_size,
            start_batch=start,
        )
        loader = DataLoader(stream, batch_size=None, **loader_kw)
    total = cfg.steps or cfg.epochs * steps_per_epoch

    def batches() -> Any:
        """Batches from step ``start`` on; the position is a function of the step alone."""
        if sampler is None:
            yield from loader
            return
        epoch, position = divmod(start, steps_per_epoch)
        while True:
            sampler.set_epoch(epoch)
            sampler.skip = position * cfg.batch_size
            yield from loader
            epoch, position = epoch + 1, 0

    if cfg.schedule == "cosine":
        sched: Any = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda s: _lr_factor(s, total, cfg.warmup_steps)
        )
    else:
        sched = torch.optim.lr_scheduler.ReduceLROnPlateau(
            opt,
            mode="max" if cfg.val_dir else "min",
            factor=cfg.plateau_factor,
            patience=cfg.plateau_patience,
        )

    # --- resume --------------------------------------------------------------------------------
    best: dict[str, Any] | None = None
    last_train_loss: float | None = None
    window = _new_window()
    if ckpt is not None:
        model_state, optim_state, doc = ckpt
        load_state_strict(model, model_state, ckpt_path)
        for index, state in optim_state["state"].items():
            if index >= len(params) or any(
                isinstance(v, torch.Tensor) and v.dim() > 0 and v.shape != params[index].shape
                for v in state.values()
            ):
                raise CheckpointError(f"{ckpt_path}: optimizer state does not fit the model")
        try:
            # after the scheduler's construction, which sets the lr: the saved lr wins
            opt.load_state_dict(optim_state)
            sched.load_state_dict(doc["scheduler"])
            best, last_train_loss = doc["best"], doc["last_train_loss"]
            ranks = doc["ranks"]
            mine = ranks[d.rank % len(ranks)]
            torch.set_rng_state(torch.tensor(mine["torch_rng"], dtype=torch.uint8))
            if cuda and mine.get("cuda_rng") is not None:
                torch.cuda.set_rng_state(torch.tensor(mine["cuda_rng"], dtype=torch.uint8))
            window = dict(mine["window"])
        except (KeyError, TypeError, ValueError, RuntimeError) as e:
            raise CheckpointError(f"{ckpt_path}: malformed training state ({e})") from None
        if len(ranks) != d.world_size and d.main:
            print(
                f"mepnet.train: warning: checkpoint from {len(ranks)} processes, now "
                f"{d.world_size}: the data order differs from an uninterrupted run",
                file=sys.stderr,
            )
    else:
        # per-rank stream for anything random in the forward pass
        torch.manual_seed(int(np.random.SeedSequence([cfg.seed, d.rank]).generate_state(1)[0]))

    net: nn.Module = model
    if d.world_size > 1:
        net = DistributedDataParallel(model, device_ids=[d.local_rank] if cuda else None)

    log = MetricsLog(out, keep_until=start if ckpt is not None else None) if d.main else None
    if d.main and ckpt is None:
        atomic_write_json(
            out / "config.json", {"train": cfg.to_dict(), "model": model_cfg.to_dict()}
        )
    if start >= total:
        if d.main:
            print(f"mepnet.train: {out} is already at step {start} of {total}; nothing to do")
        return 0

    # --- helpers of the loop -------------------------------------------------------------------
    def validate(step: int) -> dict[str, Any] | None:
        metrics = None
        if d.main and cfg.val_dir is not None:
            from mepnet.eval import evaluate
            from mepnet.model.decode import MEPNetPredictor

            t0 = time.perf_counter()
            runner = model if not cuda else _OnDevice(model, d.device)
            r = evaluate(
                cfg.val_dir,
                MEPNetPredictor(runner, model_cfg, lift=cfg.val_lift),
                cd_points=cfg.val_cd_points,
                progress=False,
            )
            model.train()
            keys = ("component_acc", "step_acc", "component_cd", "step_cd", "n_failures")
            metrics = {"step": step, "split": "val", **{k: r[k] for k in keys}}
            metrics["seconds"] = time.perf_counter() - t0
        return _broadcast(d, metrics)

    def checkpoint(step: int) -> None:
        _barrier(d)
        mine = {
            "torch_rng": torch.get_rng_state().tolist(),
            "cuda_rng": torch.cuda.get_rng_state(d.device).tolist() if cuda else None,
            "window": window,
        }
        ranks = _gather(d, mine)
        if d.main:
            state = model.state_dict()
            doc = {
                "step": step,
                "total_steps": total,
                "steps_per_epoch": steps_per_epoch,
                "world_size": d.world_size,
                "model_config": model_cfg.to_dict(),
                "train_config": cfg.to_dict(),
                "scheduler": sched.state_dict(),
                "best": best,
                "last_train_loss": last_train_loss,
                "ranks": ranks,
                "torch_version": torch.__version__,
            }
            save_checkpoint(out, model_state=state, optimizer_state=opt.state_dict(), doc=doc)
            extra = {"step": step, "best": best}
            save_model(out, state, model_cfg.to_dict(), extra=extra)
        _barrier(d)

    def say(msg: str) -> None:
        if d.main:
            tqdm.write(msg, file=sys.stdout)

    # --- the loop ------------------------------------------------------------------------------
    bar = tqdm(
        total=total,
        initial=start,
        unit="step",
        disable=not (cfg.progress and d.main),
        file=sys.stderr,
        dynamic_ncols=True,
    )
    net.train()
    step = start
    t_window, paused = time.perf_counter(), 0.0
    t_run = t_window
    it = batches()
    while step < total:
        batch = {k: v.to(d.device, non_blocking=True) for k, v in next(it).items()}
        outputs = net(batch)
        loss, parts = total_loss(outputs, batch, model_cfg)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"the loss is {loss.item()} at step {step + 1}")
        opt.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.grad_clip > 0:
            grad_norm = float(nn.utils.clip_grad_norm_(params, cfg.grad_clip))
        else:
            grad_norm = float(
                torch.linalg.vector_norm(
                    torch.stack([p.grad.norm() for p in params if p.grad is not None])
                )
            )
        opt.step()
        if cfg.schedule == "cosine":
            sched.step()
        step += 1
        bar.update(1)

        window["n"] += 1
        window["loss"] += float(loss.detach())
        window["grad_norm"] += grad_norm
        for k, v in parts.items():
            window[f"loss_{k}"] = window.get(f"loss_{k}", 0.0) + v

        if step % cfg.log_every == 0 or step == total:
            names = sorted(k for k in window if k != "n")
            means = _all_mean(d, [window[k] / max(window["n"], 1) for k in names])
            row: dict[str, Any] = {"step": step, "split": "train"}
            if steps_per_epoch:
                row["epoch"] = step / steps_per_epoch
            row["lr"] = opt.param_groups[0]["lr"]
            row.update(zip(names, means, strict=True))
            dt = time.perf_counter() - t_window - paused
            row["samples_per_s"] = window["n"] * cfg.batch_size * d.world_size / max(dt, 1e-9)
            last_train_loss = row["loss"]
            window = _new_window()
            t_window, paused = time.perf_counter(), 0.0
            if log is not None:
                log.add(row)
                bar.set_postfix(loss=f"{row['loss']:.4f}", lr=f"{row['lr']:.3g}")
                if not cfg.progress:
                    say(f"step {step}/{total} loss {row['loss']:.4f} lr {row['lr']:.3g}")

        t_pause = time.perf_counter()  # validation and checkpoints do not count as training
        if step % cfg.val_every == 0 or step == total:
            metrics = validate(step)
            if metrics is not None:
                acc = metrics["component_acc"]
                if best is None or acc > best["value"]:
                    best = {"name": "val_component_acc", "value": acc, "step": step}
                if log is not None:
                    log.add(metrics)
                say(
                    f"step {step}: validation component_acc {acc:.4f} "
                    f"step_acc {metrics['step_acc']:.4f} ({metrics['seconds']:.1f}s)"
                )
            if cfg.schedule == "plateau":
                signal_value = metrics["component_acc"] if metrics else last_train_loss
                if signal_value is not None:
                    sched.step(signal_value)
            if log is not None:
                log.plot()

        if step % cfg.checkpoint_every == 0 or step == total:
            checkpoint(step)
        if kill_at_step is not None and step == kill_at_step:
            os.kill(os.getpid(), signal.SIGKILL)  # test hook: crash without cleanup
        paused += time.perf_counter() - t_pause
    bar.close()

    if log is not None:
        log.plot()
        dt = time.perf_counter() - t_run
        say(f"trained steps {start}..{total} in {dt:.1f}s; weights in {out / 'model.safetensors'}")
    if debug_checksums:
        (out / f"params_rank{d.rank}.sha256").write_text(param_checksum(model) + "\n")
    return 0


# ---------------------------------------------------------------------------------------------
# Command line


CHOICES = {
    "schedule": ("cosine", "plateau"),
    "device": ("auto", "cpu", "cuda"),
    "val_lift": LIFTS,
}


def _field_flag(f: Any) -> tuple[str, dict[str, Any]]:
    flag = "--" + f.name.replace("_", "-")
    default = f.default
    shown = (" ".join(map(str, default)) or "none") if isinstance(default, tuple) else default
    kw: dict[str, Any] = {
        "help": f"{f.metadata['help']} (default: {shown})",
        "default": argparse.SUPPRESS,  # only flags given on the command line override
    }
    if f.name in CHOICES:
        kw["choices"] = CHOICES[f.name]
    if isinstance(default, bool):
        kw["action"] = argparse.BooleanOptionalAction
    elif f.name == "generate_seeds":
        kw.update(nargs=2, type=int, metavar=("START", "END"))
    elif isinstance(default, tuple):
        kw.update(nargs="+", metavar="VALUE")
    elif isinstance(default, (int, float)):
        kw["type"] = type(default)
    return flag, kw


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m mepnet.train`` argument parser: one flag per :class:`TrainConfig` field."""
    ap = argparse.ArgumentParser(
        prog="python -m mepnet.train",
        description=__doc__.splitlines()[0],
    )
    ap.add_argument("--config", type=Path, help="JSON file of settings (flags override it)")
    ap.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.*")
    ap.add_argument("--print-config", action="store_true", help="print the settings and exit")
    group = ap.add_argument_group("settings (TrainConfig)")
    for f in fields(TrainConfig):
        flag, kw = _field_flag(f)
        group.add_argument(flag, **kw)
    # test hooks: a per-rank checksum of the final parameters; a crash right after a step
    ap.add_argument("--debug-checksums", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--debug-kill-at-step", type=int, default=None, help=argparse.SUPPRESS)
    return ap


def _fail(msg: str) -> int:
    print(f"mepnet.train: error: {msg}", file=sys.stderr)
    return 2


def resolve(
    args: argparse.Namespace, validate: bool = True
) -> tuple[TrainConfig, ModelConfig, Any]:
    """Settings from defaults, --config, the checkpoint (with --resume) and flags; validated
    unless ``validate`` is false. Returns them and the loaded checkpoint (or None)."""
    names = {f.name for f in fields(TrainConfig)}
    flags = {k: v for k, v in vars(args).items() if k in names}
    flags = {k: tuple(v) if isinstance(v, list) else v for k, v in flags.items()}
    base = TrainConfig()
    if args.config is not None:
        try:
            base = TrainConfig.from_dict(json.loads(args.config.read_text()))
        except OSError as e:
            raise SetupError(f"{args.config}: {e.strerror or e}") from None
        except (json.JSONDecodeError, TypeError, ValueError) as e:
            raise SetupError(f"{args.config}: not a valid training config ({e})") from None
    cfg = replace(base, **flags)
    out = Path(cfg.out)
    has_ckpt = (out / "checkpoint.safetensors").exists() or (out / "checkpoint.json").exists()
    ckpt = None
    if has_ckpt and not args.resume:
        raise SetupError(f"{out}: holds a checkpoint; pass --resume or choose another --out")
    if has_ckpt:
        ckpt = load_checkpoint(out)
        path = out / "checkpoint.safetensors"
        doc = ckpt[2]
        try:
            saved = TrainConfig.from_dict(doc["train_config"])
            saved_model = ModelConfig.from_dict(doc["model_config"])
        except (KeyError, TypeError, ValueError) as e:
            raise CheckpointError(f"{path}: malformed configs ({e})") from None
        if args.config is None:
            cfg = replace(saved, **flags)
        check_resumable(saved, cfg, path)
        model_cfg = model_config_of(cfg)
        if model_cfg != saved_model:
            diff = config_diff(doc["model_config"], model_cfg, "checkpoint")
            raise SetupError(f"{path}: model config mismatch ({diff})")
    if validate:
        _validate(cfg)
    model_cfg = model_config_of(cfg)
    return cfg, model_cfg, ckpt


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (2 on bad input, with one line on stderr)."""
    args = build_parser().parse_args(argv)
    try:
        if args.print_config:  # a template for --config: printed before the checks
            print(json.dumps(resolve(args, validate=False)[0].to_dict(), indent=1))
            return 0
        cfg, model_cfg, ckpt = resolve(args)
        init = load_init(cfg.init, model_cfg) if cfg.init is not None and ckpt is None else None
        generator = generator_settings(cfg, model_cfg) if not cfg.data else None
        out = Path(cfg.out)
        out.mkdir(parents=True, exist_ok=True)
        if ckpt is None and args.resume:
            print(f"mepnet.train: no checkpoint in {out}; starting from step 0", file=sys.stderr)
    except (SetupError, CheckpointError, ManualFormatError) as e:
        return _fail(str(e))
    except OSError as e:
        return _fail(f"{e.filename or 'output folder'}: {e.strerror or e}")
    try:
        return run(
            cfg,
            model_cfg,
            ckpt,
            generator=generator,
            init=init,
            debug_checksums=args.debug_checksums,
            kill_at_step=args.debug_kill_at_step,
        )
    except (SetupError, CheckpointError, ManualFormatError) as e:
        return _fail(str(e))


if __name__ == "__main__":
    raise SystemExit(main())
