# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Occupancy-grid maps in the map_server format: an image and its YAML.

The YAML (read with :func:`robot_calib.io.safe_yaml.load_yaml`) has
``image`` (path relative to the YAML), ``resolution`` (m/pixel), ``origin``
``[x, y, yaw]`` (m, m, rad: the pose of the lower-left pixel), ``negate``
(0/1), ``occupied_thresh`` and ``free_thresh`` (0..1), and optionally
``mode`` (``trinary``, ``scale`` or ``raw``). As map_server (nav2_map_server
``map_io``): with ``negate`` 0 a pixel's occupancy is ``p = (255 - v) / 255``
(dark is occupied), with ``negate`` 1 ``p = v / 255``; a cell is occupied
when ``p > occupied_thresh`` (``raw``: ``v >= 100``, ``v <= 100``). Colour
pixels are the mean of their channels; alpha is ignored.

Images: binary or ASCII PGM (``P5``/``P2``, 8 or 16 bit) read here with
numpy, PNG through matplotlib. Bad input raises :class:`MapError` with a
one-line message; images larger than :data:`MAX_PIXELS` are refused from
their header, before any pixel is read.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
import re
from typing import Any, Union

import numpy as np

from robot_calib.core.raycast import OccupancyGrid

MAX_PIXELS = 64_000_000
"""Largest map accepted (pixels): 8000 x 8000 cells, 400 m square at 5 cm."""
MAX_YAML_BYTES = 1 << 16
"""Largest map YAML read (bytes)."""


class MapError(ValueError):
    """A map that cannot be used (one-line message)."""


def _number(data: dict, key: str, default: Any = None) -> float:
    if key not in data:
        if default is None:
            raise MapError(f'map YAML: missing {key!r}')
        return float(default)
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MapError(f'map YAML: {key} must be a number, got {value!r}')
    value = float(value)
    if not math.isfinite(value):
        raise MapError(f'map YAML: {key} must be finite, got {value!r}')
    return value


def read_pgm(path: Union[str, os.PathLike]) -> np.ndarray:
    """Return the pixels (H, W) of a binary or ASCII PGM, scaled to 0..255 (float)."""
    with open(path, 'rb') as f:
        head = f.read(1024)
        tokens: list[bytes] = []
        pos = 0
        for m in re.finditer(rb'#[^\n]*\n?|\S+', head):
            if m.group().startswith(b'#'):
                continue
            tokens.append(m.group())
            pos = m.end()
            if len(tokens) == 4:
                break
        if len(tokens) < 4 or tokens[0] not in (b'P5', b'P2'):
            raise MapError(f'{path}: not a PGM image (P5 or P2 header expected)')
        try:
            w, h, maxval = (int(t) for t in tokens[1:4])
        except ValueError:
            raise MapError(f'{path}: bad PGM header') from None
        if w <= 0 or h <= 0 or not 0 < maxval < 65536:
            raise MapError(f'{path}: bad PGM size {w} x {h} or maximum {maxval}')
        if w * h > MAX_PIXELS:
            raise MapError(f'{path}: {w} x {h} pixels is more than {MAX_PIXELS}: refused')
        if tokens[0] == b'P5':
            f.seek(pos + 1)  # one whitespace after the maximum value
            dtype = np.dtype('>u2') if maxval > 255 else np.dtype('u1')
            data = np.frombuffer(f.read(w * h * dtype.itemsize), dtype=dtype)
        else:
            f.seek(pos)
            text = re.sub(rb'#[^\n]*', b'', f.read(w * h * 6 + 16))
            data = np.array(text.split()[:w * h], dtype=np.int64)
    if data.size != w * h:
        raise MapError(f'{path}: PGM truncated ({data.size} of {w * h} pixels)')
    return data.reshape(h, w).astype(float) * (255.0 / maxval)


def _png_size(path: Path) -> tuple[int, int]:
    with open(path, 'rb') as f:
        head = f.read(24)
    if len(head) < 24 or head[:8] != b'\x89PNG\r\n\x1a\n':
        raise MapError(f'{path}: not a PNG image')
    return int.from_bytes(head[16:20], 'big'), int.from_bytes(head[20:24], 'big')


