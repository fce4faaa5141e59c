"""Chapter 5 internals: spline skinning, deformation styles, baselines, fitting, glTF rigs.

Public names come from :mod:`jaxgfx.skin`, whose docstring maps thesis sections to these modules.
"""
