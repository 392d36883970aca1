"""The one error family of mepnet's own bad-input errors.

Every error a user can cause with bad input is a :class:`MepnetError` (or the core's
:class:`mepnet.BrickGeomError`); its message names the input (file, manual, step) and the
problem in one line. The command-line runner (:mod:`mepnet.cli`) prints exactly that line and
exits 2. Errors that are bugs are left alone and keep their tracebacks.
"""

from __future__ import annotations


class MepnetError(ValueError):
    """Bad input: the message names the input and the problem."""


class InputError(MepnetError):
    """An input path that cannot be read as a file (missing, a folder, a FIFO or device)."""


class ManualFormatError(MepnetError):
    """A manual folder, ``manual.json`` or step image that does not follow the format."""


class CheckpointError(MepnetError):
    """A weights or checkpoint file that cannot be used."""


class ConfigError(MepnetError):
    """A model, training or generator setting that is out of range or unknown."""


class OutputError(MepnetError):
    """An output path that mepnet may not write (it holds something mepnet did not write)."""
