"""Training state on disk: ``checkpoint.safetensors`` + ``checkpoint.json``: model weights, the
optimizer's tensors, and a JSON document with the rest (configs, step, optimizer scalars,
scheduler state, random number generator states, best metric). The JSON document is also
stored inside the safetensors header, so the tensor file alone is complete and always
consistent (it is replaced atomically); ``checkpoint.json`` is a readable copy. Never pickles
(:mod:`mepnet.detector.weights`).
"""

from __future__ import annotations

import json
import os
import uuid
from pathlib import Path
from typing import Any

import torch

from mepnet.detector.weights import META_KEY, VERSION, read_safetensors, write_safetensors
from mepnet.errors import CheckpointError
from mepnet.files import atomic_write_json

CHECKPOINT_FORMAT = "mepnet.checkpoint"


def flatten_optimizer(
    state: dict[str, Any],
) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """An optimizer ``state_dict()`` as ``optim/<param>/<key>`` tensors plus a JSON-able rest."""
    tensors: dict[str, torch.Tensor] = {}
    scalars: dict[str, Any] = {}
    for index, per_param in state["state"].items():
        for key, value in per_param.items():
            if isinstance(value, torch.Tensor):
                tensors[f"optim/{index}/{key}"] = value
            else:
                scalars[f"{index}/{key}"] = value
    groups = [
        {k: list(v) if isinstance(v, tuple) else v for k, v in g.items()}
        for g in state["param_groups"]
    ]
    return tensors, {"param_groups": groups, "scalars": scalars}


def unflatten_optimizer(tensors: dict[str, torch.Tensor], rest: dict[str, Any]) -> dict[str, Any]:
    """Inverse of :func:`flatten_optimizer`."""
    state: dict[int, dict[str, Any]] = {}
    for name, value in tensors.items():
        _, index, key = name.split("/", 2)
        state.setdefault(int(index), {})[key] = value
    for name, value in rest["scalars"].items():
        index, key = name.split("/", 1)
        state.setdefault(int(index), {})[key] = value
    groups = [
        {k: tuple(v) if k == "betas" else v for k, v in g.items()} for g in rest["param_groups"]
    ]
    return {"state": state, "param_groups": groups}


def save_checkpoint(
    out: str | os.PathLike[str],
    *,
    model_state: dict[str, torch.Tensor],
    optimizer_state: dict[str, Any],
    doc: dict[str, Any],
) -> None:
    """``OUT/checkpoint.safetensors`` (``model/*`` and ``optim/*`` tensors; ``doc`` plus the
    optimizer's scalars in the header) and ``OUT/checkpoint.json`` (the same document)."""
    out = Path(out)
    optim_tensors, optim_rest = flatten_optimizer(optimizer_state)
    full = {
        "format": CHECKPOINT_FORMAT,
        "version": VERSION,
        "id": uuid.uuid4().hex,
        **doc,
        "optimizer": optim_rest,
    }
    tensors = {f"model/{k}": v for k, v in model_state.items()} | optim_tensors
    write_safetensors(out / "checkpoint.safetensors", tensors, {META_KEY: json.dumps(full)})
    atomic_write_json(out / "checkpoint.json", full)


def load_checkpoint(
    out: str | os.PathLike[str],
) -> tuple[dict[str, torch.Tensor], dict[str, Any], dict[str, Any]]:
    """Model state, optimizer ``state_dict`` and the JSON document of ``OUT/checkpoint.*``.

    The document comes from the safetensors header: if a crash fell between the two renames of
    :func:`save_checkpoint`, ``checkpoint.json`` is one save behind and is ignored."""
    path = Path(out) / "checkpoint.safetensors"
    if not path.is_file():
        if (Path(out) / "checkpoint.json").is_file():
            raise CheckpointError(f"{path}: missing (checkpoint.json has no tensors beside it)")
        raise CheckpointError(f"{path}: no such file")
    tensors, meta = read_safetensors(path)
    try:
        doc = json.loads(meta[META_KEY])
    except (KeyError, json.JSONDecodeError):
        raise CheckpointError(
            f"{path}: not a mepnet checkpoint (no training state in its header)"
        ) from None
    if not isinstance(doc, dict):
        raise CheckpointError(f"{path}: not a mepnet checkpoint (its header is not an object)")
    if doc.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: format is {doc.get('format')!r}, not {CHECKPOINT_FORMAT}")
    if doc.get("version") != VERSION:
        raise CheckpointError(f"{path}: checkpoint version {doc.get('version')!r} not supported")
    model_state = {k[len("model/") :]: v for k, v in tensors.items() if k.startswith("model/")}
    optim_tensors = {k: v for k, v in tensors.items() if k.startswith("optim/")}
    try:
        optimizer_state = unflatten_optimizer(optim_tensors, doc["optimizer"])
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(
            f"{path}: malformed optimizer state ({type(e).__name__}: {e})"
        ) from None
    # every parameter with state has the same entries (AdamW: step, exp_avg, exp_avg_sq)
    keys = [set(s) for s in optimizer_state["state"].values()]
    full_keys = set().union(*keys) if keys else set()
    for index, s in optimizer_state["state"].items():
        if set(s) != full_keys:
            lacking = ", ".join(sorted(full_keys - set(s)))
            raise CheckpointError(f"{path}: missing tensors optim/{index}/{{{lacking}}}")
    return model_state, optimizer_state, doc


def check_training_state(path: Path, doc: dict[str, Any]) -> None:
    """The fields of a training run's checkpoint document (``mepnet.train`` writes them),
    checked before anything uses them."""

    def bad(what: str) -> CheckpointError:
        return CheckpointError(f"{path}: malformed training state ({what})")

    step = doc.get("step")
    if isinstance(step, bool) or not isinstance(step, int) or step < 0:
        raise bad(f"step {step!r} is not a count of steps")
    for key in ("train_config", "model_config", "scheduler", "optimizer"):
        if not isinstance(doc.get(key), dict):
            raise bad(f"{key} is not an object")
    ranks = doc.get("ranks")
    if not isinstance(ranks, list) or not ranks or not all(isinstance(r, dict) for r in ranks):
        raise bad("ranks is not a list of objects")
    if doc.get("best") is not None and not isinstance(doc["best"], dict):
        raise bad("best is not an object")
    loss = doc.get("last_train_loss")
    if loss is not None and (isinstance(loss, bool) or not isinstance(loss, (int, float))):
        raise bad("last_train_loss is not a number")
