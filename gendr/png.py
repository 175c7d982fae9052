"""A tiny dependency-free PNG writer and reader (stdlib ``zlib`` + ``struct`` and numpy).

* :func:`write_png` writes 8-bit grayscale, gray+alpha, RGB or RGBA images atomically.
* :func:`read_png` reads back 8-bit non-interlaced PNGs of those colour types (filter types 0-4),
  enough to round-trip what :func:`write_png` writes and to check images in tests.
* :func:`contact_sheet` tiles many images into one RGBA grid.

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
import struct
import tempfile
import zlib
from pathlib import Path

import numpy as np

from .errors import DTypeError, InputValueError, ParameterError, ShapeError

__all__ = ["write_png", "encode_png", "read_png", "decode_png", "contact_sheet", "to_uint8"]

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: channels -> PNG colour type (0 gray, 4 gray+alpha, 2 RGB, 6 RGBA)
_COLOR_TYPE = {1: 0, 2: 4, 3: 2, 4: 6}
_CHANNELS = {v: k for k, v in _COLOR_TYPE.items()}


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
    if a.ndim != 3 or a.shape[2] not in _COLOR_TYPE:
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


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def _paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - c)
    return np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))


def _filter_rows(rows: np.ndarray, bpp: int, filter_type: int | None) -> np.ndarray:
    """Apply PNG filters to uint8 rows ``[H, stride]``; returns ``[H, 1 + stride]`` with filter bytes.

    ``filter_type`` None picks per row the filter minimising the sum of absolute signed residuals
    (the usual heuristic); 0-4 force one filter.
    """
    x = rows.astype(np.int16)
    a = np.zeros_like(x)
    a[:, bpp:] = x[:, :-bpp]
    b = np.zeros_like(x)
    b[1:] = x[:-1]
    c = np.zeros_like(x)
    c[1:, bpp:] = x[:-1, :-bpp]
    candidates = np.stack([x, x - a, x - b, x - (a + b) // 2, x - _paeth(a, b, c)]) % 256  # [5, H, stride]
    if filter_type is None:
        signed = np.where(candidates >= 128, 256 - candidates, candidates)
        choice = signed.sum(axis=2).argmin(axis=0)
    elif filter_type in (0, 1, 2, 3, 4):
        choice = np.full(x.shape[0], filter_type)
    else:
        raise ParameterError(f"PNG filter_type must be None or 0..4, got {filter_type!r}")
    chosen = candidates[choice, np.arange(x.shape[0])]
    return np.concatenate([choice[:, None], chosen], axis=1).astype(np.uint8)


def encode_png(image, *, filter_type: int | None = None, level: int = 6) -> bytes:
    """The bytes of an 8-bit PNG of ``image`` (see :func:`to_uint8` for accepted inputs)."""
    a = to_uint8(image)
    h, w, ch = a.shape
    header = struct.pack(">IIBBBBB", w, h, 8, _COLOR_TYPE[ch], 0, 0, 0)
    raw = _filter_rows(a.reshape(h, w * ch), ch, filter_type)
    return (_SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(raw.tobytes(), level))
            + _chunk(b"IEND", b""))


def write_png(path, image, **kwargs) -> Path:
    """Write ``image`` as an 8-bit PNG at ``path`` and return the path.

    ``image``: uint8, bool or float array (or CPU tensor) of shape ``[H, W]`` or ``[H, W, C]`` with C =
    1 (gray), 2 (gray+alpha), 3 (RGB) or 4 (RGBA); floats are clipped to [0, 1]. The file is written
    to a temporary file in the same directory and moved into place with ``os.replace``, so readers
    never see a half-written file and a failure leaves nothing behind. The parent directory must exist.
    """
    data = encode_png(image, **kwargs)
    path = Path(os.fspath(path))
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
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


def decode_png(data: bytes, *, name: str = "PNG data") -> np.ndarray:
    """Decode PNG bytes to uint8 ``[H, W, C]`` (8-bit, colour types 0/2/4/6, no interlace)."""
    if data[:8] != _SIGNATURE:
        raise InputValueError(f"{name} is not a PNG file (bad signature)")
    pos, header, idat = 8, None, []
    while pos + 8 <= len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind = data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + length]
        crc = data[pos + 8 + length:pos + 12 + length]
        if len(body) != length or len(crc) != 4:
            raise InputValueError(f"{name} is truncated in chunk {kind!r}")
        if struct.unpack(">I", crc)[0] != zlib.crc32(kind + body) & 0xFFFFFFFF:
            raise InputValueError(f"{name} has a bad CRC in chunk {kind!r}")
        pos += 12 + length
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    if header is None:
        raise InputValueError(f"{name} has no IHDR chunk")
    w, h, depth, color, _comp, _filt, interlace = header
    if depth != 8 or color not in _CHANNELS or interlace != 0:
        raise InputValueError(f"{name}: only 8-bit non-interlaced gray/gray+alpha/RGB/RGBA PNGs are "
                              f"supported, got bit depth {depth}, colour type {color}, interlace {interlace}")
    ch = _CHANNELS[color]
    stride = w * ch
    try:
        raw = zlib.decompress(b"".join(idat))
    except zlib.error as e:
        raise InputValueError(f"{name} has corrupt image data: {e}") from None
    if len(raw) != h * (stride + 1):
        raise InputValueError(f"{name}: image data has {len(raw)} bytes, expected {h * (stride + 1)}")
    rows = np.frombuffer(raw, dtype=np.uint8).reshape(h, stride + 1)
    out = np.zeros((h, stride), dtype=np.uint8)
    prev = np.zeros(stride, dtype=np.int64)
    for i in range(h):
        ftype, f = int(rows[i, 0]), rows[i, 1:].astype(np.int64)
        if ftype == 0:
            cur = f
        elif ftype == 1:  # Sub: running sum per channel
            cur = np.cumsum(f.reshape(w, ch), axis=0).reshape(-1) % 256
        elif ftype == 2:  # Up
            cur = (f + prev) % 256
        elif ftype in (3, 4):  # Average / Paeth: sequential within the row
            fl, pl, cur_l = f.tolist(), prev.tolist(), [0] * stride
            for k in range(stride):
                left = cur_l[k - ch] if k >= ch else 0
                up = pl[k]
                if ftype == 3:
                    pred = (left + up) // 2
                else:
                    ul = pl[k - ch] if k >= ch else 0
                    p = left + up - ul
                    pa, pb, pc = abs(p - left), abs(p - up), abs(p - ul)
                    pred = left if pa <= pb and pa <= pc else (up if pb <= pc else ul)
                cur_l[k] = (fl[k] + pred) & 0xFF
            cur = np.array(cur_l, dtype=np.int64)
        else:
            raise InputValueError(f"{name}: unknown filter type {ftype} in row {i}")
        out[i] = cur
        prev = cur
    return out.reshape(h, w, ch)


def read_png(path) -> np.ndarray:
    """Read an 8-bit non-interlaced PNG written by :func:`write_png` (or similar) as uint8 ``[H, W, C]``."""
    p = os.fspath(path)
    try:
        with open(p, "rb") as fh:
            data = fh.read()
    except OSError as e:
        raise InputValueError(f"cannot read PNG file {p!r}: {e.strerror or e}") from None
    return decode_png(data, name=f"PNG file {p!r}")


def _rgba(image, index: int) -> np.ndarray:
    a = _as_numpy(image)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in _COLOR_TYPE or a.shape[0] < 1 or a.shape[1] < 1:
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
