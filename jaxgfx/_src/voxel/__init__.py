"""Chapter 4 internals: surface voxels, their RLE encoding and the per-plane ray caster.

The public face is :mod:`jaxgfx.raycast`.  Modules, in the thesis's order: ``voxset``
(coloured voxel sets, surfaces, mips), ``voxelize`` (4.3.1), ``formats`` (4.3.2 volumes,
Voxlap files, scenes), ``tree`` (4.3.3), ``codec`` (the RLE element and drawn-element bit
layouts), ``encode`` (4.4.6 - 4.4.7 pointer map, columns, mips, instances), ``planes``
(4.5.1 - 4.5.3), ``grid`` (device-side reads of the encoded volume), ``traverse`` (4.5.4),
``warp`` (4.5.5 and the per-pixel re-walk), ``render`` (the frame, its settings),
``reference`` (the exact per-pixel 3-D DDA).
"""
