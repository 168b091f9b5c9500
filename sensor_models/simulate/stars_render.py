"""TEMPORARY: the point-source PSF kernels now live in :mod:`sensor_models.psf`.

Only :mod:`gcpmatch.starfind` still imports this module; the helper splitting that module
switches its import to ``from sensor_models.psf import pixel_integrals, render_stars``. Delete
this file once that change is merged (``tests/test_layers.py`` lists the import in
``KNOWN_PENDING``).
"""

from sensor_models.psf import pixel_integrals, render_stars

__all__ = ["pixel_integrals", "render_stars"]
