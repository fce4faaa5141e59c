"""Run-length encoding of surface voxels: pointer map, columns, mip levels (thesis 4.4.6, 4.4.7).

Each vertical column is run-length encoded from top to bottom into 16-bit elements
of (skipped, drawn) counts (10 + 6 bits, long runs split; the layout is in
:mod:`.codec`).  A pointer map over the x-z plane holds, per column, the pointer to
its remaining elements, its element count and its first element inline (64 bits
per entry, Fig. 4.11).  Mip levels (4.4.7) are 2x down-sampled copies encoded the
same way.  :func:`decode_rle` gives back exactly the voxels that went in.

Encoding is NumPy pre-processing; :class:`RLEVolume` is the JAX pytree the renderer
consumes (:func:`as_jax` moves it to the device).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import check_int, static_field
from jaxgfx._src.voxel.codec import MAX_DRAW, MAX_SKIP, pack_element, unpack_element
from jaxgfx._src.voxel.voxset import (
    Voxels,
    _check_shape,
    as_voxels,
    downsample_voxels,
    make_voxels,
)

__all__ = [
    "MIPS",
    "RLEVolume",
    "encode_rle",
    "decode_rle",
    "rle_stats",
    "place_instances",
    "share_columns",
    "as_jax",
]

Array = jax.Array | np.ndarray
"""A buffer of :class:`RLEVolume`: NumPy after :func:`encode_rle`, JAX after :func:`as_jax`."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RLEVolume:
    """Run-length encoded surface voxels with a pointer map and mip levels (Fig. 4.11).

    Column ``c = x * Z_l + z`` of level ``l`` is entry ``level_offsets[l] + c``
    of the pointer-map arrays.  An element is ``skip << 6 | draw`` (10 + 6 bits,
    :func:`~jaxgfx.raycast.pack_element`):
    ``skip`` empty voxels, then ``draw`` coloured ones, counted from the top of
    the column (y = Y_l - 1) downwards.

    Attributes:
        first: (C,) uint16, the column's first element, inline in the pointer map.
        count: (C,) uint16, elements in the column (0 = empty column).
        ptr: (C,) uint32, index in ``elements`` of the column's second element.
        color_ptr: (C,) uint32, index in ``colors`` of the column's first drawn voxel.
        elements: (M,) uint16, every column's elements after the first.
        colors: (K, 3) uint8, one RGB per drawn voxel in column order, top to bottom.
        tiles: (TX, TZ) int32 instance map: the scene is a TX x TZ grid of
            object-sized tiles, each holding the object (0) or nothing (-1).
            A plain volume is one tile.  Instances share every column.
        tail_sums: (2, M) uint16, per element of ``elements`` (not in the
            thesis): the voxels its column tail spans
            down to the element's bottom, and the drawn voxels of the tail
            before it.  The ray caster reads a column's elements directly
            instead of decoding every element above them.
        shape: static ``(X, Y, Z)`` of the whole scene at level 0
            (``TX * X_0, Y_0, TZ * Z_0``).
        level_shapes: static tuple of the object's ``(X_l, Y_l, Z_l)``; ``Y_l = Y_0`` with
            column mips.
        level_offsets: static tuple, first pointer-map entry of each level.
        max_elements: static, the largest column element count over all levels.
        voxel_counts: static tuple, drawn voxels per level.
        column_mips: static; False: level ``l``'s cells are cubes of ``2^l`` voxels (the
            thesis's mips); True: columns ``2^l`` voxels wide and one voxel high, so every
            level keeps the exact heights (:func:`encode_rle`'s ``mips="column"``).
        column_tails: static; the tail elements the columns reach, shared ones
            counted once per column (None: ``len(elements)``, each stored element
            in one column; set by :func:`share_columns`, see ``shared_tails``).
    """

    first: Array
    count: Array
    ptr: Array
    color_ptr: Array
    elements: Array
    colors: Array
    tiles: Array
    tail_sums: Array
    shape: tuple = static_field()
    level_shapes: tuple = static_field()
    level_offsets: tuple = static_field()
    max_elements: int = static_field()
    voxel_counts: tuple = static_field()
    column_mips: bool = static_field(default=False)
    column_tails: int | None = static_field(default=None)

    @property
    def levels(self) -> int:
        return len(self.level_shapes)

    @property
    def shared_tails(self) -> bool:
        """True where columns may share their stored tails (:func:`share_columns`), so
        ``elements`` holds fewer elements than the columns reach (``column_tails``)."""
        return self.column_tails is not None


