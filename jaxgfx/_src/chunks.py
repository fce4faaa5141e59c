"""Storage of a resumable sweep: compressed chunk files, per-item images, reading back.

A sweep's directory holds ``manifest.json`` (what defines the results, written by
:mod:`jaxgfx._src.sweep`), one ``chunk_XXXXX.npz`` per chunk of items, compressed with
zlib (``np.savez_compressed``), and, for outputs stored as images, one PNG per item
(lossless, and several times smaller than the raw 8-bit pixels of a rendered frame).
Every file is written atomically (:func:`jaxgfx._src.io.atomic_write`); a chunk's images
are written before its ``.npz``, so a chunk whose ``.npz`` reads back with all its items
and whose images are all there is complete (:func:`chunk_complete`), whatever
interrupted the sweep.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from jaxgfx._src.io import atomic_write

__all__ = [
    "chunk_path",
    "image_path",
    "image_patterns",
    "check_image_outputs",
    "write_chunk",
    "read_images",
    "chunk_complete",
    "load_sweep",
]


def chunk_path(out_dir, k: int) -> Path:
    """File of chunk ``k`` inside a sweep directory."""
    return Path(out_dir) / f"chunk_{k:05d}.npz"


def image_path(out_dir, pattern: str, i: int) -> Path:
    """File of item ``i`` of an image output: ``pattern`` (e.g. ``"color_{i:05d}.png"``)
    formatted with ``i``, relative to ``out_dir``."""
    return Path(out_dir) / pattern.format(i=i)


def image_patterns(images) -> dict[str, str]:
    """``images`` as ``{output name: file pattern}``; names alone get ``NAME_{i:05d}.png``."""
    if isinstance(images, str):
        raise TypeError(f"images must be a sequence of output names or a mapping, got {images!r}")
    if isinstance(images, Mapping):
        pats = {str(k): str(v) for k, v in images.items()}
    elif isinstance(images, Sequence):
        pats = {str(k): f"{k}_{{i:05d}}.png" for k in images}
    else:
        raise TypeError(f"images must be a sequence of output names or a mapping, got {images!r}")
    for name, pat in pats.items():
        if not pat.lower().endswith(".png") or "{i" not in pat:
            raise ValueError(
                f"images[{name!r}]: pattern must contain {{i}} and end in .png, got {pat!r}"
            )
        try:
            pat.format(i=0)
        except (KeyError, IndexError, ValueError):
            raise ValueError(f"images[{name!r}]: pattern {pat!r} takes only {{i}}") from None
    return pats


def check_image_outputs(patterns: dict[str, str], out_info) -> None:
    """Image outputs must exist and be (H, W) or (H, W, 3 | 4) uint8 per item."""
    for name in patterns:
        if name not in out_info:
            raise ValueError(f"images names {name!r}, which render_fn does not return")
        a = out_info[name]
        if (
            a.dtype != np.uint8
            or len(a.shape) not in (3, 4)
            or (len(a.shape) == 4 and a.shape[-1] not in (3, 4))
        ):
            raise ValueError(
                f"images[{name!r}]: an image output must be uint8 (H, W) or (H, W, 3|4) per "
                f"item, got {a.dtype}{list(a.shape[1:])} (convert with jaxgfx.compose.to_uint8)"
            )


def _write_images(out_dir: Path, patterns: dict[str, str], start: int, out: dict) -> None:
    """Every item's image outputs as PNG files, each written atomically."""
    import imageio.v3 as iio

    for name, pat in patterns.items():
        for j, img in enumerate(out[name]):
            path = image_path(out_dir, pat, start + j)
            with atomic_write(path) as tmp:
                iio.imwrite(tmp, np.asarray(img), extension=".png")


def write_chunk(out_dir: Path, k: int, start: int, out: dict, patterns: dict[str, str]) -> None:
    """Writes chunk ``k`` (items from ``start``): its images, then its compressed ``.npz``
    of the other outputs, which marks the chunk complete."""
    _write_images(out_dir, patterns, start, out)
    with atomic_write(chunk_path(out_dir, k)) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **{key: v for key, v in out.items() if key not in patterns})


def read_images(out_dir: Path, patterns: dict[str, str], start: int, n: int) -> dict:
    import imageio.v3 as iio

    return {
        name: np.stack([iio.imread(image_path(out_dir, pat, start + j)) for j in range(n)])
        for name, pat in patterns.items()
    }


def chunk_complete(out_dir: Path, k: int, sizes: list[int], manifest: dict) -> bool:
    """Chunk ``k`` is complete on disk: its ``.npz`` reads with ``sizes[k]`` items in every
    array, and each of its items' image files is there (they are written before the npz)."""
    n_items, start = sizes[k], sum(sizes[:k])
    patterns = manifest.get("images") or {}
    try:
        with np.load(chunk_path(out_dir, k)) as z:
            ok = all(z[key].shape[0] == n_items for key in z.files)
            ok = ok and (len(z.files) > 0 or bool(patterns))
    except Exception:
        return False
    return ok and all(
        _nonempty_file(image_path(out_dir, pat, start + j))
        for pat in patterns.values()
        for j in range(n_items)
    )


def _nonempty_file(path: Path) -> bool:
    try:
        return os.path.getsize(path) > 0
    except OSError:
        return False


def load_sweep(out_dir, names: Sequence[str] | None = None) -> dict:
    """Concatenates every chunk of a finished sweep -> dict of (N, ...) arrays.

    Outputs stored as images (``run_sweep(images=...)``) are read back from their PNG
    files, bit for bit what was rendered.

    Args:
        out_dir: the sweep's directory (``manifest.json`` and the chunks).
        names: outputs to read (default all); e.g. ``["depth"]`` skips the images.

    Raises:
        FileNotFoundError: a chunk or an image of the sweep is missing (not finished).
    """
    out_dir = Path(out_dir)
    manifest = json.loads((out_dir / "manifest.json").read_text())
    patterns = manifest.get("images") or {}
    wanted = None if names is None else set(names)
    parts: dict[str, list] = {}
    start = 0
    for k in range(manifest["n_chunks"]):
        path = chunk_path(out_dir, k)
        if not path.exists():
            raise FileNotFoundError(f"sweep in {out_dir} is incomplete: {path.name} missing")
        with np.load(path) as z:
            for key in z.files:
                if wanted is None or key in wanted:
                    parts.setdefault(key, []).append(z[key])
        n_items = min(manifest["chunk_size"], manifest["n"] - start)
        pick = {n: p for n, p in patterns.items() if wanted is None or n in wanted}
        for key, v in read_images(out_dir, pick, start, n_items).items():
            parts.setdefault(key, []).append(v)
        start += n_items
    return {key: np.concatenate(v) for key, v in parts.items()}
