"""Atomic outputs: every file and folder mepnet writes appears whole or not at all, with the
permissions the user's umask asks for, and never replaces anything mepnet did not write.

- :func:`atomic_write_bytes` / :func:`atomic_write_text` / :func:`atomic_write_json`: a
  temporary sibling, fsynced, renamed over the target.
- :func:`atomic_folder`: a context manager giving a temporary sibling folder that is renamed to
  the target on success. The folder carries a manifest (:data:`MANIFEST`) of what mepnet wrote;
  an existing target is replaced only when it is a folder mepnet wrote whose files are all in
  its manifest (or an empty folder), so nobody's thesis is deleted by ``--out``.
- Temporary names carry the writing process id: leftovers of a killed run (SIGKILL) are
  removed by the next run into the same place, never those of a run still going.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mepnet.errors import OutputError

#: The manifest file mepnet writes into every output folder.
MANIFEST = ".mepnet-output.json"
_TMP = ".tmp-"


def umask() -> int:
    """The process umask (read without changing it for long)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _tmp_prefix(name: str) -> str:
    return f"{_TMP}{name}-{os.getpid()}-"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_temporaries(parent: Path, name: str | None = None) -> int:
    """Remove temporary siblings (``.tmp-NAME-PID-*``; any NAME when ``name`` is None) left in
    ``parent`` by mepnet processes that no longer run; returns how many were removed."""
    removed = 0
    if not parent.is_dir():
        return 0
    pattern = f"{_TMP}{name}-*" if name is not None else f"{_TMP}*"
    for p in parent.glob(pattern):
        rest = p.name[len(_TMP) :]
        if name is not None:
            rest = rest[len(name) + 1 :]
        else:
            # NAME may contain dashes: the pid is the second-to-last dash-separated field
            parts = rest.rsplit("-", 2)
            rest = "-".join(parts[-2:]) if len(parts) >= 3 else ""
        pid_text = rest.split("-", 1)[0]
        if not pid_text.isdigit() or _pid_alive(int(pid_text)):
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        removed += 1
    return removed


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to a temporary sibling of ``path``, fsync it, rename it over ``path``.
    ``path`` must not be a folder."""
    path = Path(path)
    check_output_file(path)
    fd, tmp = tempfile.mkstemp(prefix=_tmp_prefix(path.name), dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), 0o666 & ~umask())  # mkstemp makes 0600: be a normal file
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def check_output_file(path: str | os.PathLike[str]) -> None:
    """Refuse, before any work starts, an output file path that cannot be written: a folder,
    or a file in a folder that does not exist."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, not a file")
    if not path.parent.is_dir():
        raise OutputError(f"{path}: folder {path.parent} does not exist")
    if not os.access(path.parent, os.W_OK):
        raise OutputError(f"{path}: folder {path.parent} is not writable")


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """:func:`atomic_write_bytes` of UTF-8 text."""
    atomic_write_bytes(path, text.encode())


def format_json(doc: Any, indent: int = 0) -> str:
    """JSON with one key per line, but lists of scalars on one line: readable and diffable
    without thousands of short lines."""
    pad = " " * (indent + 1)
    if isinstance(doc, dict) and doc:
        items = [f"{pad}{json.dumps(str(k))}: {format_json(v, indent + 1)}" for k, v in doc.items()]
        return "{\n" + ",\n".join(items) + "\n" + " " * indent + "}"
    if isinstance(doc, (list, tuple)) and any(isinstance(v, (dict, list, tuple)) for v in doc):
        items = [pad + format_json(v, indent + 1) for v in doc]
        return "[\n" + ",\n".join(items) + "\n" + " " * indent + "]"
    return json.dumps(doc)


def atomic_write_json(path: str | os.PathLike[str], doc: Any) -> None:
    """Write a JSON document atomically (:func:`format_json`, trailing newline)."""
    atomic_write_text(path, format_json(doc) + "\n")


def _listing(folder: Path) -> list[str]:
    return sorted(
        str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file() or p.is_symlink()
    )


def check_replaceable(out: Path, writer: str) -> None:
    """Raise :class:`OutputError` unless ``out`` is absent, an empty folder, or a folder that
    ``writer`` wrote and nobody added to since."""
    if not out.exists() and not out.is_symlink():
        return
    if out.is_symlink() or not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder mepnet wrote (choose a new --out)")
    if not any(out.iterdir()):
        return
    try:
        manifest = json.loads((out / MANIFEST).read_text())
        ours = set(manifest["files"])
        by = manifest["writer"]
    except (OSError, ValueError, KeyError, TypeError):
        raise OutputError(
            f"{out}: exists and was not written by mepnet (choose a new --out; nothing was changed)"
        ) from None
    if by != writer:
        raise OutputError(
            f"{out}: was written by {by}, not {writer} (choose a new --out; nothing was changed)"
        )
    extra = [f for f in _listing(out) if f != MANIFEST and f not in ours]
    if extra:
        more = f" and {len(extra) - 1} more" if len(extra) > 1 else ""
        raise OutputError(
            f"{out}: holds {extra[0]}{more}, which mepnet did not write (choose a new --out; "
            "nothing was changed)"
        )


@contextlib.contextmanager
def atomic_folder(out: str | os.PathLike[str], writer: str, replace: bool = True) -> Iterator[Path]:
    """Write a folder atomically: yields a temporary sibling folder to fill; on success it is
    renamed to ``out`` with a manifest of its files (written by ``writer``, e.g.
    ``mepnet.infer``). An existing ``out`` is replaced only when ``replace`` and
    :func:`check_replaceable` allow; checked before any work starts and again at the end.
    On any error (or Ctrl-C) the temporary folder is removed and ``out`` is untouched."""
    out = Path(out)
    if out.exists() and not replace:
        raise OutputError(f"{out}: already exists (choose a new folder)")
    check_replaceable(out, writer)
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(out.parent, out.name)
    tmp = Path(tempfile.mkdtemp(prefix=_tmp_prefix(out.name), dir=out.parent))
    old: Path | None = None
    try:
        os.chmod(tmp, 0o777 & ~umask())  # mkdtemp makes 0700: be a normal folder
        yield tmp
        files = [f for f in _listing(tmp) if f != MANIFEST]
        (tmp / MANIFEST).write_text(json.dumps({"writer": writer, "files": files}, indent=1))
        os.chmod(tmp / MANIFEST, 0o666 & ~umask())
        if out.exists():
            check_replaceable(out, writer)
            old = Path(tempfile.mkdtemp(prefix=_tmp_prefix(out.name), dir=out.parent))
            os.replace(out, old / "old")
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if old is not None and (old / "old").exists() and not out.exists():
            os.replace(old / "old", out)  # put back what was there
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
