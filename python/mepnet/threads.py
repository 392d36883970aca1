"""torch's thread pool for inference: one thread.

Inference runs small tensors through torch (a step's network input, the camera sweep's FFTs).
On a 2-core CPU torch's intra-op pool of two threads gains little when the machine is idle and
loses a lot when another process holds a core, as the pool's threads then wait on each other.
Measured interleaved, call by call (``docs/cameras.md``, *At stop 52*: the shipped detector's
network on one synthetic manual, 13 steps): idle 79 ms a step on one thread, 72 on the pool; with a
core busy elsewhere 72 against 163. A camera sweep's FFT correlation: 5.2 ms against 3.3 idle,
7 against 120 under load. Training keeps its own setting (``--threads``); the caller's setting
is restored.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["one_thread"]


@contextmanager
def one_thread() -> Iterator[None]:
    """Run the block with torch on one intra-op thread, then restore the caller's count."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)
