"""jaxgfx internals, grouped by thesis concept.

Nothing here is public API: users import from ``jaxgfx`` or from the chapter faces
``jaxgfx.terrain`` (ch. 3), ``jaxgfx.raycast`` (ch. 4) and ``jaxgfx.skin`` (ch. 5).
Layout: ``terrain/`` (terrain functions, Clip-Boxes, meshing, pipeline, worker), ``voxel/``
(voxel sets, formats, RLE codec and encoding, the per-plane ray caster), ``skin/`` (spline,
rig, binding, styles, skinning, baselines, fitting, glTF), ``checks`` (argument checks shared
by every layer).
"""
