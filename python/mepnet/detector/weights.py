"""Detector weights on disk: ``model.safetensors`` (the tensors, the model config in the header)
and ``model.json`` (a readable copy of the config and provenance).

Never pickles: ``torch.save`` / ``torch.load`` are not used anywhere, and a file that looks like
a pickle (or torch's zip format) is refused before anything reads it. Every file is written to
a temporary sibling and renamed (:mod:`mepnet.files`), so a crash never leaves a torn file.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import torch
from mepnet.detector.config import ModelConfig
from mepnet.detector.net import Direct3DNet, MEPNet, build_model
from mepnet.errors import CheckpointError
from mepnet.files import atomic_write_bytes, atomic_write_json, regular_input
from safetensors import SafetensorError
from safetensors.torch import load as _st_load
from safetensors.torch import save as _st_save

MODEL_FORMAT = "mepnet.model"
VERSION = 1
#: The safetensors header key holding mepnet's JSON document.
META_KEY = "mepnet"


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
    if not path.exists():
        raise CheckpointError(f"{path}: no such file")
    regular_input(path, "weights file", CheckpointError)
    try:
        data = path.read_bytes()
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
    write_safetensors(out / "model.safetensors", state_dict, {META_KEY: json.dumps(doc)})
    atomic_write_json(out / "model.json", doc)


def load_model_weights(
    path: str | os.PathLike[str],
) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Weights and model config (a dict) of a ``model.safetensors`` written by :func:`save_model`
    (its config comes from the file's header; ``model.json`` is a readable copy)."""
    path = Path(path)
    tensors, meta = read_safetensors(path)
    try:
        doc = json.loads(meta[META_KEY])
    except (KeyError, TypeError, json.JSONDecodeError):
        doc = None
    if (
        not isinstance(doc, dict)
        or doc.get("format") != MODEL_FORMAT
        or not isinstance(doc.get("model_config"), dict)
    ):
        raise CheckpointError(f"{path}: not a mepnet model file (no model config in its header)")
    return tensors, dict(doc["model_config"])


def load_model(
    path: str | os.PathLike[str], device: str | torch.device = "cpu"
) -> tuple[MEPNet | Direct3DNet, ModelConfig]:
    """A ready network (eval mode: :class:`mepnet.detector.net.MEPNet`, or
    :class:`~mepnet.detector.net.Direct3DNet` for weights trained with ``--head direct3d``) and
    its config from ``model.safetensors``."""
    tensors, cfg_dict = load_model_weights(path)
    try:
        cfg = ModelConfig.from_dict(cfg_dict)
    except (TypeError, ValueError, AttributeError) as e:
        raise CheckpointError(f"{path}: model config in the header is invalid ({e})") from None
    except RuntimeError as e:  # a size torch refuses although it passed the checks
        raise CheckpointError(f"{path}: model config in the header cannot be built ({e})") from None
    try:
        model = build_model(cfg)
    except RuntimeError as e:
        raise CheckpointError(f"{path}: model config in the header cannot be built ({e})") from None
    load_state_strict(model, tensors, path)
    return model.to(device).eval(), cfg


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
