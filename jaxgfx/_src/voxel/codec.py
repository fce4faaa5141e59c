"""Bit layouts of the ray caster: the RLE element (4.4.6) and the drawn-element words (4.5.4).

Every shift and mask of the chapter lives here, so the layouts are read and changed
in one place.  The helpers are plain integer arithmetic: they work on Python ints,
NumPy arrays (pre-processing) and JAX arrays (rendering) alike.

RLE element (Fig. 4.11): 16 bits, ``skip << DRAW_BITS | draw``: ``skip`` empty voxels
(10 bits), then ``draw`` coloured ones (6 bits), counted from the top of the column
downwards.  Longer gaps and runs are split over several elements.

Drawn element (the per-plane lists of :func:`~jaxgfx._src.voxel.wide.traverse_wide`):
``ELEMENT_WORDS`` int32 words, two 16-bit halves packed in words 0 and 1 and the
mip level above the cell's z in word 4.
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = [
    "SKIP_BITS",
    "DRAW_BITS",
    "MAX_SKIP",
    "MAX_DRAW",
    "pack_element",
    "unpack_element",
    "ELEMENT_WORDS",
    "WORD_ROWS",
    "WORD_HEIGHTS",
    "WORD_COLOR",
    "WORD_X",
    "WORD_Z_LEVEL",
    "HALF_BITS",
    "HALF_MASK",
    "HALF_LIMIT",
    "NO_ENTRY",
    "IZ_BITS",
    "pack_drawn",
    "unpack_drawn_rows",
    "unpack_drawn_box",
]

# ---------------------------------------------------------------------------
# 4.4.6 The RLE element: (skipped, drawn) counts in 10 + 6 bits
# ---------------------------------------------------------------------------

SKIP_BITS = 10
DRAW_BITS = 6
MAX_SKIP = (1 << SKIP_BITS) - 1  # 1023
MAX_DRAW = (1 << DRAW_BITS) - 1  # 63


def pack_element(skip, draw):
    """The element ``skip << DRAW_BITS | draw`` (counts within ``MAX_SKIP`` / ``MAX_DRAW``)."""
    return (skip << DRAW_BITS) | draw


def unpack_element(el):
    """``(skip, draw)`` of an element (or an array of them): the inverse of :func:`pack_element`."""
    return el >> DRAW_BITS, el & MAX_DRAW


# ---------------------------------------------------------------------------
# 4.5.4 A drawn element in a plane's list: five int32 words
# ---------------------------------------------------------------------------

ELEMENT_WORDS = 5
"""int32 words per drawn element in a plane's list (:func:`pack_drawn`)."""
WORD_ROWS = 0  # ray-buffer rows r0 | r1 << 16
WORD_HEIGHTS = 1  # top | bottom << 16 (voxel heights at the element's level)
WORD_COLOR = 2  # colour index of the top voxel
WORD_X = 3  # map cell x
WORD_Z_LEVEL = 4  # map cell z | level << IZ_BITS

HALF_BITS = 16
HALF_MASK = (1 << HALF_BITS) - 1  # 0xFFFF
HALF_LIMIT = 1 << (HALF_BITS - 1)
"""Rows and heights must stay below this, so a packed upper half keeps the int32 positive."""
IZ_BITS = 26
"""Bits of the map cell z in word 4; the level sits above them."""
NO_ENTRY = 2**31 - 1
"""No list entry: a coverage word no element drew in, a row without a writer."""


def pack_drawn(r0, r1, top, bottom, cbase, ix, iz, lev):
    """Drawn elements as (N, 5) int32 words: ``r0 | r1 << 16``, ``top | bottom << 16``,
    colour index, cell x, ``iz | lev << 26``.

    Five words instead of eight: the lists are the ray caster's largest
    buffers, and the warp gathers three words per candidate instead of five.
    :func:`jaxgfx.raycast.render_rle` checks the ranges (rows and heights below
    2^15, map depth below 2^26).
    """
    return jnp.stack(
        [r0 | (r1 << HALF_BITS), top | (bottom << HALF_BITS), cbase, ix, iz | (lev << IZ_BITS)],
        axis=-1,
    )


def unpack_drawn_rows(w):
    """``(r0, r1)``: the row range ``[r0, r1)`` from word 0."""
    return w & HALF_MASK, w >> HALF_BITS


def unpack_drawn_box(w_y, w_x, w_z):
    """``(top, bottom, cell x, cell z, level)`` from words 1, 3 and 4."""
    return w_y & HALF_MASK, w_y >> HALF_BITS, w_x, w_z & ((1 << IZ_BITS) - 1), w_z >> IZ_BITS