def _tail_sums(count, ptr, elements) -> np.ndarray:
    """Running sums over every column tail: the :attr:`RLEVolume.tail_sums` table.

    A column's first element sits inline in the pointer map; its tail, the
    elements after it, is ``elements[ptr : ptr + count - 1]``.  For the tail's
    ``j``-th element (``j >= 1``), row 0 is ``S_j``, the voxels (skipped and
    drawn) of tail elements ``1..j``, so its bottom voxel is the first
    element's bottom minus ``S_j``; row 1 is the drawn voxels of tail
    elements ``1..j-1``, its colours' offset after the first element's.
    Both depend on the tail alone, so columns sharing a tail
    (:func:`share_columns`) share them.  With them the ray caster reads the
    elements a step works on without decoding the column above them (the
    same heights, bit for bit).

    Args:
        count: (C,) elements per column.
        ptr: (C,) index in ``elements`` of each column's second element.
        elements: (M,) the packed tail elements; tails are contiguous and
            either equal or disjoint (as :func:`encode_rle` and
            :func:`share_columns` store them).

    Returns:
        (2, M) uint16.
    """
    el = np.asarray(elements).astype(np.int64)
    count = np.asarray(count, np.int64)
    ptr = np.asarray(ptr, np.int64)
    starts = np.zeros(len(el), bool)
    starts[np.unique(ptr[count > 1])] = True
    starts[:1] = True
    skip, draw = unpack_element(el)
    adv = skip + draw
    seg = np.cumsum(starts) - 1  # tail of each element
    seg_start = np.flatnonzero(starts)
    c_adv = np.cumsum(adv)
    c_draw = np.cumsum(draw)
    base_adv = (c_adv - adv)[seg_start][seg]
    base_draw = (c_draw - draw)[seg_start][seg]
    out = np.stack([c_adv - base_adv, c_draw - draw - base_draw])
    if out.size and out.max() > 0xFFFF:
        raise ValueError("a column tail spans more than 65535 voxels")
    return out.astype(np.uint16)


