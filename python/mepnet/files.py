"""Atomic outputs: every file and folder mepnet writes appears whole or not at all, with the
permissions the user's umask asks for, and never replaces anything mepnet did not write.

- :func:`atomic_write_bytes` / :func:`atomic_write_text` / :func:`atomic_write_json`: a
  temporary sibling, fsynced, renamed over the target (never over a device, pipe or symlink).
- :func:`check_output_file`: an output file named on the command line may replace only a file
  the same command wrote (marked ``"written_by"``).
- :func:`atomic_folder`: a context manager giving a temporary sibling folder that is renamed to
  the target on success. The folder carries a manifest (:data:`MANIFEST`) of what mepnet wrote,
  with a checksum per file; an existing target is replaced only when it is a folder the same
  command wrote and nobody added, removed or changed a file or folder in since (or an empty
  folder), so nobody's thesis is deleted by ``--out``.
- :func:`regular_input`: an input path must be a regular file (a FIFO would block forever).
- Temporary names are ``.tmp-mepnet-NAME-PID-RANDOM``: leftovers of a killed run (SIGKILL) are
  removed by the next run into the same place, never those of a run still going.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mepnet.errors import InputError, MepnetError, OutputError

#: The manifest file mepnet writes into every output folder.
MANIFEST = ".mepnet-output.json"
_TMP = ".tmp-mepnet-"


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
    except OverflowError:
        return False
    return True


def remove_stale_temporaries(parent: Path, name: str | None = None) -> int:
    """Remove temporary siblings (``.tmp-mepnet-NAME-PID-RANDOM``; any NAME when ``name`` is
    None) left in ``parent`` by mepnet processes that no longer run; returns how many."""
    removed = 0
    if not parent.is_dir():
        return 0
    for p in parent.glob(f"{_TMP}*"):
        rest = p.name[len(_TMP) :]
        parts = rest.rsplit("-", 2)  # NAME may hold dashes; PID and RANDOM never do
        if len(parts) != 3 or not parts[1].isdigit():
            continue
        if name is not None and parts[0] != name:
            continue
        if _pid_alive(int(parts[1])):
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        removed += 1
    return removed


def regular_input(
    path: str | os.PathLike[str], what: str = "input file", error: type[MepnetError] = InputError
) -> Path:
    """``path`` if it is a regular file (a symlink to one is fine); otherwise ``error`` (the
    caller's kind of bad input) naming it: a FIFO or device would block or never end."""
    path = Path(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise error(f"{path}: no such {what}") from None
    except OSError as e:
        raise error(f"{path}: cannot read the {what} ({e.strerror or e})") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{path}: is a folder, not a {what}")
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{path}: not a regular file (a pipe or device cannot be a {what})")
    return path


def _check_target_file(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        raise OutputError(f"{path}: is a folder, not a file")
    if not path.parent.is_dir():
        raise OutputError(f"{path}: folder {path.parent} does not exist")
    if path.is_symlink() or (path.exists() and not stat.S_ISREG(path.lstat().st_mode)):
        raise OutputError(f"{path}: exists and is not a regular file (choose a new file)")


def check_output_file(path: str | os.PathLike[str], writer: str | None = None) -> None:
    """Refuse, before any work starts, an output file path that cannot or may not be written:
    a folder, a file in a folder that does not exist or is not writable, anything that is not
    a regular file (a device, a pipe, a symlink: replacing it would destroy it), or, with
    ``writer``, an existing file that is not a JSON document ``writer`` wrote
    (``"written_by": writer``)."""
    path = Path(path)
    _check_target_file(path)
    if not os.access(path.parent, os.W_OK):
        raise OutputError(f"{path}: folder {path.parent} is not writable")
    if writer is None or not path.exists():
        return
    try:
        ours = json.loads(path.read_bytes()).get("written_by") == writer
    except (OSError, ValueError, AttributeError):
        ours = False
    if not ours:
        raise OutputError(
            f"{path}: exists and was not written by {writer} (choose a new file; nothing was "
            "changed)"
        )


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to a temporary sibling of ``path``, fsync it, rename it over ``path``
    (which must be absent or a regular file)."""
    path = Path(path)
    _check_target_file(path)
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


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _contents(folder: Path) -> tuple[dict[str, str], set[str]]:
    """Files (relative path -> sha256; a symlink counts as a foreign file) and folders."""
    files: dict[str, str] = {}
    dirs: set[str] = set()
    for p in folder.rglob("*"):
        rel = p.relative_to(folder).as_posix()
        if p.is_symlink() or not (p.is_file() or p.is_dir()):
            files[rel] = "not a regular file"
        elif p.is_dir():
            dirs.add(rel)
        else:
            files[rel] = _digest(p)
    files.pop(MANIFEST, None)
    return files, dirs


def check_replaceable(out: Path, writer: str) -> None:
    """Raise :class:`OutputError` unless ``out`` is absent, an empty folder, or a folder that
    ``writer`` wrote and nobody added, removed or changed anything in since."""
    if not out.exists() and not out.is_symlink():
        return
    if out.is_symlink() or not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder mepnet wrote (choose a new --out)")
    if not any(out.iterdir()):
        return
    try:
        manifest = json.loads((out / MANIFEST).read_text())
        ours = dict(manifest["files"])
        by = manifest["writer"]
    except (OSError, ValueError, KeyError, TypeError):
        raise OutputError(
            f"{out}: exists and was not written by mepnet (choose a new --out; nothing was changed)"
        ) from None
    if by != writer:
        raise OutputError(
            f"{out}: was written by {by}, not {writer} (choose a new --out; nothing was changed)"
        )
    files, dirs = _contents(out)
    our_dirs = {Path(f).parent.as_posix() for f in ours} - {"."}
    our_dirs |= {p.as_posix() for d in list(our_dirs) for p in Path(d).parents if str(p) != "."}
    extra = sorted(set(files) - set(ours)) + sorted(dirs - our_dirs)
    if extra:
        more = f" and {len(extra) - 1} more" if len(extra) > 1 else ""
        raise OutputError(
            f"{out}: holds {extra[0]}{more}, which mepnet did not write (choose a new --out; "
            "nothing was changed)"
        )
    changed = sorted(f for f, digest in ours.items() if files.get(f, digest) != digest)
    if changed:
        raise OutputError(
            f"{out}: {changed[0]} was changed since mepnet wrote it (choose a new --out; nothing "
            "was changed)"
        )


@contextlib.contextmanager
def atomic_folder(out: str | os.PathLike[str], writer: str, replace: bool = True) -> Iterator[Path]:
    """Write a folder atomically: yields a temporary sibling folder to fill; on success it is
    renamed to ``out`` with a manifest of its files (written by ``writer``, e.g.
    ``mepnet.infer``). With ``replace``, an existing ``out`` is replaced only when
    :func:`check_replaceable` allows, checked before any work starts and again at the end;
    without it, ``out`` must not exist, then or at the end (another run may have written it
    meanwhile: :class:`OutputError`). On any error (or Ctrl-C) the temporary folder is removed
    and ``out`` is untouched."""
    out = Path(out)
    if not replace and (out.exists() or out.is_symlink()):
        raise OutputError(f"{out}: already exists (choose a new folder)")
    check_replaceable(out, writer)
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(out.parent, out.name)
    tmp = Path(tempfile.mkdtemp(prefix=_tmp_prefix(out.name), dir=out.parent))
    old: Path | None = None
    try:
        os.chmod(tmp, 0o777 & ~umask())  # mkdtemp makes 0700: be a normal folder
        yield tmp
        files, _ = _contents(tmp)
        (tmp / MANIFEST).write_text(json.dumps({"writer": writer, "files": files}, indent=1))
        os.chmod(tmp / MANIFEST, 0o666 & ~umask())
        if out.exists() or out.is_symlink():
            if not replace:
                raise OutputError(
                    f"{out}: appeared while mepnet was writing it (nothing was changed)"
                )
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
