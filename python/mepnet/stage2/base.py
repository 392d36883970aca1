"""The stage-2 interface: a predictor gets a step's context -- what the page shows (image,
camera, parts callout), the shape built so far and the components -- and returns a pose for
every component the step adds. The context holds no answers: a manual stripped of them gives
the same plan. Oracles, which read the answers by definition, implement
:class:`AnswerReader` and are handed the step's answers separately by the loop that scores
them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from mepnet import _brickgeom as _bg
from mepnet.manual import ComponentRef, Step, StepTruth

#: How the ``mepnet`` predictor lifts detections to 3D: by ``synthesis`` from the type masks
#: (:mod:`mepnet.stage2.synthesis`) or by the paper's ``keypoint`` ray search.
LIFTS = ("synthesis", "keypoint")


@dataclass(frozen=True)
class StepContext:
    """Everything a predictor may use for one step: the page step, the base shape (the
    previous steps' result), the components (primitives and built submodules) and the
    manual's image size (W, H)."""

    step: Step
    base: _bg.Assembly
    components: dict[ComponentRef, _bg.Component]
    image_size: tuple[int, int]
    #: The build's earlier page steps, oldest first, each with the camera it was predicted with
    #: (given or estimated; None when there was none) and how many of the base's instances
    #: (in the order they were added) existed after it: their pictures show the base shape, or
    #: a part of it, as the manual's own renderer draws it.
    earlier: tuple[EarlierStep, ...] = ()
    #: CPU seconds the step's search may take (None: the predictor's own limit; stage 2 by
    #: synthesis: :data:`mepnet.stage2.synthesis.STEP_BUDGET_S`). The plan's second looks at a
    #: step (:data:`mepnet.plan.TIE_RETRY_BUDGET_S`) ask for less.
    budget_s: float | None = None

    @property
    def camera(self) -> _bg.Camera:
        """The step camera."""
        return self.step.camera_object()

    def colour(self, entry: int) -> int:
        """The colour the callout gives entry ``entry`` of the step."""
        return self.step.components[entry].colour


@dataclass(frozen=True)
class EarlierStep:
    """An earlier step of the build (:attr:`StepContext.earlier`)."""

    step: Step
    #: The base's first ``instances`` instances had been added after this step.
    instances: int


@dataclass
class Prediction:
    """A predicted instance: which callout entry of the step it belongs to, its component, and
    its pose or why there is none."""

    entry: int
    component: ComponentRef
    yaw: int | None
    t: tuple[int, int, int] | None
    attach: str | None = None
    failure: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def placed(self) -> bool:
        """Whether the prediction has a pose."""
        return self.t is not None and self.yaw is not None


class Predictor:
    """Base class: ``predict(ctx)`` returns one :class:`Prediction` per instance of the step."""

    name = "base"
    #: Per-component time-outs so far (predictors with a time limit count them).
    timeouts = 0

    def predict(self, ctx: StepContext) -> list[Prediction]:
        """Poses for every instance the step adds."""
        raise NotImplementedError


class AnswerReader(Predictor):
    """An oracle: it reads the step's answers (ground truth) to predict. Only scoring runs it,
    on manuals with answers; its name says that it is an oracle."""

    def predict(self, ctx: StepContext) -> list[Prediction]:
        from mepnet.errors import ManualFormatError

        raise ManualFormatError(
            f"{ctx.step.where}: predictor '{self.name}' is an oracle and needs the manual's answers"
        )

    def predict_with_answers(self, ctx: StepContext, truth: StepTruth) -> list[Prediction]:
        """Poses for every instance, given the step's answers."""
        raise NotImplementedError


def predict_step(
    predictor: Predictor, ctx: StepContext, truth: StepTruth | None
) -> tuple[list[Prediction], float]:
    """Run a predictor on a step (oracles are handed ``truth``; nothing else sees it) and
    measure its wall time."""
    t0 = time.perf_counter()
    if isinstance(predictor, AnswerReader):
        if truth is None:
            out = predictor.predict(ctx)  # raises: an oracle on a manual without answers
        else:
            out = predictor.predict_with_answers(ctx, truth)
    else:
        out = predictor.predict(ctx)
    return out, time.perf_counter() - t0