def _encode_level(vox: Voxels):
    """Encodes one level: returns (first, count, ptr_local, color_ptr, elements, colors)."""
    X, Y, Z = vox.shape
    c = np.asarray(vox.coords, np.int64)
    colors = np.asarray(vox.colors, np.uint8)
    ncols = X * Z
    colid = c[:, 0] * Z + c[:, 2]
    order = np.lexsort((-c[:, 1], colid))  # column, then top to bottom
    colid, y, colors = colid[order], c[order, 1], colors[order]
    n = len(y)
    if n:
        new_run = np.ones(n, bool)
        new_run[1:] = (colid[1:] != colid[:-1]) | (y[1:] != y[:-1] - 1)
        run_start = np.flatnonzero(new_run)
        run_len = np.diff(np.append(run_start, n))
        run_col = colid[run_start]
        run_top = y[run_start]
        first_in_col = np.ones(len(run_start), bool)
        first_in_col[1:] = run_col[1:] != run_col[:-1]
        prev_bottom = np.empty(len(run_start), np.int64)
        prev_bottom[0] = Y
        prev_bottom[1:] = run_top[:-1] - run_len[:-1] + 1
        prev_bottom[first_in_col] = Y
        skip = prev_bottom - 1 - run_top
    else:
        run_len = run_col = skip = np.zeros(0, np.int64)
    # Long skips become (1023, 0) elements; long runs continue as (0, <=63).
    n_skip_el = np.maximum(0, (skip - 1) // MAX_SKIP)
    n_draw_el = np.maximum(1, -(-run_len // MAX_DRAW))
    per_run = n_skip_el + n_draw_el
    run_of = np.repeat(np.arange(len(run_len)), per_run)
    k = np.arange(per_run.sum()) - np.repeat(np.cumsum(per_run) - per_run, per_run)
    ns = n_skip_el[run_of]
    is_skip = k < ns
    kd = k - ns
    el_skip = np.where(is_skip, MAX_SKIP, np.where(kd == 0, skip[run_of] - ns * MAX_SKIP, 0))
    el_draw = np.where(is_skip, 0, np.minimum(MAX_DRAW, run_len[run_of] - kd * MAX_DRAW))
    el = pack_element(el_skip, el_draw).astype(np.uint16)
    el_col = run_col[run_of]
    count = np.bincount(el_col, minlength=ncols).astype(np.int64)
    if count.max(initial=0) > 0xFFFF:
        raise ValueError("a column needs more than 65535 RLE elements")
    start = np.cumsum(count) - count
    first = np.zeros(ncols, np.uint16)
    nonempty = count > 0
    first[nonempty] = el[start[nonempty]]
    is_first = np.zeros(len(el), bool)
    is_first[start[nonempty]] = True
    rest = el[~is_first]
    ptr = (np.cumsum(np.maximum(count - 1, 0)) - np.maximum(count - 1, 0)).astype(np.int64)
    drawn = np.bincount(colid, minlength=ncols).astype(np.int64)
    color_ptr = np.cumsum(drawn) - drawn
    return first, count, ptr, color_ptr, rest, colors


MIPS = ("cube", "column")
"""Mip kinds of :func:`encode_rle`."""


def encode_rle(vox: Voxels, *, levels: int = 1, mips: str = "cube") -> RLEVolume:
    """Encodes surface voxels into the pointer map + RLE columns, with mip levels.

    Args:
        vox: coloured voxels (normally only the surface, see :func:`surface_voxels`); a
            3-D occupancy array is taken as its surface voxels in the clay colour
            (:func:`~jaxgfx.raycast.dense_to_voxels`).
        levels: number of levels; level ``l`` is ``l`` times 2x down-sampled.
        mips: ``"cube"``: 2x2x2 down-sampling, as the thesis (4.4.7); a coarse cell is
            ``2^l`` voxels high, so where two LOD bands meet, a surface can step up by up to
            ``2^l - 1`` voxels (a seam line on flat ground).  ``"column"``: 2x1x2
            down-sampling, every level keeps the level-0 heights, so bands join without
            steps; the coarse levels hold more voxels (tall surfaces keep their vertical
            runs).

    Returns:
        The :class:`RLEVolume` (NumPy-backed leaves; ``jax.device_put`` it for speed).

    Raises:
        TypeError: ``vox`` is neither :class:`Voxels` nor a 3-D array.
    """
    vox = as_voxels(vox)
    shape = _check_shape(vox.shape)
    levels = check_int("levels", levels, low=1)
    if mips not in MIPS:
        raise ValueError(f"mips must be one of {MIPS}, got {mips!r}")
    c = np.asarray(vox.coords)
    if len(c) and (c.min() < 0 or np.any(c.max(axis=0) >= np.array(shape))):
        raise ValueError(f"voxel coordinates outside the grid {shape}")
    parts = []
    cur = vox
    for _ in range(levels):
        parts.append((cur.shape, len(cur.coords), _encode_level(cur)))
        cur = downsample_voxels(cur, vertical=mips == "cube")
    firsts, counts, ptrs, cptrs, els, cols = [], [], [], [], [], []
    offsets, shapes, nvox = [], [], []
    col_base = el_base = c_base = 0
    for shp, nv, (first, count, ptr, cptr, el, col) in parts:
        offsets.append(col_base)
        shapes.append(tuple(int(s) for s in shp))
        nvox.append(int(nv))
        firsts.append(first)
        counts.append(count)
        ptrs.append(ptr + el_base)
        cptrs.append(cptr + c_base)
        els.append(el)
        cols.append(col)
        col_base += len(first)
        el_base += len(el)
        c_base += len(col)
    count = np.concatenate(counts)
    ptr = np.concatenate(ptrs).astype(np.uint32)
    elements = np.concatenate(els).astype(np.uint16) if el_base else np.zeros(1, np.uint16)
    return RLEVolume(
        first=np.concatenate(firsts).astype(np.uint16),
        count=count.astype(np.uint16),
        ptr=ptr,
        color_ptr=np.concatenate(cptrs).astype(np.uint32),
        elements=elements,
        colors=np.concatenate(cols).astype(np.uint8) if c_base else np.zeros((1, 3), np.uint8),
        tiles=np.zeros((1, 1), np.int32),
        tail_sums=_tail_sums(count, ptr, elements),
        shape=shape,
        level_shapes=tuple(shapes),
        level_offsets=tuple(offsets),
        max_elements=int(max(1, count.max(initial=0))),
        voxel_counts=tuple(nvox),
        column_mips=mips == "column",
    )


def decode_rle(rle: RLEVolume, level: int = 0) -> Voxels:
    """Decodes one level back into :class:`Voxels` (exact inverse of :func:`encode_rle`)."""
    level = check_int("level", level, low=0, high=rle.levels - 1)
    X, Y, Z = rle.level_shapes[level]
    o = rle.level_offsets[level]
    ncols = X * Z
    count = np.asarray(rle.count[o : o + ncols], np.int64)
    first = np.asarray(rle.first[o : o + ncols])
    ptr = np.asarray(rle.ptr[o : o + ncols], np.int64)
    cptr = np.asarray(rle.color_ptr[o : o + ncols], np.int64)
    elements = np.asarray(rle.elements)
    colors = np.asarray(rle.colors)
    col = np.repeat(np.arange(ncols), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    el = np.where(k == 0, first[col], elements[np.maximum(ptr[col] + k - 1, 0)])
    el = el.astype(np.int64)
    skip, draw = unpack_element(el)
    # Height of each element's first drawn voxel: column top minus everything above.
    adv = skip + draw
    col_start = np.repeat(np.cumsum(count) - count, count)
    before = np.cumsum(adv) - adv
    above = before - np.concatenate([[0], np.cumsum(adv)])[col_start]
    top = Y - 1 - above - skip
    vid = np.repeat(np.arange(len(el)), draw)
    j = np.arange(draw.sum()) - np.repeat(np.cumsum(draw) - draw, draw)
    y = top[vid] - j
    drawn_before = np.cumsum(draw) - draw
    cstart = np.concatenate([[0], np.cumsum(draw)])[col_start]
    cidx = cptr[col[vid]] + (drawn_before[vid] - cstart[vid]) + j
    c = col[vid]
    coords = np.stack([c // Z, y, c % Z], axis=1).astype(np.int32)
    rgb = colors[cidx] if len(cidx) else np.zeros((0, 3), np.uint8)
    tiles = np.asarray(rle.tiles)
    if tiles.shape == (1, 1) and tiles[0, 0] == 0:
        return Voxels(coords, rgb, (X, Y, Z))
    where = np.argwhere(tiles >= 0)
    coords = np.concatenate([coords + [tx * X, 0, tz * Z] for tx, tz in where])
    rgb = np.concatenate([rgb] * len(where))
    shape = (tiles.shape[0] * X, Y, tiles.shape[1] * Z)
    return make_voxels(coords, rgb, shape)


def rle_stats(rle: RLEVolume) -> dict:
    """Memory accounting as in Table 4.1 (bits/voxel) and Table 4.2 (bytes with colour).

    Position data = 64 bits per pointer-map entry (32-bit pointer, 16-bit count,
    16-bit first element) plus 16 bits per further element, summed over all mip
    levels, divided by the level-0 voxel count.  Colour data = 24-bit RGB per
    stored drawn voxel (all levels) plus our 32-bit colour pointer per column.
    Buffers are counted as stored, so instances sharing columns count once.
    ``tail_sums_bytes`` is our running sums over the column tails (four bytes per
    stored element, not in the thesis), reported apart.
    """
    entries = int(np.asarray(rle.count).shape[0])
    count = np.asarray(rle.count, np.int64)
    total_elements = int(count.sum())
    # Buffers as stored: instanced scenes share one element / colour buffer.
    stored = int(np.asarray(rle.elements).shape[0]) if int(np.maximum(count - 1, 0).sum()) else 0
    ntiles = int(np.asarray(rle.tiles).size)
    # 64 bits per pointer-map entry, 16 per stored element, 32 per instance tile.
    position_bits = 64 * entries + 16 * stored + (32 * ntiles if ntiles > 1 else 0)
    nvox0 = max(1, rle.voxel_counts[0])
    ncolors = int(np.asarray(rle.colors).shape[0]) if sum(rle.voxel_counts) else 0
    color_bytes = 3 * ncolors + 4 * entries
    return dict(
        voxels=int(rle.voxel_counts[0]),
        voxels_all_levels=int(sum(rle.voxel_counts)),
        rle_elements=total_elements,
        rle_elements_level0=int(count[: rle.level_offsets[1]].sum())
        if rle.levels > 1
        else total_elements,
        pointer_map_entries=entries,
        position_bytes=position_bits // 8,
        bits_per_voxel=position_bits / nvox0,
        bytes_with_color=position_bits // 8 + color_bytes,
        bytes_per_voxel_with_color=(position_bits / 8 + color_bytes) / nvox0,
        tail_sums_bytes=int(np.asarray(rle.tail_sums).nbytes),
    )


def place_instances(rle: RLEVolume, tiles, grid) -> RLEVolume:
    """A large map of many copies of one object that share all of its columns.

    The scene is a grid of object-sized tiles; a tile map of 32-bit entries
    says where the object stands.  No column, element or colour is copied, so
    memory grows only by the tile map (the thesis's 3000-tree forest and 1600
    Imrods).

    Args:
        rle: the object (one tile); its x and z sizes must be multiples of
            ``2 ** (levels - 1)`` so that every mip level tiles exactly.
        tiles: (K, 2) integer ``(tx, tz)`` tile positions of the copies.
        grid: ``(TX, TZ)`` tiles of the map.

    Raises:
        ValueError: a copy outside the grid, two copies on one tile, or an
            object size that does not tile its mip levels.
    """
    t = np.asarray(tiles, np.int64).reshape(-1, 2)
    TX, TZ = (int(v) for v in grid)
    X, Y, Z = rle.level_shapes[0]
    if np.asarray(rle.tiles).shape != (1, 1):
        raise ValueError("rle: already an instanced scene")
    if TX <= 0 or TZ <= 0:
        raise ValueError(f"grid must be positive, got {grid}")
    align = 1 << (rle.levels - 1)
    if X % align or Z % align:
        raise ValueError(f"object x/z size {X}x{Z} must be multiples of {align} for its mips")
    if len(t) == 0:
        raise ValueError("tiles: need at least one instance")
    if np.any(t < 0) or np.any(t[:, 0] >= TX) or np.any(t[:, 1] >= TZ):
        raise ValueError(f"tiles: an instance leaves the {TX}x{TZ} grid")
    m = np.full((TX, TZ), -1, np.int32)
    for i, (a, b) in enumerate(t):
        if m[a, b] >= 0:
            raise ValueError(f"tiles: instance {i} overlaps another at tile ({a}, {b})")
        m[a, b] = 0
    return dataclasses.replace(
        rle,
        tiles=m,
        shape=(TX * X, Y, TZ * Z),
        voxel_counts=tuple(int(n) * len(t) for n in rle.voxel_counts),
    )


def share_columns(rle: RLEVolume) -> RLEVolume:
    """Stores every distinct column tail once: instancing through the pointer map (4.4.6).

    The first element of a column is inline in the pointer map and holds the empty run
    above the column's top; the rest of the column is reached through ``ptr`` and its
    colours through ``color_ptr``.  Copies of one object standing at different heights
    (a forest on a slope) therefore differ only in their inline first elements: their
    remaining elements and colours are equal and are stored once here, with every copy's
    pointers aimed at the shared runs.  The renderer and :func:`decode_rle` read columns
    only through these pointers, so every frame stays bit-identical; :func:`rle_stats`
    counts the buffers as stored.  Unlike :func:`place_instances` the copies need no
    common tile grid or base height.

    Args:
        rle: an encoded volume (NumPy or JAX buffers).

    Returns:
        The same volume with deduplicated ``elements`` and ``colors`` (NumPy buffers).
    """
    count = np.asarray(rle.count, np.int64)
    ptr = np.asarray(rle.ptr, np.int64)
    cptr = np.asarray(rle.color_ptr, np.int64)
    first = np.asarray(rle.first)
    elements = np.asarray(rle.elements)
    colors = np.asarray(rle.colors)
    _, draw_first = unpack_element(first.astype(np.int64))
    new_ptr, new_cptr = ptr.copy(), cptr.copy()
    els: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    seen: dict[tuple[bytes, bytes], tuple[int, int]] = {}
    n_el = n_col = 0
    for c in np.flatnonzero(count):
        tail = elements[ptr[c] : ptr[c] + count[c] - 1]
        _, d = unpack_element(tail.astype(np.int64))
        ndraw = int(draw_first[c] + d.sum())
        rgb = colors[cptr[c] : cptr[c] + ndraw]
        key = (tail.tobytes(), rgb.tobytes())
        hit = seen.get(key)
        if hit is None:
            hit = seen[key] = (n_el, n_col)
            els.append(tail)
            cols.append(rgb)
            n_el += len(tail)
            n_col += ndraw
        new_ptr[c], new_cptr[c] = hit
    els_all = np.concatenate(els).astype(np.uint16) if n_el else np.zeros(1, np.uint16)
    return dataclasses.replace(
        rle,
        ptr=new_ptr.astype(np.uint32),
        color_ptr=new_cptr.astype(np.uint32),
        elements=els_all,
        colors=np.concatenate(cols).astype(np.uint8) if n_col else np.zeros((1, 3), np.uint8),
        first=first,
        count=np.asarray(rle.count),
        tiles=np.asarray(rle.tiles),
        tail_sums=_tail_sums(rle.count, new_ptr, els_all),
        column_tails=int(np.maximum(count - 1, 0).sum()),
    )


def as_jax(rle: RLEVolume) -> RLEVolume:
    """Moves an :class:`RLEVolume`'s buffers to the default JAX device."""
    return jax.tree_util.tree_map(jnp.asarray, rle)
