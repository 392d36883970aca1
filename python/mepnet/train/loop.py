"""The training loop of the MEPNet detector, written out as nanoGPT's: set-up in small named
functions (model and optimizer, data, schedule, resume), then one readable loop with phase
comments (forward, backward, update, log, validate, checkpoint). Settings and their checks are
in :mod:`mepnet.train.config`, data in :mod:`mepnet.train.data`, files in
:mod:`mepnet.train.checkpoint`, the command line in :mod:`mepnet.train.cli`.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader
from tqdm import tqdm

from mepnet.cli import note, workers_ignore_interrupts
from mepnet.detector.config import ModelConfig
from mepnet.detector.losses import total_loss
from mepnet.detector.net import DIRECT3D_FROM_DETECTOR, build_model
from mepnet.detector.targets import collate
from mepnet.detector.weights import load_state_strict, save_model
from mepnet.errors import CheckpointError, ConfigError
from mepnet.files import atomic_write_json
from mepnet.train import distributed as dist
from mepnet.train.checkpoint import save_checkpoint
from mepnet.train.config import TrainConfig
from mepnet.train.data import FolderSteps, GeneratedSteps, ResumableSampler, worker_init
from mepnet.train.log import MetricsLog

#: Data worker processes per CPU at most (``--workers`` above it is capped, with a note).
MAX_WORKERS_PER_CPU = 4

#: A loaded checkpoint: model state, optimizer state, JSON document.
Checkpoint = tuple[dict[str, torch.Tensor], dict[str, Any], dict[str, Any]]


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


#: ``-W`` option for the resource tracker: its UserWarnings are about an interrupted run's queues.
TRACKER_QUIET = "ignore::UserWarning:multiprocessing.resource_tracker"


@dataclass
class Data:
    """The batch stream: ``batches(start)`` yields from step ``start`` on; ``steps_per_epoch``
    is 0 for on-the-fly generation."""

    loader: DataLoader
    sampler: ResumableSampler | None
    steps_per_epoch: int
    batch_size: int

    def batches(self, start: int) -> Iterator[dict[str, torch.Tensor]]:
        """Batches from step ``start`` on; the position is a function of the step alone."""
        if self.sampler is None:
            with workers_ignore_interrupts():
                batches = iter(self.loader)
            yield from batches
            return
        epoch, position = divmod(start, self.steps_per_epoch)
        while True:
            self.sampler.set_epoch(epoch)
            self.sampler.skip = position * self.batch_size
            with workers_ignore_interrupts():  # (persistent workers start once)
                batches = iter(self.loader)
            yield from batches
            epoch, position = epoch + 1, 0

    def close(self) -> None:
        """Stop the worker processes now (persistent workers otherwise live until the loader is
        collected at exit, where an interrupted run's queues can be torn down out of order and
        multiprocessing's resource tracker warns about them after the one-line message)."""
        iterator = getattr(self.loader, "_iterator", None)
        if iterator is not None and hasattr(iterator, "_shutdown_workers"):
            try:
                iterator._shutdown_workers()
            except RuntimeError as e:
                # A worker that dies while it stops (seen on a GPU machine, 14 workers: SIGABRT,
                # "terminate called without an active exception", after the last checkpoint)
                # made nothing that was used; torch's own clean-up has already run (its
                # finally), so the run ends as it would have, with a note instead of a traceback.
                note(f"a data worker ended abnormally while the workers stopped ({e})")
        self.loader._iterator = None  # type: ignore[attr-defined]


def make_data(
    cfg: TrainConfig,
    model_cfg: ModelConfig,
    d: dist.Dist,
    start: int,
    generator: dict[str, Any] | None,
) -> Data:
    """Folder data (a resumable sampler over the steps) or manuals generated on the fly."""
    cuda = d.device.type == "cuda"
    # a few worker processes per core at most: each is an interpreter with torch (hundreds of
    # MB); batches do not depend on the number of workers, so capping changes nothing else
    workers = min(cfg.workers, MAX_WORKERS_PER_CPU * (os.cpu_count() or 1))
    if workers < cfg.workers and d.main:
        note(
            f"using {workers} data workers, not {cfg.workers} ({MAX_WORKERS_PER_CPU} per CPU at most)"
        )
    loader_kw: dict[str, Any] = {"num_workers": workers, "pin_memory": cuda}
    if workers > 0:
        # multiprocessing's resource tracker starts with the loader's queues and takes its
        # warning options from these: after Ctrl-C its notes on the queues an interrupted run
        # left would follow the one-line message
        if TRACKER_QUIET not in sys.warnoptions:
            sys.warnoptions.append(TRACKER_QUIET)
        # spawn, not fork: validation runs the extension's thread pool in this process, and a
        # pool started before a fork is unusable in the child; workers persist across epochs
        loader_kw.update(
            multiprocessing_context="spawn",
            persistent_workers=True,
            worker_init_fn=worker_init,
            prefetch_factor=2,
        )
    if cfg.data:
        folder = FolderSteps(
            cfg.data,
            model_config=model_cfg,
            seed=cfg.seed,
            augment=cfg.augment,
            submodules=cfg.submodule_steps,
            styles=cfg.styles,
        )
        if len(folder) == 0:
            raise ConfigError(f"{cfg.data[0]}: the manuals have no steps")
        sampler = ResumableSampler(folder, num_replicas=d.world_size, rank=d.rank, seed=cfg.seed)
        steps_per_epoch = len(sampler) // cfg.batch_size
        if steps_per_epoch == 0:
            raise ConfigError(
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
        return Data(loader, sampler, steps_per_epoch, cfg.batch_size)
    assert generator is not None
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
        styles=cfg.styles,
    )
    return Data(DataLoader(stream, batch_size=None, **loader_kw), None, 0, cfg.batch_size)


def make_schedule(cfg: TrainConfig, opt: torch.optim.Optimizer, total: int) -> Any:
    """Cosine (stepped every step) or plateau (stepped at every validation)."""
    if cfg.schedule == "cosine":
        return torch.optim.lr_scheduler.LambdaLR(
            opt, lambda s: _lr_factor(s, total, cfg.warmup_steps)
        )
    return torch.optim.lr_scheduler.ReduceLROnPlateau(
        opt,
        mode="max" if cfg.val_dir else "min",
        factor=cfg.plateau_factor,
        patience=cfg.plateau_patience,
    )


@dataclass
class RunState:
    """What a checkpoint carries besides the weights and the optimizer."""

    best: dict[str, Any] | None
    last_train_loss: float | None
    window: dict[str, float]


def restore(
    ckpt: Checkpoint | None,
    path: Path,
    model: nn.Module,
    opt: torch.optim.Optimizer,
    sched: Any,
    cfg: TrainConfig,
    d: dist.Dist,
) -> RunState:
    """Load a checkpoint into model, optimizer, schedule and random number generators (or seed
    a fresh run)."""
    if ckpt is None:
        # per-rank stream for anything random in the forward pass
        torch.manual_seed(int(np.random.SeedSequence([cfg.seed, d.rank]).generate_state(1)[0]))
        return RunState(None, None, _new_window())
    model_state, optim_state, doc = ckpt
    load_state_strict(model, model_state, path)
    params = list(model.parameters())
    for index, state in optim_state["state"].items():
        if index >= len(params) or any(
            isinstance(v, torch.Tensor) and v.dim() > 0 and v.shape != params[index].shape
            for v in state.values()
        ):
            raise CheckpointError(f"{path}: optimizer state does not fit the model")
    try:
        # after the scheduler's construction, which sets the lr: the saved lr wins
        opt.load_state_dict(optim_state)
        sched.load_state_dict(doc["scheduler"])
        ranks = doc["ranks"]
        mine = ranks[d.rank % len(ranks)]
        torch.set_rng_state(torch.tensor(mine["torch_rng"], dtype=torch.uint8))
        if d.device.type == "cuda" and mine.get("cuda_rng") is not None:
            torch.cuda.set_rng_state(torch.tensor(mine["cuda_rng"], dtype=torch.uint8))
        state = RunState(doc["best"], doc["last_train_loss"], dict(mine["window"]))
    except (KeyError, TypeError, ValueError, RuntimeError) as e:
        raise CheckpointError(f"{path}: malformed training state ({e})") from None
    if len(ranks) != d.world_size and d.main:
        print(
            f"mepnet.train: warning: checkpoint from {len(ranks)} processes, now "
            f"{d.world_size}: the data order differs from an uninterrupted run",
            file=sys.stderr,
        )
    return state


def run(
    cfg: TrainConfig,
    model_cfg: ModelConfig,
    ckpt: Checkpoint | None,
    *,
    generator: dict[str, Any] | None,
    init: dict[str, torch.Tensor] | None = None,
    debug_checksums: bool = False,
    kill_at_step: int | None = None,
) -> int:
    """Train (in this process, or as one rank of a torchrun job) from the ``--init`` weights
    ``init`` (when given and not resuming); returns the exit status."""
    d = dist.setup_distributed(cfg)
    try:
        return train(cfg, model_cfg, ckpt, d, generator, init, debug_checksums, kill_at_step)
    finally:
        if d.world_size > 1:
            import torch.distributed as td

            td.destroy_process_group()


def train(
    cfg: TrainConfig,
    model_cfg: ModelConfig,
    ckpt: Checkpoint | None,
    d: dist.Dist,
    generator: dict[str, Any] | None,
    init: dict[str, torch.Tensor] | None,
    debug_checksums: bool,
    kill_at_step: int | None,
) -> int:
    """The training run of one process."""
    from torch.nn.parallel import DistributedDataParallel

    out = Path(cfg.out)
    ckpt_path = out / "checkpoint.safetensors"
    cuda = d.device.type == "cuda"
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    bf16 = cfg.precision == "bf16"
    if (
        bf16
        and d.main
        and d.device.type == "cpu"
        and not torch.ops.mkldnn._is_mkldnn_bf16_supported()
    ):
        note("--precision bf16: this CPU has no bfloat16 instructions; emulated, slower than fp32")

    # --- set-up: model, optimizer, data, schedule, resume --------------------------------------
    torch.manual_seed(cfg.seed)  # the same initial weights on every rank
    model = build_model(model_cfg).to(d.device)
    if init is not None and ckpt is None:
        # a Direct3D run from the detector's weights: its own heads keep their fresh values
        own = {
            k: v
            for k, v in model.state_dict().items()
            if model_cfg.head == "direct3d" and not k.startswith(DIRECT3D_FROM_DETECTOR)
        }
        load_state_strict(model, {**own, **init}, Path(str(cfg.init)))
    params = list(model.parameters())
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    start = int(ckpt[2]["step"]) if ckpt is not None else 0
    data = make_data(cfg, model_cfg, d, start, generator)
    total = cfg.steps or cfg.epochs * data.steps_per_epoch
    sched = make_schedule(cfg, opt, total)
    state = restore(ckpt, ckpt_path, model, opt, sched, cfg, d)
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

    def validate(step: int) -> dict[str, Any] | None:
        """Pose accuracy of the whole pipeline on ``--val-dir`` (rank 0; broadcast)."""
        metrics = None
        if d.main and cfg.val_dir is not None:
            from mepnet.eval import evaluate
            from mepnet.stage2.detector import MEPNetPredictor
            from mepnet.stage2.direct3d import Direct3DPredictor

            t0 = time.perf_counter()
            runner = model if not cuda else _OnDevice(model, d.device)
            predictor = (
                Direct3DPredictor(runner, model_cfg)  # type: ignore[arg-type]
                if model_cfg.head == "direct3d"
                else MEPNetPredictor(runner, model_cfg, lift=cfg.val_lift)  # type: ignore[arg-type]
            )
            r = evaluate(cfg.val_dir, predictor, cd_points=cfg.val_cd_points, progress=False)
            model.train()
            keys = ("component_acc", "step_acc", "component_cd", "step_cd", "n_failures")
            metrics = {"step": step, "split": "val", **{k: r[k] for k in keys}}
            metrics["seconds"] = time.perf_counter() - t0
        return dist.broadcast(d, metrics)  # type: ignore[no-any-return]

    def checkpoint(step: int) -> None:
        """Everything needed to resume bit for bit, and the weights to ship."""
        dist.barrier(d)
        mine = {
            "torch_rng": torch.get_rng_state().tolist(),
            "cuda_rng": torch.cuda.get_rng_state(d.device).tolist() if cuda else None,
            "window": state.window,
        }
        ranks = dist.gather(d, mine)
        if d.main:
            weights = model.state_dict()
            doc = {
                "step": step,
                "total_steps": total,
                "steps_per_epoch": data.steps_per_epoch,
                "world_size": d.world_size,
                "model_config": model_cfg.to_dict(),
                "train_config": cfg.to_dict(),
                "scheduler": sched.state_dict(),
                "best": state.best,
                "last_train_loss": state.last_train_loss,
                "ranks": ranks,
                "torch_version": torch.__version__,
            }
            save_checkpoint(out, model_state=weights, optimizer_state=opt.state_dict(), doc=doc)
            save_model(out, weights, model_cfg.to_dict(), extra={"step": step, "best": state.best})
        dist.barrier(d)

    def say(msg: str) -> None:
        if d.main:
            tqdm.write(msg, file=sys.stdout)

    # --- the loop ------------------------------------------------------------------------------
    bar = tqdm(
        total=total,
        initial=start,
        unit="step",
        disable=not (cfg.progress and d.main),
        leave=False,  # an error then stays one line
        file=sys.stderr,
        dynamic_ncols=True,
    )
    net.train()
    step = start
    t_window, paused = time.perf_counter(), 0.0
    waited = 0.0  # seconds of the window spent waiting for the data workers' batches
    t_run = t_window
    batches = data.batches(start)
    window = state.window
    try:
        while step < total:
            # forward
            t_wait = time.perf_counter()
            host = next(batches)
            waited += time.perf_counter() - t_wait
            batch = {k: v.to(d.device, non_blocking=True) for k, v in host.items()}
            with torch.autocast(d.device.type, dtype=torch.bfloat16, enabled=bf16):
                outputs = net(batch)
            outputs = {k: v.float() for k, v in outputs.items()}  # the losses in float32
            loss, parts = total_loss(outputs, batch, model_cfg)
            if not torch.isfinite(loss):
                raise FloatingPointError(f"the loss is {loss.item()} at step {step + 1}")
            # backward
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
            # update
            opt.step()
            if cfg.schedule == "cosine":
                sched.step()
            step += 1
            bar.update(1)

            # log: means over the window, across ranks
            window["n"] += 1
            window["loss"] += float(loss.detach())
            window["grad_norm"] += grad_norm
            for k, v in parts.items():
                window[f"loss_{k}"] = window.get(f"loss_{k}", 0.0) + v
            if step % cfg.log_every == 0 or step == total:
                names = sorted(k for k in window if k != "n")
                means = dist.all_mean(d, [window[k] / max(window["n"], 1) for k in names])
                row: dict[str, Any] = {"step": step, "split": "train"}
                if data.steps_per_epoch:
                    row["epoch"] = step / data.steps_per_epoch
                row["lr"] = opt.param_groups[0]["lr"]
                row.update(zip(names, means, strict=True))
                dt = time.perf_counter() - t_window - paused
                row["samples_per_s"] = window["n"] * cfg.batch_size * d.world_size / max(dt, 1e-9)
                # the share of the time the training process waited for data (this rank's): near
                # 1, the data workers are the limit; near 0, the network is
                row["data_wait_share"] = min(1.0, waited / max(dt, 1e-9))
                state.last_train_loss = row["loss"]
                window = state.window = _new_window()
                t_window, paused, waited = time.perf_counter(), 0.0, 0.0
                if log is not None:
                    log.add(row)
                    bar.set_postfix(loss=f"{row['loss']:.4f}", lr=f"{row['lr']:.3g}")
                    if not cfg.progress:
                        say(
                            f"step {step}/{total} loss {row['loss']:.4f} lr {row['lr']:.3g}"
                            f" samples/s {row['samples_per_s']:.1f}"
                            f" waiting for data {100 * row['data_wait_share']:.0f}%"
                        )

            # validate (validation and checkpoints do not count as training time)
            t_pause = time.perf_counter()
            if step % cfg.val_every == 0 or step == total:
                metrics = validate(step)
                if metrics is not None:
                    acc = metrics["component_acc"]
                    if state.best is None or acc > state.best["value"]:
                        state.best = {"name": "val_component_acc", "value": acc, "step": step}
                    if log is not None:
                        log.add(metrics)
                    say(
                        f"step {step}: validation component_acc {acc:.4f} "
                        f"step_acc {metrics['step_acc']:.4f} ({metrics['seconds']:.1f}s)"
                    )
                if cfg.schedule == "plateau":
                    signal_value = metrics["component_acc"] if metrics else state.last_train_loss
                    if signal_value is not None:
                        sched.step(signal_value)
                if log is not None:
                    log.plot()

            # checkpoint
            if step % cfg.checkpoint_every == 0 or step == total:
                checkpoint(step)
            if kill_at_step is not None and step == kill_at_step:
                os.kill(os.getpid(), signal.SIGKILL)  # test hook: crash without cleanup
            paused += time.perf_counter() - t_pause
    finally:
        bar.close()  # also on Ctrl-C, before the one-line message
        batches.close()  # the generator drops its loader iterator (non-persistent workers stop)
        data.close()

    if log is not None:
        log.plot()
        dt = time.perf_counter() - t_run
        say(f"trained steps {start}..{total} in {dt:.1f}s; weights in {out / 'model.safetensors'}")
    if debug_checksums:
        (out / f"params_rank{d.rank}.sha256").write_text(dist.param_checksum(model) + "\n")
    return 0
