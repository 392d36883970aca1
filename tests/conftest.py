"""Shared test helpers."""

from __future__ import annotations

import contextlib
import subprocess
import sys
from collections.abc import Iterator
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


@contextlib.contextmanager
def plain_network() -> Iterator[None]:
    """The detector network without its shortcuts, the reference they must equal: every
    component slot encoded (batch norm over all of them) and the stem's first conv run on all
    its input channels at once (input gradients for all of them)."""
    import torch
    from mepnet.detector import net

    def components(self, vox, valid):  # type: ignore[no-untyped-def]
        b, k = vox.shape[:2]
        return self.convs(vox.flatten(0, 1)).mean(dim=(2, 3, 4)).view(b, k, -1) * valid[..., None]

    def stem(self, image, maps, state, planes):  # type: ignore[no-untyped-def]
        return self.stem[0](torch.cat([image, maps, state, planes], dim=1))

    saved = (net.ComponentEncoder.forward, net.Trunk._stem_in)
    net.ComponentEncoder.forward, net.Trunk._stem_in = components, stem  # type: ignore[method-assign]
    try:
        yield
    finally:
        net.ComponentEncoder.forward, net.Trunk._stem_in = saved  # type: ignore[method-assign]
