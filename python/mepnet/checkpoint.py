"""Weights and training state on disk: safetensors for tensors, JSON for everything else.

Never pickles: ``torch.save`` / ``torch.load`` are not used anywhere, and a file that looks like
a pickle (or torch's zip format) is refused before anything reads it.

- ``model.safetensors`` + ``model.json``: the weights and the :class:`ModelConfig`, for shipping
  (:func:`save_model` / :func:`load_model`).
- ``checkpoint.safetensors`` + ``checkpoint.json``: model weights, the optimizer's tensors, and a
  JSON document with the rest (configs, step, optimizer scalars, scheduler state, random number
  generator states, best metric) (:func:`save_checkpoint` / :func:`load_checkpoint`). The JSON
  document is also stored inside the safetensors header, so the tensor file alone is complete
  and always consistent (it is replaced atomically); ``checkpoint.json`` is a readable copy.

Every file is written to a temporary sibling and renamed, so a crash never leaves a torn file.
"""

from __future__ import annotations

import json
import os
import tempfile
import uuid
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load as _st_load
from safetensors.torch import save as _st_save

CHECKPOINT_FORMAT = "mepnet.checkpoint"
MODEL_FORMAT = "mepnet.model"
VERSION = 1
_META_KEY = "mepnet"


class CheckpointError(ValueError):
    """A weights or checkpoint file that cannot be used; the message names the file."""


# ---------------------------------------------------------------------------------------------
# Atomic files


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to a temporary sibling of ``path``, fsync it, rename it over ``path``."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".tmp-{path.name}-", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), 0o666 & ~_umask())  # mkstemp makes 0600; be a normal file
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def format_json(doc: Any, indent: int = 0) -> str:
    """JSON with one key per line, but lists of scalars (random number generator states,
    grid sizes) on one line: readable and diffable without thousands of short lines."""
    pad = " " * (indent + 1)
    if isinstance(doc, dict) and doc:
        items = [f"{pad}{json.dumps(str(k))}: {format_json(v, indent + 1)}" for k, v in doc.items()]
        return "{\n" + ",\n".join(items) + "\n" + " " * indent + "}"
    if isinstance(doc, (list, tuple)) and any(isinstance(v, (dict, list, tuple)) for v in doc):
        items = [pad + format_json(v, indent + 1) for v in doc]
        return "[\n" + ",\n".join(items) + "\n" + " " * indent + "]"
    return json.dumps(doc)


def atomic_write_json(path: str | os.PathLike[str], doc: Any) -> None:
    """Write a JSON document atomically (:func:`format_json`, trailing newline)."""
    atomic_write_bytes(path, (format_json(doc) + "\n").encode())


def _check_not_pickle(path: Path, data: bytes) -> None:
    # A safetensors file: an 8-byte little-endian header length, then a JSON header ("{"). Its
    # first byte can be 0x80 (a header of 0x..80 bytes), so that layout is checked first.
    n = int.from_bytes(data[:8], "little") if len(data) >= 8 else -1
    if 0 < n <= len(data) - 8 and data[8:9] == b"{":
        return
    # torch.save writes a zip archive ("PK"); a bare pickle starts with the PROTO opcode 0x80.
    if data[:2] == b"PK" or data[:1] == b"\x80":
        raise CheckpointError(
            f"{path}: a pickle / torch.save file, not safetensors (pickles are never loaded)"
        )


