"""Reading the pictures of a manual: step images and instance maps, checked.

Whatever Pillow can open is read, in any mode: 16-bit greys are scaled to 8 bits (not clipped
to white), palettes and alpha are flattened onto the page. Images larger than
:data:`MAX_PIXELS` are refused before they are decoded, and a truncated or unreadable file is a
:class:`~mepnet.errors.ManualFormatError` naming it.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from mepnet.cli import note
from mepnet.errors import ManualFormatError
from mepnet.files import regular_input

#: The largest image mepnet reads (pixels): 8192 x 8192.
MAX_PIXELS = 8192 * 8192

_RESIZE_NOTED: set[Path] = set()


def _open(path: Path, what: str):  # type: ignore[no-untyped-def]
    from PIL import Image, UnidentifiedImageError

    regular_input(path, what, ManualFormatError)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            im = Image.open(path)
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        raise ManualFormatError(
            f"{path}: {what} is too large (more than {MAX_PIXELS:,} pixels)"
        ) from None
    except (UnidentifiedImageError, OSError, ValueError) as e:
        raise ManualFormatError(f"{path}: unreadable {what} ({e})") from None
    w, h = im.size
    if w * h > MAX_PIXELS:
        im.close()
        raise ManualFormatError(
            f"{path}: {what} is {w}x{h}, larger than mepnet reads ({MAX_PIXELS:,} pixels)"
        )
    return im


def _to_rgb(im) -> np.ndarray:  # type: ignore[no-untyped-def]
    """(H, W, 3) uint8 of an image in any Pillow mode."""
    from PIL import Image

    if im.mode in ("I;16", "I;16B", "I;16L", "I;16N", "I", "F"):
        a = np.asarray(im, dtype=np.float64)
        top = 65535.0 if im.mode.startswith("I;16") or a.max(initial=0) > 255 else 255.0
        g = np.clip(np.round(a / top * 255.0), 0, 255).astype(np.uint8)
        return np.repeat(g[:, :, None], 3, axis=2)
    if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
        rgba = im.convert("RGBA")
        page = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        return np.asarray(Image.alpha_composite(page, rgba).convert("RGB"))
    return np.asarray(im.convert("RGB"))


def read_step_image(path: Path, size: tuple[int, int] | None, where: str = "") -> np.ndarray:
    """The step image at ``path``, (H, W, 3) uint8, resized to ``size`` (W, H) when it differs
    (said once per manual on stderr)."""
    from PIL import Image

    what = f"step image ({where})" if where else "step image"
    im = _open(path, what)
    try:
        with im:
            rgb = _to_rgb(im)
    except (OSError, ValueError, SyntaxError) as e:
        raise ManualFormatError(f"{path}: unreadable {what} ({e})") from None
    if size is not None and (rgb.shape[1], rgb.shape[0]) != tuple(size):
        if path.parent not in _RESIZE_NOTED:
            _RESIZE_NOTED.add(path.parent)
            note(
                f"{path}: image is {rgb.shape[1]}x{rgb.shape[0]}, the manual says "
                f"{size[0]}x{size[1]}; resized (and so are the other step images of this "
                "manual that differ)"
            )
        rgb = np.asarray(
            Image.fromarray(rgb).resize(tuple(size), Image.Resampling.BILINEAR)  # type: ignore[arg-type]
        )
    return rgb


def read_instance_map(path: Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """An instance map (16-bit PNG: instance id + 1, 0 on the background) as (H, W) int32 with
    -1 on the background; it must have the manual's image size."""
    im = _open(path, "instance map")
    try:
        with im:
            ids = np.asarray(im, dtype=np.int32) - 1
    except (OSError, ValueError, SyntaxError) as e:
        raise ManualFormatError(f"{path}: unreadable instance map ({e})") from None
    if ids.ndim != 2:
        raise ManualFormatError(f"{path}: an instance map must be a one-channel image")
    if size is not None and (ids.shape[1], ids.shape[0]) != tuple(size):
        raise ManualFormatError(
            f"{path}: instance map is {ids.shape[1]}x{ids.shape[0]}, the manual's images are "
            f"{size[0]}x{size[1]}"
        )
    return ids
