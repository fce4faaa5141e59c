"""Terrain (thesis chapter 3), private implementation of :mod:`jaxgfx.terrain`.

Modules from the bottom up, each importing only those above it: ``functions``
(Eq. 3.1-3.2, combinators) -> ``csg``, ``heightmap`` -> ``sampling`` -> ``clipbox``
(3.4.1-3.4.3, 3.4.5-3.4.6) -> ``meshing`` (3.4.4-3.4.5) -> ``postprocess`` (3.4.7) ->
``display`` -> ``shading`` (colours, fog, sky) -> ``pipeline`` -> ``worker`` (3.5.4).
"""
