"""One CCD of a push-broom model seen as a model of its own image.

A stitched multi-CCD raster maps the ground discontinuously where CCDs overlap, so an RPC (or any
smooth approximation) describes one CCD at a time: :class:`CcdView` (made by
:meth:`PushbroomModel.detector_view <sensor_models.models.pushbroom.PushbroomModel.detector_view>`) is
that CCD with its columns counted from 0, delegating everything to the parent model
(``PushbroomModel`` below is :class:`sensor_models.models.pushbroom.PushbroomModel`).
"""

from __future__ import annotations

import numpy as np

from sensor_models.base import DetectorArray, ParameterVector, SensorModel

__all__ = ["CcdView"]


class CcdView(SensorModel):
    """A single CCD of a :class:`~sensor_models.models.pushbroom.PushbroomModel` seen as an image of its own.

    ``col_view = col_scene - ccd.first_col``; rows are unchanged. Parameters (and parameter
    groups) are those of the parent model. Its one band is the CCD's band and its one detector
    array is the CCD, starting at column 0; ``band=`` arguments of the localization methods
    are ignored (the view's band is fixed).

    Parameters
    ----------
    model : sensor_models.models.pushbroom.PushbroomModel
        The parent model.
    band : str
        The band.
    ccd : str or int
        CCD name or index in ``model.band_ccds(band)``.
    """

    kind = "pushbroom_ccd"
    is_rigorous = True

    def __init__(self, model, *, band: str, ccd):
        self.model = model
        self.band = band
        self.index = int(model.ccd_index(np.zeros(1), band=band, array=ccd)[0])
        self.ccd = model.band_ccds(band)[self.index]

    @property
    def image_shape(self) -> tuple[int, int]:
        """``(n_rows, n_detectors)`` of the CCD."""
        return (self.model.n_rows, self.ccd.n_detectors)

    @property
    def reference_band(self) -> str:
        """The CCD's band."""
        return self.band

    def detector_arrays(self, band=None) -> tuple[DetectorArray, ...]:
        """The CCD, as one array starting at the view's column 0.

        Parameters
        ----------
        band : str, optional
            None or the view's band.

        Returns
        -------
        tuple of DetectorArray
            ``(DetectorArray(ccd.name, 0, ccd.n_detectors),)``.
        """
        self._protocol_band(band)
        return (DetectorArray(self.ccd.name, 0, self.ccd.n_detectors),)

    def parameter_groups(self) -> dict[str, tuple[str, ...]]:
        """The parent model's groups (:meth:`PushbroomModel.parameter_groups`).

        Returns
        -------
        dict of str to tuple of str
        """
        return self.model.parameter_groups()

    def interior_group(self, band=None, array=None) -> str:
        """The group of this CCD's directional-angle coefficients.

        Parameters
        ----------
        band : str, optional
            None or the view's band.
        array : str or int, optional
            None, 0 or the CCD's name.

        Returns
        -------
        str
            ``"interior.<band>.<ccd>"``.
        """
        self._one_array(band, array)
        return self.model.interior_group(self.band, self.index)

    def _parent_ccd(self, array):
        self._check_array(None, array)
        return self.index

    def image_to_ground(self, row, col, *, height=None, dem=None, band=None, array=None):
        """Direct localization in view coordinates (:meth:`PushbroomModel.image_to_ground`).

        Parameters
        ----------
        row, col : array_like
            View coordinates (``col = 0.5`` is the CCD's first detector centre).
        height : float or array_like, optional
            Ellipsoidal heights, metres (exactly one of ``height`` and ``dem``).
        dem : sensor_models.terrain.dem.Dem, optional
            Terrain to intersect.
        band : str, optional
            Ignored: the view's band is fixed.
        array : str or int, optional
            None, 0 or the CCD's name.

        Returns
        -------
        lon_deg, lat_deg, h_m : ndarray, shape of the broadcast ``row, col``
        """
        ccd = self._parent_ccd(array)
        col = np.asarray(col, dtype=np.float64) + self.ccd.first_col
        return self.model.image_to_ground(row, col, height=height, dem=dem, band=self.band, array=ccd)

    def ground_to_image(self, lon, lat, h, *, band=None, array=None):
        """Inverse localization into view coordinates (:meth:`PushbroomModel.ground_to_image`).

        Parameters
        ----------
        lon, lat : array_like
            WGS84 longitude and latitude, degrees.
        h : array_like
            Height above the ellipsoid, metres.
        band : str, optional
            Ignored: the view's band is fixed.
        array : str or int, optional
            None, 0 or the CCD's name.

        Returns
        -------
        row, col : ndarray, shape of the broadcast inputs
        """
        row, col = self.model.ground_to_image(lon, lat, h, band=self.band, array=self._parent_ccd(array))
        return row, col - self.ccd.first_col

    def parameters(self) -> ParameterVector:
        """The parent model's parameters.

        Returns
        -------
        ParameterVector
        """
        return self.model.parameters()

    def with_parameters(self, values) -> "CcdView":
        """The same CCD of the parent model with new parameter values.

        Parameters
        ----------
        values : array_like, shape (P,)
            In the order of the parent's :meth:`PushbroomModel.parameter_names`.

        Returns
        -------
        CcdView
        """
        return CcdView(self.model.with_parameters(values), band=self.band, ccd=self.index)

    def image_jacobian(self, lon, lat, h, *, band=None, names=None, array=None):
        """``d(row, col)/d(parameters)`` in view coordinates (:meth:`PushbroomModel.image_jacobian`).

        Parameters
        ----------
        lon, lat, h : array_like, shape (N,)
            Ground points: degrees, degrees, metres above the ellipsoid.
        band : str, optional
            Ignored: the view's band is fixed.
        names : sequence of str, optional
            Parameters (default: all of the parent's).
        array : str or int, optional
            None, 0 or the CCD's name.

        Returns
        -------
        row, col : ndarray, shape (N,)
        jac : ndarray, shape (N, 2, P)
        """
        row, col, jac = self.model.image_jacobian(
            lon, lat, h, band=self.band, names=names, array=self._parent_ccd(array)
        )
        return row, col - self.ccd.first_col, jac
