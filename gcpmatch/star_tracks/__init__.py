"""Stars in camera frames: FITS input, background, detection and centroids, identification.

Star calibration of a geostationary camera (seed 000, section 2.1) starts from the centroids
of star images and the catalogue stars they are. One module per job:

* :mod:`~gcpmatch.star_tracks.fits` -- FITS images (through :mod:`astropy.io.fits`), SExtractor
  catalogues, and the FITS 1-based pixel convention <-> project ``(row, col)``;
* :mod:`~gcpmatch.star_tracks.background` -- background level and noise maps;
* :mod:`~gcpmatch.star_tracks.detect` -- detection, segmentation and sub-pixel centroids;
* :mod:`~gcpmatch.star_tracks.identify` -- star identification from a pointing or lost in space;
* :mod:`~gcpmatch.star_tracks.patterns` -- the catalogue triangle index lost in space looks up.

Coordinates follow the project convention: ``(row, col)`` with the centre of the first pixel
at ``(0.5, 0.5)``.
"""

from gcpmatch.star_tracks.background import Background, estimate_background, estimate_background_sep
from gcpmatch.star_tracks.detect import (
    CENTROID_METHODS,
    FLAG_EDGE,
    FLAG_FIT_FAILED,
    FLAG_SATURATED,
    StarTable,
    centroid_stars,
    detect_stars,
)
from gcpmatch.star_tracks.fits import (
    fits_to_rowcol,
    read_fits_image,
    read_sextractor_catalog,
    rowcol_to_fits,
)
from gcpmatch.star_tracks.identify import CameraPointing, StarIdentification, identify_stars
from gcpmatch.star_tracks.patterns import StarPatternIndex

__all__ = [
    "CENTROID_METHODS",
    "FLAG_EDGE",
    "FLAG_FIT_FAILED",
    "FLAG_SATURATED",
    "Background",
    "CameraPointing",
    "StarIdentification",
    "StarPatternIndex",
    "StarTable",
    "centroid_stars",
    "detect_stars",
    "estimate_background",
    "estimate_background_sep",
    "fits_to_rowcol",
    "identify_stars",
    "read_fits_image",
    "read_sextractor_catalog",
    "rowcol_to_fits",
]
