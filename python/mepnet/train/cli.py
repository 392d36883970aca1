"""Train the MEPNet detector (stage 1).

    python -m mepnet.train --data DIR [DIR ...] --out OUT [--model slim|paper|tiny|FILE.json]
                           [--val-dir DIR] [--config FILE.json] [--resume] [--<setting> VALUE ...]
    python -m mepnet.train --out OUT --steps N            # manuals generated on the fly
    python -m mepnet.train ... --head direct3d             # the paper's Direct3D baseline
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
import json
import os
import sys
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

from mepnet.cli import ArgumentParser
from mepnet.cli import run as run_cli
from mepnet.detector.config import HEADS, ModelConfig
from mepnet.errors import CheckpointError, ConfigError, OutputError
from mepnet.files import MANIFEST, atomic_write_json
from mepnet.stage2.base import LIFTS
from mepnet.train.checkpoint import check_training_state, load_checkpoint
from mepnet.train.config import (
    PRECISIONS,
    TrainConfig,
    check_resumable,
    config_diff,
    generator_settings,
    load_init,
    model_config_of,
    validate,
)
from mepnet.train.loop import run

#: What a training run writes into its --out folder (rank 0).
RUN_FILES = (
    "config.json",
    "checkpoint.safetensors",
    "checkpoint.json",
    "model.safetensors",
    "model.json",
    "metrics.csv",
    "metrics.json",
    "curves.png",
    ".mepnet-train.lock",
)


def _lock(out: Path) -> Any:
    """One run at a time per --out: an exclusive lock on a file in it, held while the returned
    file is open."""
    import fcntl

    f = open(out / ".mepnet-train.lock", "a")  # noqa: SIM115 (the caller closes it)
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        f.close()
        raise OutputError(
            f"{out}: another training run is writing into it (wait for it or choose another --out)"
        ) from None
    return f


CHOICES = {
    "schedule": ("cosine", "plateau"),
    "device": ("auto", "cpu", "cuda"),
    "val_lift": LIFTS,
    "head": HEADS,
    "precision": PRECISIONS,
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
    ap = ArgumentParser(
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


def resolve(args: argparse.Namespace, check: bool = True) -> tuple[TrainConfig, ModelConfig, Any]:
    """Settings from defaults, --config, the checkpoint (with --resume) and flags; checked
    unless ``check`` is false. Returns them and the loaded checkpoint (or None)."""
    names = {f.name for f in fields(TrainConfig)}
    flags = {k: v for k, v in vars(args).items() if k in names}
    flags = {k: tuple(v) if isinstance(v, list) else v for k, v in flags.items()}
    base = TrainConfig()
    if args.config is not None:
        try:
            base = TrainConfig.from_dict(json.loads(args.config.read_text()))
        except OSError as e:
            raise ConfigError(f"{args.config}: {e.strerror or e}") from None
        except (json.JSONDecodeError, UnicodeDecodeError, TypeError, ValueError) as e:
            raise ConfigError(f"{args.config}: not a valid training config ({e})") from None
    cfg = replace(base, **flags)
    out = Path(cfg.out)
    has_ckpt = (out / "checkpoint.safetensors").exists() or (out / "checkpoint.json").exists()
    ckpt = None
    if has_ckpt and not args.resume:
        raise ConfigError(f"{out}: holds a checkpoint; pass --resume or choose another --out")
    if has_ckpt:
        ckpt = load_checkpoint(out)
        path = out / "checkpoint.safetensors"
        doc = ckpt[2]
        check_training_state(path, doc)
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
            raise ConfigError(f"{path}: model config mismatch ({diff})")
    if check:
        validate(cfg)
    model_cfg = model_config_of(cfg)
    return cfg, model_cfg, ckpt


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (2 on bad input, with one line on stderr; 130 on
    Ctrl-C)."""
    args = build_parser().parse_args(argv)
    return run_cli("mepnet.train", lambda: _main(args))


def _main(args: argparse.Namespace) -> int:
    if args.print_config:  # a template for --config: printed before the checks
        print(json.dumps(resolve(args, check=False)[0].to_dict(), indent=1))
        return 0
    cfg, model_cfg, ckpt = resolve(args)
    init = load_init(cfg.init, model_cfg) if cfg.init is not None and ckpt is None else None
    generator = generator_settings(cfg, model_cfg) if not cfg.data else None
    out = Path(cfg.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: exists and is not a folder (--out)")
    main_rank = os.environ.get("RANK", "0") == "0"
    # a run writes only into a folder of its own: new, empty, or an earlier run's (checked by
    # the main process alone: the others would race with its lock file and manifest)
    if main_rank and out.is_dir() and any(out.iterdir()) and not (out / MANIFEST).is_file():
        raise OutputError(
            f"{out}: holds files mepnet.train did not write (choose a new --out; nothing was changed)"
        )
    out.mkdir(parents=True, exist_ok=True)
    lock = _lock(out) if main_rank else None
    try:
        if lock is not None and not (out / MANIFEST).is_file():
            atomic_write_json(out / MANIFEST, {"writer": "mepnet.train", "files": list(RUN_FILES)})
        if ckpt is None and args.resume:
            print(f"mepnet.train: no checkpoint in {out}; starting from step 0", file=sys.stderr)
        return run(
            cfg,
            model_cfg,
            ckpt,
            generator=generator,
            init=init,
            debug_checksums=args.debug_checksums,
            kill_at_step=args.debug_kill_at_step,
        )
    finally:
        if lock is not None:
            lock.close()  # (closing releases the lock)
