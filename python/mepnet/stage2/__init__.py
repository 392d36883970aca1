"""Stage 2: from a step's page (and, for ``mepnet``, the detector's detections) to 3D poses.

Predictors behind one interface (:mod:`.base`) and a registry (:func:`make_predictor`):

- ``mepnet``: the detector, then stage 2 by synthesis or the keypoint lift (:mod:`.detector`);
- ``synthesis``: stage 2 by synthesis without a detector (:mod:`.synthesis`, the ablation);
- ``oracle`` / ``oracle-noisy`` / ``oracle-abys``: oracles fed the answers (:mod:`.baselines`);
- ``oracle-translation`` / ``oracle-rotation``: the detector and the keypoint lift with the true
  positions or the true rotations swapped in (the supplementary's ablation, :mod:`.baselines`);
- ``abys``: analysis-by-synthesis on the detector's masks (:mod:`.abys`, the paper's Table 3);
- ``direct3d``: the paper's Direct3D baseline (:mod:`.direct3d`), from weights trained with
  ``python -m mepnet.train --head direct3d`` (``--weights``; default: the shipped ones,
  ``data/weights/direct3d.safetensors``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

from mepnet.errors import CheckpointError, ConfigError
from mepnet.stage2.base import (
    LIFTS,
    AnswerReader,
    Prediction,
    Predictor,
    StepContext,
    predict_step,
)

#: Every predictor name the commands accept.
PREDICTORS = (
    "mepnet",
    "synthesis",
    "oracle",
    "oracle-noisy",
    "oracle-abys",
    "oracle-translation",
    "oracle-rotation",
    "abys",
    "direct3d",
)


def bundled_weights() -> Path:
    """Path of the shipped slim detector weights."""
    return Path(str(resources.files("mepnet") / "data" / "weights" / "slim.safetensors"))


def bundled_direct3d_weights() -> Path:
    """The shipped Direct3D weights (``direct3d.json`` beside them: how they were trained)."""
    return Path(str(resources.files("mepnet") / "data" / "weights" / "direct3d.safetensors"))


def _load(path: Path, head: str, predictor: str) -> tuple[Any, Any]:
    """The network and config of ``path``, which must hold a ``head`` network (one line naming
    the file otherwise)."""
    from mepnet.detector.weights import load_model

    if not path.exists():
        raise CheckpointError(f"{path}: detector weights not found")
    model, cfg = load_model(path)
    if cfg.head != head:
        want = "--head direct3d" if head == "direct3d" else "the detector (--head mepnet)"
        raise CheckpointError(
            f"{path}: holds {cfg.head} weights; --predictor {predictor} needs weights of {want}"
        )
    return model, cfg


def make_predictor(
    name: str,
    sigma: float = 1.0,
    seed: int = 0,
    time_limit_s: float = 60.0,
    weights: str | Path | None = None,
    lift: str = "synthesis",
) -> Predictor:
    """A predictor by name (``mepnet`` and ``abys`` take ``weights``, a ``model.safetensors``;
    default: the shipped slim weights; ``direct3d`` takes Direct3D weights); ``time_limit_s``:
    seconds per component for ``abys`` and ``oracle-abys``."""
    if not time_limit_s > 0:
        raise ConfigError(f"the time limit must be > 0 seconds, got {time_limit_s}")
    if name == "oracle":
        from mepnet.stage2.baselines import OraclePredictor

        return OraclePredictor(0.0, seed)
    if name == "oracle-noisy":
        from mepnet.stage2.baselines import OraclePredictor

        if not sigma > 0:
            raise ConfigError(f"oracle-noisy needs --sigma > 0 pixels, got {sigma}")
        return OraclePredictor(sigma, seed)
    if name == "oracle-abys":
        from mepnet.stage2.baselines import OracleAbysPredictor

        return OracleAbysPredictor(time_limit_s)
    if name == "synthesis":
        from mepnet.stage2.synthesis import SynthesisPredictor

        return SynthesisPredictor(min(time_limit_s, 10.0))
    if name in ("oracle-translation", "oracle-rotation"):
        from mepnet.stage2.baselines import HalfOraclePredictor
        from mepnet.stage2.detector import MEPNetPredictor

        model, cfg = _load(Path(weights or bundled_weights()), "mepnet", name)
        return HalfOraclePredictor(MEPNetPredictor(model, cfg), name.split("-", 1)[1])
    if name in ("mepnet", "abys"):
        from mepnet.stage2.detector import MEPNetPredictor

        if lift not in LIFTS:
            raise ConfigError(f"unknown lift '{lift}' (choose from {', '.join(LIFTS)})")
        model, cfg = _load(Path(weights or bundled_weights()), "mepnet", name)
        detector = MEPNetPredictor(model, cfg, lift=lift)  # type: ignore[arg-type]
        if name == "mepnet":
            return detector
        from mepnet.stage2.abys import AbysPredictor

        return AbysPredictor(detector, time_limit_s)
    if name == "direct3d":
        from mepnet.stage2.direct3d import Direct3DPredictor

        path = Path(weights) if weights else bundled_direct3d_weights()
        if not weights and not path.exists():
            raise ConfigError(
                f"predictor 'direct3d': the shipped weights are missing ({path}); reinstall, "
                "or give --weights (python -m mepnet.train --head direct3d; docs/results.md)"
            )
        model, cfg = _load(path, "direct3d", name)
        return Direct3DPredictor(model, cfg)  # type: ignore[arg-type]
    raise ConfigError(f"unknown predictor '{name}' (choose from {', '.join(PREDICTORS)})")


__all__ = [
    "LIFTS",
    "PREDICTORS",
    "AnswerReader",
    "Prediction",
    "Predictor",
    "StepContext",
    "bundled_direct3d_weights",
    "bundled_weights",
    "make_predictor",
    "predict_step",
]
