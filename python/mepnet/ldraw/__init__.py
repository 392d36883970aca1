"""LDraw: reading and writing .ldr / .mpd files (:mod:`.io`), converting real models into
manuals (:mod:`.convert`) and ``python -m mepnet.ldraw`` (:mod:`.cli`)."""

from mepnet.ldraw import io as _io
from mepnet.ldraw.cli import main
from mepnet.ldraw.io import *  # noqa: F403 (the public LDraw API, listed in io.__all__)

__all__ = [*_io.__all__, "main"]
