"""The manual format: what a manual page shows (:mod:`.page`), the answers kept apart
(:mod:`.answers`), reading, checking and writing folders (:mod:`.io`), and
``python -m mepnet.manual strip`` (:mod:`.cli`)."""

from mepnet.errors import ManualFormatError
from mepnet.manual.answers import (
    Answers,
    BuildAnswers,
    Instance,
    InstanceView,
    StepAnswers,
    StepTruth,
    SubmoduleShape,
    answers_of,
)
from mepnet.manual.io import (
    generated_manual,
    iter_manual_dirs,
    load_manual,
    manual_json,
    strip_manual,
    write_manual,
)
from mepnet.manual.page import (
    MAIN_COLOUR,
    Build,
    ComponentRef,
    Manual,
    Step,
    StepComponent,
    make_camera,
)

__all__ = [
    "MAIN_COLOUR",
    "Answers",
    "Build",
    "BuildAnswers",
    "ComponentRef",
    "Instance",
    "InstanceView",
    "Manual",
    "ManualFormatError",
    "Step",
    "StepAnswers",
    "StepComponent",
    "StepTruth",
    "SubmoduleShape",
    "answers_of",
    "generated_manual",
    "iter_manual_dirs",
    "load_manual",
    "make_camera",
    "manual_json",
    "strip_manual",
    "write_manual",
]
