"""mepnet.threads: inference's torch work on one thread, the caller's setting restored."""

from __future__ import annotations

import pytest
import torch
from mepnet.threads import one_thread


def test_one_thread_inside_and_the_callers_setting_after():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with one_thread():
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
        with pytest.raises(RuntimeError), one_thread():
            raise RuntimeError("inside")
        assert torch.get_num_threads() == 2  # restored after an error too
    finally:
        torch.set_num_threads(before)
