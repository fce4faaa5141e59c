"""Chapter 4 internals: surface voxels, their RLE encoding and the per-plane ray caster.

The public face is :mod:`jaxgfx.raycast`.  Modules, in the thesis's order: ``voxset``
(coloured voxel sets, surfaces, mips), ``voxelize`` (4.3.1), ``formats`` (4.3.2 volumes,
Voxlap files, scenes), ``tree`` (4.3.3), ``codec`` (the RLE element and drawn-element bit
layouts), ``encode`` (4.4.6 - 4.4.7 pointer map, columns, mips, instances), ``planes``
(4.5.1 - 4.5.3), ``grid`` (device-side reads of the encoded volume), ``walk`` (a plane's
start and cells, 4.5.4), ``scatter`` with ``scatter_planes``, ``scatter_elements`` and
``scatter_warp`` (the ray buffer drawn column by column, the default, 4.5.4), ``wide`` (the
plane walk in blocks of cells, 4.5.4), ``warp`` (4.5.5 and the per-pixel re-walk),
``settings`` and ``render`` (the frame, its settings), ``reference`` (the exact per-pixel
3-D DDA).
"""