def read_image(path: Union[str, os.PathLike]) -> np.ndarray:
    """Return the grey levels (H, W) 0..255 of a PGM or PNG map image (row 0 at the top)."""
    path = Path(path)
    if not path.is_file():
        raise MapError(f'map image not found: {path}')
    if path.suffix.lower() in ('.pgm', '.pnm'):
        return read_pgm(path)
    if path.suffix.lower() != '.png':
        raise MapError(f'{path}: map images must be PGM or PNG')
    w, h = _png_size(path)
    if w * h > MAX_PIXELS or w <= 0 or h <= 0:
        raise MapError(f'{path}: {w} x {h} pixels is more than {MAX_PIXELS}: refused')
    from matplotlib import image as mpimg
    try:
        img = np.asarray(mpimg.imread(str(path)), dtype=float)
    except Exception as exc:  # noqa: B902 - any decoder failure is a bad image
        raise MapError(f'{path}: cannot read the PNG ({str(exc).splitlines()[0]})') from None
    if img.ndim == 3:
        img = img[..., :3].mean(axis=2) if img.shape[2] >= 3 else img[..., 0]
    return img * 255.0 if img.max(initial=0.0) <= 1.0 else img


def load_map(path: Union[str, os.PathLike]) -> OccupancyGrid:
    """Return the occupancy grid of a map_server YAML (and its image); :class:`MapError`."""
    import yaml
    from robot_calib.io.safe_yaml import load_yaml
    path = Path(path)
    try:
        data = load_yaml(path, max_bytes=MAX_YAML_BYTES)
    except (OSError, UnicodeDecodeError) as exc:
        raise MapError(f'cannot read map YAML {path}: {exc.__class__.__name__}') from None
    except yaml.YAMLError as exc:
        raise MapError(f'map YAML {path}: {str(exc).splitlines()[0]}') from None
    if not isinstance(data, dict):
        raise MapError(f'map YAML {path}: expected a mapping with image, resolution, origin')
    image = data.get('image')
    if not isinstance(image, str) or not image:
        raise MapError(f'map YAML {path}: missing image (file name)')
    res = _number(data, 'resolution')
    if not 1e-4 <= res <= 100.0:
        raise MapError(f'map YAML: resolution {res} m/pixel out of [1e-4, 100]')
    origin = data.get('origin')
    if not isinstance(origin, (list, tuple)) or len(origin) not in (2, 3):
        raise MapError(f'map YAML: origin must be [x, y, yaw], got {origin!r}')
    ox, oy, oyaw = (_number({'origin': v}, 'origin') for v in (list(origin) + [0.0])[:3])
    negate = data.get('negate', 0)
    if negate not in (0, 1, True, False):
        raise MapError(f'map YAML: negate must be 0 or 1, got {negate!r}')
    occ_t = _number(data, 'occupied_thresh', 0.65)
    free_t = _number(data, 'free_thresh', 0.25)
    if not 0.0 <= free_t <= occ_t <= 1.0:
        raise MapError(f'map YAML: need 0 <= free_thresh <= occupied_thresh <= 1, got '
                       f'{free_t}, {occ_t}')
    mode = data.get('mode', 'trinary')
    if mode not in ('trinary', 'scale', 'raw'):
        raise MapError(f'map YAML: mode must be trinary, scale or raw, got {mode!r}')
    grey = read_image(path.parent / image)
    if mode == 'raw':
        occupied = grey >= 100
    else:
        p = grey / 255.0 if negate else (255.0 - grey) / 255.0
        occupied = p > occ_t
    return OccupancyGrid(np.ascontiguousarray(occupied[::-1]), res, ox, oy, oyaw)


def write_map(yaml_path: Union[str, os.PathLike], grid: OccupancyGrid) -> None:
    """Write ``grid`` as a map_server YAML and binary PGM beside it (occupied 0, free 254)."""
    yaml_path = Path(yaml_path)
    pgm = yaml_path.with_suffix('.pgm')
    img = np.where(grid.occupied[::-1], 0, 254).astype(np.uint8)
    h, w = img.shape
    pgm.write_bytes(f'P5\n{w} {h}\n255\n'.encode() + img.tobytes())
    yaml_path.write_text(
        f'image: {pgm.name}\nresolution: {grid.resolution!r}\n'
        f'origin: [{grid.origin_x!r}, {grid.origin_y!r}, {grid.origin_yaw!r}]\n'
        'negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n')
