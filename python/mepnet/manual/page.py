"""What a manual page shows: the step images, per step its components (part id and colour, as
the parts callout draws them, or a submodule reference) with counts, the submodules' own steps,
and optionally cameras. This is all a predictor may read (DESIGN §5); the answers (poses,
keypoints, instance maps, attach kinds) live apart in :mod:`mepnet.manual.answers`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.manual.images import read_step_image

#: LDraw's main colour ("the colour of the referencing line"): what a submodule is drawn in.
MAIN_COLOUR = 16
#: The camera keys of a step (weak perspective, DESIGN §4).
CAMERA_KEYS = ("elevation", "azimuth", "roll", "scale", "translation")


@dataclass(frozen=True)
class ComponentRef:
    """A library part or a submodule of the same manual (index into ``Manual.submodules``)."""

    part: str | None = None
    submodule: int | None = None

    def to_json(self) -> dict[str, Any]:
        """``{"part": id}`` or ``{"submodule": k}``."""
        return {"part": self.part} if self.part is not None else {"submodule": self.submodule}

    def __str__(self) -> str:
        return self.part if self.part is not None else f"submodule {self.submodule}"


@dataclass(frozen=True)
class StepComponent:
    """One entry of a step's parts callout: a component type, its colour (LDraw code; for a
    submodule :data:`MAIN_COLOUR`, its bricks keep their own) and how many the step adds."""

    component: ComponentRef
    count: int
    colour: int = MAIN_COLOUR

    def to_json(self) -> dict[str, Any]:
        """The callout entry as written in ``manual.json``."""
        if self.component.part is not None:
            return {"part": self.component.part, "colour": self.colour, "count": self.count}
        return {"submodule": self.component.submodule, "count": self.count}


def make_camera(camera: dict[str, Any]) -> _bg.Camera:
    """The brickgeom camera of a step camera dict (keys :data:`CAMERA_KEYS`)."""
    return _bg.Camera(
        camera["elevation"],
        camera["azimuth"],
        camera["roll"],
        camera["scale"],
        tuple(camera["translation"]),
    )


@dataclass
class Step:
    """A manual step as the page shows it: its image, camera (None when the manual does not
    state it) and parts callout."""

    index: int
    image_path: Path
    camera: dict[str, Any] | None
    components: list[StepComponent]
    #: The manual's image size (W, H); an image of another size is resized to it.
    size: tuple[int, int]
    #: Where the step is, for messages: "MANUAL step N" or "MANUAL submodule NAME step N".
    where: str = ""

    def image(self) -> np.ndarray:
        """The step image, (H, W, 3) uint8, at the manual's image size."""
        return read_step_image(self.image_path, self.size, self.where)

    def camera_object(self) -> _bg.Camera:
        """The step camera as a :class:`mepnet.Camera`."""
        if self.camera is None:
            from mepnet.errors import ManualFormatError

            raise ManualFormatError(
                f"{self.where}: the manual states no camera for this step, and mepnet cannot "
                "estimate cameras yet"
            )
        return make_camera(self.camera)

    @property
    def n_instances(self) -> int:
        """How many components the step adds."""
        return sum(c.count for c in self.components)


@dataclass
class Build:
    """The steps that build one shape: the main model or a submodule."""

    name: str
    steps: list[Step]


@dataclass
class Manual:
    """A whole manual: the main build and the submodules' builds, provenance, and the answers
    when the manual has them (synthetic and converted manuals; never a manual in the wild)."""

    path: Path
    source: dict[str, Any]
    image_size: tuple[int, int]
    parts: list[str]
    main: Build
    submodules: list[Build] = field(default_factory=list)
    #: The answers (:class:`mepnet.manual.answers.Answers`), or None.
    answers: Any = None

    def builds(self) -> list[tuple[int | None, Build]]:
        """Every build in build order: the submodules (index k), then the main model (None)."""
        return [*enumerate(self.submodules), (None, self.main)]

    def all_steps(self) -> list[Step]:
        """Every step: the main build's, then each submodule build's."""
        return [st for b in [self.main, *self.submodules] for st in b.steps]

    def primitive_components(self) -> dict[ComponentRef, _bg.Component]:
        """The library parts the manual's callouts name, as components."""
        out: dict[ComponentRef, _bg.Component] = {}
        for st in self.all_steps():
            for c in st.components:
                if c.component.part is not None and c.component not in out:
                    out[c.component] = _bg.Component.primitive(c.component.part)
        return out