def read_safetensors(
    path: str | os.PathLike[str],
) -> tuple[dict[str, torch.Tensor], dict[str, str]]:
    """Tensors (on the CPU) and header metadata of a safetensors file; :class:`CheckpointError`
    naming the file for anything that is not one."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no such file") from None
    except OSError as e:
        raise CheckpointError(f"{path}: cannot read ({e.strerror or e})") from None
    _check_not_pickle(path, data)
    if len(data) < 8:
        raise CheckpointError(f"{path}: truncated (not a safetensors file)")
    header_len = int.from_bytes(data[:8], "little")
    if header_len > len(data) - 8:
        raise CheckpointError(f"{path}: truncated or not a safetensors file")
    try:
        header = json.loads(data[8 : 8 + header_len])
        tensors = _st_load(data)
    except (SafetensorError, json.JSONDecodeError, UnicodeDecodeError, ValueError) as e:
        raise CheckpointError(f"{path}: not a valid safetensors file ({e})") from None
    meta = header.get("__metadata__") or {}
    return tensors, dict(meta)


def write_safetensors(
    path: str | os.PathLike[str], tensors: dict[str, torch.Tensor], metadata: dict[str, str]
) -> None:
    """Write tensors (copied to contiguous CPU storage, so shared or strided views are fine)
    and string metadata atomically."""
    flat = {k: v.detach().to("cpu", copy=True).contiguous() for k, v in tensors.items()}
    atomic_write_bytes(path, _st_save(flat, metadata=metadata))


# ---------------------------------------------------------------------------------------------
# Optimizer state <-> tensors + JSON


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


# ---------------------------------------------------------------------------------------------
# Shipping weights


def save_model(
    out: str | os.PathLike[str],
    state_dict: dict[str, torch.Tensor],
    model_config: dict[str, Any],
    extra: dict[str, Any] | None = None,
) -> None:
    """``OUT/model.safetensors`` (weights, model config in the header) and ``OUT/model.json``."""
    out = Path(out)
    doc = {
        "format": MODEL_FORMAT,
        "version": VERSION,
        "model_config": model_config,
        **(extra or {}),
    }
    write_safetensors(out / "model.safetensors", state_dict, {_META_KEY: json.dumps(doc)})
    atomic_write_json(out / "model.json", doc)


def load_model_weights(
    path: str | os.PathLike[str],
) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Weights and model config (a dict) of a ``model.safetensors`` written by :func:`save_model`
    (its config comes from the file's header; ``model.json`` is a readable copy)."""
    path = Path(path)
    tensors, meta = read_safetensors(path)
    try:
        doc = json.loads(meta[_META_KEY])
        if doc.get("format") != MODEL_FORMAT:
            raise KeyError("format")
        return tensors, dict(doc["model_config"])
    except (KeyError, TypeError, json.JSONDecodeError):
        raise CheckpointError(
            f"{path}: not a mepnet model file (no model config in its header)"
        ) from None


def load_model(path: str | os.PathLike[str], device: str | torch.device = "cpu") -> Any:
    """A ready :class:`mepnet.model.net.MEPNet` (eval mode) and its config from
    ``model.safetensors``."""
    from mepnet.model.config import ModelConfig
    from mepnet.model.net import build_model

    tensors, cfg_dict = load_model_weights(path)
    try:
        cfg = ModelConfig.from_dict(cfg_dict)
    except (TypeError, ValueError) as e:
        raise CheckpointError(f"{path}: model config in the header is invalid ({e})") from None
    model = build_model(cfg)
    load_state_strict(model, tensors, path)
    return model.to(device).eval(), cfg


def load_predictor(
    path: str | os.PathLike[str], device: str | torch.device = "cpu", lift: str = "synthesis"
) -> Any:
    """The ``mepnet`` predictor (detector + stage 2, lifting by ``synthesis`` or ``keypoint``)
    with the weights of ``model.safetensors``."""
    from mepnet.model.decode import MEPNetPredictor

    model, cfg = load_model(path, device)
    return MEPNetPredictor(model, cfg, lift=lift)


def load_state_strict(model: torch.nn.Module, tensors: dict[str, torch.Tensor], path: Path) -> None:
    """``model.load_state_dict`` with missing / unexpected / mis-shaped tensors reported as one
    :class:`CheckpointError` line naming the file."""
    expected = model.state_dict()
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    shapes = [k for k in expected if k in tensors and tensors[k].shape != expected[k].shape]

    def few(names: list[str]) -> str:
        return ", ".join(names[:3]) + (f" (and {len(names) - 3} more)" if len(names) > 3 else "")

    if missing:
        raise CheckpointError(f"{path}: missing tensors {few(missing)}")
    if unexpected:
        raise CheckpointError(f"{path}: unexpected tensors {few(unexpected)}")
    if shapes:
        k = shapes[0]
        raise CheckpointError(
            f"{path}: tensor {k} has shape {tuple(tensors[k].shape)}, "
            f"the model expects {tuple(expected[k].shape)}"
        )
    model.load_state_dict(tensors)


# ---------------------------------------------------------------------------------------------
# Training checkpoints


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
    write_safetensors(out / "checkpoint.safetensors", tensors, {_META_KEY: json.dumps(full)})
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
        doc = json.loads(meta[_META_KEY])
    except (KeyError, json.JSONDecodeError):
        raise CheckpointError(
            f"{path}: not a mepnet checkpoint (no training state in its header)"
        ) from None
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
