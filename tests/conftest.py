"""Shared test helpers."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def generate_manuals(out: Path, manuals: int, seed: int, size: int = 256) -> Path:
    """Write synthetic manuals with the command-line tool (as a user would); returns ``out``."""
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "mepnet.synth",
            "--no-progress",
            "--out",
            str(out),
            "--manuals",
            str(manuals),
            "--seed",
            str(seed),
            "--size",
            str(size),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    return out
