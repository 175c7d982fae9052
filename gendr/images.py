"""Images: 8-bit PNG files (written and read with Pillow) and contact sheets (numpy).

* :func:`write_png` writes grayscale, gray+alpha, RGB or RGBA images atomically.
* :func:`read_png` reads a PNG (or any image Pillow reads) as uint8 ``[H, W, C]``.
* :func:`contact_sheet` tiles many images into one RGBA grid.

Pillow is imported when a file is written or read: it comes with the ``images`` extra
(``pip install gendr[images]``; the validation and experiments extras bring it too), so that
``import gendr`` needs numpy only.

>>> import numpy as np, tempfile, os
>>> img = np.zeros((4, 6, 4)); img[..., 3] = 1.0
>>> path = os.path.join(tempfile.mkdtemp(), "x.png")
>>> _ = write_png(path, img)
>>> read_png(path).shape
(4, 6, 4)
"""
from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

import numpy as np

from .errors import BackendUnavailableError, DTypeError, InputValueError, ParameterError, ShapeError

__all__ = ["write_png", "read_png", "contact_sheet", "to_uint8", "require_pillow"]

#: channels -> Pillow mode
_MODES = {1: "L", 2: "LA", 3: "RGB", 4: "RGBA"}


def require_pillow(what: str):
    """``PIL.Image``, or :class:`~gendr.errors.BackendUnavailableError` saying that ``what`` needs Pillow."""
    try:
        from PIL import Image
    except ImportError as e:
        raise BackendUnavailableError(f"{what} needs Pillow: pip install gendr[images] (or pillow) ({e})") from None
    return Image


def _as_numpy(image) -> np.ndarray:
    if hasattr(image, "detach") and hasattr(image, "cpu"):  # a torch tensor, without importing torch
        image = image.detach().cpu().numpy()
    return np.asarray(image)


def to_uint8(image) -> np.ndarray:
    """Convert an image to uint8 ``[H, W, C]`` (C in 1..4).

    Accepts ``[H, W]``, ``[H, W, 1]``, ``[H, W, 2]`` (gray+alpha), ``[H, W, 3]`` or ``[H, W, 4]``;
    uint8 is kept, bool maps to 0/255, floats are clipped to [0, 1] and scaled by 255 (NaN -> 0).
    Raises :class:`~gendr.errors.ShapeError` / :class:`~gendr.errors.DTypeError`.
    """
    a = _as_numpy(image)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in _MODES:
        raise ShapeError(f"image must have shape [H, W], [H, W, 1], [H, W, 2], [H, W, 3] or [H, W, 4], "
                         f"got {tuple(a.shape)}")
    if a.shape[0] < 1 or a.shape[1] < 1:
        raise ShapeError(f"image must be at least 1x1 pixels, got shape {tuple(a.shape)}")
    if a.dtype == np.uint8:
        return np.ascontiguousarray(a)
    if a.dtype == np.bool_:
        return a.astype(np.uint8) * 255
    if np.issubdtype(a.dtype, np.floating):
        a = np.nan_to_num(a.astype(np.float64), nan=0.0, posinf=1.0, neginf=0.0)
        return np.round(np.clip(a, 0.0, 1.0) * 255.0).astype(np.uint8)
    raise DTypeError(f"image dtype must be uint8, bool or floating point, got {a.dtype}")


