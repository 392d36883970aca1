"""The answers of a manual: what training and scoring compare against, and no predictor reads
(DESIGN §5). Per build, the placed instances (component, pose, colour) and per step which
instances it adds (per callout entry), how each appears in the step image (keypoints, box,
visible fraction, attach kind) and the step's instance map; per submodule, its bricks in its
own frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.geom import submodule_from_placed
from mepnet.manual.images import read_instance_map
from mepnet.manual.page import ComponentRef, Manual


@dataclass(frozen=True)
class Instance:
    """A placed component: its pose on the lattice and LDraw colour."""

    id: int
    component: ComponentRef
    yaw: int
    t: tuple[int, int, int]
    colour: int = 16


@dataclass(frozen=True)
class InstanceView:
    """How a new instance appears in its step image."""

    id: int
    attach: str
    keypoints: list[tuple[float, float]]
    box: tuple[int, int, int, int] | None
    visible_fraction: float

    @property
    def keypoint(self) -> tuple[float, float]:
        """The keypoint (the first topmost brick's, for a submodule)."""
        return self.keypoints[0]


@dataclass
class StepAnswers:
    """The answers of one step: per callout entry the instances it adds (same order as the
    page's ``components``), their views, and the instance map."""

    instances_of: list[list[int]]
    views: list[InstanceView]
    ids_path: Path | None
    size: tuple[int, int]

    def ids(self) -> np.ndarray:
        """The instance map, (H, W) int32: instance id, -1 on the background."""
        if self.ids_path is None:
            raise ValueError("this manual has no instance maps")
        return read_instance_map(self.ids_path, self.size)

    @property
    def instance_ids(self) -> list[int]:
        """Ids of the instances this step adds."""
        return [v.id for v in self.views]

    def view(self, iid: int) -> InstanceView:
        """The view of instance ``iid``."""
        return next(v for v in self.views if v.id == iid)


@dataclass
class StepTruth:
    """The answers of one step with the build's instances at hand (what training targets,
    oracles and scoring read)."""

    answers: StepAnswers
    instances: list[Instance]

    def ids(self) -> np.ndarray:
        """The instance map (see :meth:`StepAnswers.ids`)."""
        return self.answers.ids()

    @property
    def instances_of(self) -> list[list[int]]:
        """Per callout entry, the ids of the instances it adds."""
        return self.answers.instances_of

    def keypoint(self, iid: int) -> tuple[float, float]:
        """Instance ``iid``'s keypoint in the step image (pixels)."""
        return self.answers.view(iid).keypoint

    def placed(self) -> list[Instance]:
        """The instances the step adds, in view order."""
        return [self.instances[v.id] for v in self.answers.views]


@dataclass
class BuildAnswers:
    """The answers of one build (main model or submodule)."""

    instances: list[Instance]
    steps: list[StepAnswers]

    def truth(self, k: int) -> StepTruth:
        """The answers of step ``k`` (0-based)."""
        return StepTruth(self.steps[k], self.instances)

    def assembly_before(
        self, k: int, components: dict[ComponentRef, _bg.Component]
    ) -> _bg.Assembly:
        """The true base shape of step ``k`` (0-based): everything added before it."""
        asm = _bg.Assembly()
        for s in self.steps[:k]:
            for v in s.views:
                inst = self.instances[v.id]
                asm.add(components[inst.component], inst.yaw, inst.t, inst.colour)
        return asm


@dataclass
class SubmoduleShape:
    """A submodule's true shape: its bricks in its own frame (part, yaw, t, colour)."""

    name: str
    symmetry: int
    topmost: list[int]
    bricks: list[tuple[str, int, tuple[int, int, int], int]]

    def component(self) -> _bg.Component:
        """The submodule as a :class:`mepnet.Component`."""
        return submodule_from_placed(
            self.name, [(_bg.Component.primitive(p), y, t, c) for p, y, t, c in self.bricks]
        )


@dataclass
class Answers:
    """All answers of a manual."""

    main: BuildAnswers
    submodules: list[BuildAnswers]
    shapes: list[SubmoduleShape]

    def build(self, k: int | None) -> BuildAnswers:
        """The answers of submodule ``k``'s build, or of the main build (None)."""
        return self.main if k is None else self.submodules[k]

    def components(self, manual: Manual) -> dict[ComponentRef, _bg.Component]:
        """Every component of the manual with its true shape (submodules from their bricks)."""
        out = dict(manual.primitive_components())
        for k, shape in enumerate(self.shapes):
            out[ComponentRef(submodule=k)] = shape.component()
        for b in [self.main, *self.submodules]:
            for inst in b.instances:
                if inst.component.part is not None and inst.component not in out:
                    out[inst.component] = _bg.Component.primitive(inst.component.part)
        return out


def answers_of(manual: Manual) -> Answers:
    """The manual's answers; a clear error when it has none (a manual as users have it)."""
    if manual.answers is None:
        from mepnet.errors import ManualFormatError

        raise ManualFormatError(
            f"{manual.path}: the manual has no answers (poses) to score against"
        )
    return manual.answers  # type: ignore[no-any-return]


def instance_json(x: Instance) -> dict[str, Any]:
    """An instance as written in ``manual.json``."""
    return {
        "component": x.component.to_json(),
        "yaw": x.yaw,
        "t": list(x.t),
        "colour": x.colour,
    }
