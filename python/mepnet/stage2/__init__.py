"""Stage 2: from a step's page (and, for ``mepnet``, the detector's detections) to 3D poses.

Predictors behind one interface (:mod:`.base`) and a registry (:func:`make_predictor`):

- ``mepnet``: the detector, then stage 2 by synthesis or the keypoint lift (:mod:`.detector`);
- ``synthesis``: stage 2 by synthesis without a detector (:mod:`.synthesis`, the ablation);
- ``oracle`` / ``oracle-noisy`` / ``oracle-abys``: oracles fed the answers (:mod:`.baselines`);
- ``direct3d`` and ``abys`` (the paper's baselines) are not built yet and say so.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

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
    "abys",
    "direct3d",
)


def bundled_weights() -> Path:
    """Path of the shipped slim detector weights."""
    return Path(str(resources.files("mepnet") / "data" / "weights" / "slim.safetensors"))


def make_predictor(
    name: str,
    sigma: float = 1.0,
    seed: int = 0,
    time_limit_s: float = 60.0,
    weights: str | Path | None = None,
    lift: str = "synthesis",
) -> Predictor:
    """A predictor by name (``mepnet`` takes ``weights``, a ``model.safetensors``; default: the
    shipped slim weights)."""
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
    if name == "mepnet":
        from mepnet.detector.weights import load_model
        from mepnet.stage2.detector import MEPNetPredictor

        if lift not in LIFTS:
            raise ConfigError(f"unknown lift '{lift}' (choose from {', '.join(LIFTS)})")
        path = Path(weights or bundled_weights())
        if not path.exists():
            raise CheckpointError(f"{path}: detector weights not found")
        model, cfg = load_model(path)
        return MEPNetPredictor(model, cfg, lift=lift)
    if name in ("direct3d", "abys"):
        what = {"direct3d": "the Direct3D baseline", "abys": "a-by-s on the detector's masks"}
        raise ConfigError(
            f"predictor '{name}' ({what[name]}) is not part of this build yet "
            "(the ground-truth-mask variant is 'oracle-abys')"
        )
    raise ConfigError(f"unknown predictor '{name}' (choose from {', '.join(PREDICTORS)})")


__all__ = [
    "LIFTS",
    "PREDICTORS",
    "AnswerReader",
    "Prediction",
    "Predictor",
    "StepContext",
    "bundled_weights",
    "make_predictor",
    "predict_step",
]