def write_png(path, image) -> Path:
    """Write ``image`` as an 8-bit PNG at ``path`` and return the path.

    ``image``: uint8, bool or float array (or CPU tensor) of shape ``[H, W]`` or ``[H, W, C]`` with C =
    1 (gray), 2 (gray+alpha), 3 (RGB) or 4 (RGBA); floats are clipped to [0, 1] (see :func:`to_uint8`).
    The file is written to a temporary file in the same directory and moved into place with
    ``os.replace``, so readers never see a half-written file and a failure leaves nothing behind.
    The parent directory must exist.
    """
    a = to_uint8(image)
    pil = require_pillow(f"writing {os.fspath(path)!r}").fromarray(a[..., 0] if a.shape[2] == 1 else a)  # mode L, LA, RGB, RGBA
    path = Path(os.fspath(path))
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():  # (else mkstemp's error names the hidden temporary file)
        raise FileNotFoundError(f"cannot write {str(path)!r}: the folder {str(directory)!r} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as fh:
            pil.save(fh, format="PNG")
            fh.flush()
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path


def read_png(path) -> np.ndarray:
    """Read a PNG file (or any image Pillow reads) as uint8 ``[H, W, C]``: C = 1 (gray), 2 (gray+alpha),
    3 (RGB) or 4 (RGBA); 16-bit gray is scaled to 8 bits (C = 1), palette and other 8-bit modes are
    converted to RGBA. Raises :class:`~gendr.errors.InputValueError` naming the path when it cannot
    be read or decoded, or holds float or 32-bit integer pixels (no 8-bit meaning to give them)."""
    p = os.fspath(path)
    Image = require_pillow(f"reading {p!r}")
    a = None
    try:
        with Image.open(p) as im:
            im.load()
            mode = im.mode
            if mode.startswith("I;16") or (mode == "I" and im.format == "PNG"):
                # 16-bit gray (mode I for PNGs before Pillow 10.3): convert() would clip at 255, not scale
                a = ((np.asarray(im).astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
            elif mode not in ("I", "F"):
                a = np.asarray(im if mode in _MODES.values() else im.convert("RGBA"), dtype=np.uint8)
    except (OSError, SyntaxError, ValueError) as e:  # Pillow reports a corrupt PNG as SyntaxError
        raise InputValueError(f"cannot read image file {p!r}: {e}") from None
    if a is None:
        kind = "float" if mode == "F" else "32-bit integer"
        raise InputValueError(f"cannot read image file {p!r}: its pixels are {kind} (Pillow mode {mode!r}), "
                              f"which have no 8-bit meaning; save it as an 8- or 16-bit PNG")
    return a[:, :, None] if a.ndim == 2 else a


def _rgba(image, index: int) -> np.ndarray:
    a = _as_numpy(image)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in _MODES or a.shape[0] < 1 or a.shape[1] < 1:
        raise ShapeError(f"contact_sheet image {index} must have shape [H, W] or [H, W, C] with C in 1..4, "
                         f"got {tuple(a.shape)}")
    if a.dtype == np.uint8:
        a = a.astype(np.float64) / 255.0
    elif a.dtype == np.bool_ or np.issubdtype(a.dtype, np.floating):
        a = np.clip(np.nan_to_num(a.astype(np.float64), nan=0.0), 0.0, 1.0)
    else:
        raise DTypeError(f"contact_sheet image {index} dtype must be floating point or uint8, got {a.dtype}")
    ch = a.shape[2]
    if ch == 1:
        return np.concatenate([np.repeat(a, 3, axis=2), np.ones_like(a)], axis=2)
    if ch == 2:
        return np.concatenate([np.repeat(a[..., :1], 3, axis=2), a[..., 1:]], axis=2)
    if ch == 3:
        return np.concatenate([a, np.ones_like(a[..., :1])], axis=2)
    return a


def contact_sheet(images, columns: int | None = None, pad: int = 2, background=(1.0, 1.0, 1.0, 1.0)) -> np.ndarray:
    """Tile ``images`` row by row into one float64 RGBA image ``[h, w, 4]`` in [0, 1].

    ``images``: a sequence (or a ``[N, H, W, C]`` array) of ``[H, W, C]`` images, C in 1..4, float or
    uint8; they may differ in size (each cell is as large as the largest image; smaller images are
    centred). ``columns``: images per row (default ``ceil(sqrt(N))``). ``pad``: pixels between cells
    and around the border. ``background``: gray level, RGB or RGBA of padding and empty cells.
    Cell (row r, column c) holds ``images[r * columns + c]`` with its top-left corner at
    ``(pad + r * (cell_h + pad), pad + c * (cell_w + pad))``.
    """
    cells = [_rgba(im, i) for i, im in enumerate(images)]
    if not cells:
        raise ShapeError("contact_sheet needs at least one image, got 0")
    n = len(cells)
    if columns is None:
        columns = math.ceil(math.sqrt(n))
    if isinstance(columns, bool) or not isinstance(columns, (int, np.integer)) or columns < 1:
        raise ParameterError(f"contact_sheet columns must be an integer >= 1, got {columns!r}")
    if isinstance(pad, bool) or not isinstance(pad, (int, np.integer)) or pad < 0:
        raise ParameterError(f"contact_sheet pad must be an integer >= 0, got {pad!r}")
    bg = np.atleast_1d(np.asarray(background, dtype=np.float64))
    if bg.shape == (1,):
        bg = np.array([bg[0]] * 3 + [1.0])
    elif bg.shape == (3,):
        bg = np.append(bg, 1.0)
    elif bg.shape != (4,):
        raise ShapeError(f"contact_sheet background must be a gray level, RGB or RGBA, got shape {bg.shape}")
    if not np.all(np.isfinite(bg)):
        raise InputValueError(f"contact_sheet background must be finite, got {background!r}")
    columns = int(columns)
    rows = math.ceil(n / columns)
    ch = max(c.shape[0] for c in cells)
    cw = max(c.shape[1] for c in cells)
    sheet = np.empty((pad + rows * (ch + pad), pad + columns * (cw + pad), 4))
    sheet[:] = np.clip(bg, 0.0, 1.0)
    for i, c in enumerate(cells):
        r, k = divmod(i, columns)
        y = pad + r * (ch + pad) + (ch - c.shape[0]) // 2
        x = pad + k * (cw + pad) + (cw - c.shape[1]) // 2
        sheet[y:y + c.shape[0], x:x + c.shape[1]] = c
    return sheet
