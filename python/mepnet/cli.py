"""The one command-line runner: every ``python -m mepnet.*`` command runs its work through
:func:`run`, so bad input ends the same way everywhere -- one line naming the input and the
problem on stderr, exit 2, no traceback -- and Ctrl-C ends with one line and exit 130."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from collections.abc import Callable, Iterator
from typing import NoReturn

from mepnet.errors import MepnetError
from mepnet.geom import BrickGeomError

#: Exit status of a command stopped by bad input.
BAD_INPUT = 2
OUT_OF_MEMORY = "out of memory (the input or the settings ask for more than this machine has)"
#: Exit status of a command stopped by Ctrl-C (128 + SIGINT).
INTERRUPTED = 130


class ArgumentParser(argparse.ArgumentParser):
    """argparse with the one-line contract: a usage mistake is ``PROG: error: MESSAGE (see
    --help)`` on stderr and exit 2, without the usage block (``--help`` still shows it)."""

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message} (see --help)", file=sys.stderr)
        raise SystemExit(BAD_INPUT)


#: Notes of the command running (None outside :func:`run`): said at the end of a successful
#: run, so that a run stopped by bad input or Ctrl-C ends with exactly one line.
_NOTES: list[str] | None = None


def note(message: str) -> None:
    """Tell the user something worth knowing about a run that goes on (an image resized, a
    setting capped): on stderr when the command succeeds."""
    if _NOTES is None:
        print(f"mepnet: {message}", file=sys.stderr)
    elif message not in _NOTES:
        _NOTES.append(message)


def fail(prog: str, message: str) -> int:
    """Print ``prog: error: message`` on stderr; returns :data:`BAD_INPUT`."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    return BAD_INPUT


def one_line(message: str) -> str:
    """An error message as one line: an error re-raised from a worker process (torch's
    DataLoader wraps it with the worker's traceback) keeps only its own message."""
    if "Traceback (most recent call last)" in message:
        last = message.strip().splitlines()[-1]
        return last.split(": ", 1)[-1] if ": " in last else last
    return " ".join(message.split("\n"))


def os_error_message(e: OSError) -> str:
    """One line for an OS error: the file it concerns and what went wrong."""
    name = e.filename if e.filename is not None else ""
    text = e.strerror or str(e)
    return f"{name}: {text}" if name else f"{text} (writing the output)"


def run(prog: str, work: Callable[[], int]) -> int:
    """Run ``work`` (a command's body) and map its bad-input errors to exit statuses."""
    global _NOTES
    for stream in (sys.stdout, sys.stderr):
        # file names need not be UTF-8: print them escaped rather than fail on them
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    _NOTES = []
    try:
        status = int(work())
        for message in _NOTES:
            print(f"{prog}: note: {message}", file=sys.stderr)
        return status
    except BrokenPipeError:  # `... | head`: the reader has what it wanted
        with contextlib.suppress(OSError):
            sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (no flush error at exit)
        return 141
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return INTERRUPTED
    except (MepnetError, BrickGeomError) as e:
        return fail(prog, one_line(str(e)))
    except RecursionError:
        return fail(prog, "input nested too deeply")
    except MemoryError:
        return fail(
            prog, "out of memory (the input or the settings ask for more than this machine has)"
        )
    except OSError as e:
        return fail(prog, os_error_message(e))
    finally:
        _NOTES = None


@contextlib.contextmanager
def workers_ignore_interrupts() -> Iterator[None]:
    """Start worker processes inside this block: they begin with Ctrl-C ignored (a spawned
    interpreter keeps an ignored SIGINT), so only the main process reacts to it, with one line,
    instead of every worker printing a traceback while it is still starting up."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def quiet_interrupts_in_workers() -> None:
    """For worker processes (data loaders, pools): ignore Ctrl-C, which the main process
    handles, so a terminal does not fill with one traceback per worker."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
