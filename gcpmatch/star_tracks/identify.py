"""Star identification: which catalogue star each centroid is.

(a) With an approximate pointing (:class:`CameraPointing`): project the catalogue, vote for the
    offset, match mutual nearest neighbours within a tolerance, solve the rotation (Wahba's
    problem by SVD [1]_) and the focal length, and re-match until the set is stable.
(b) Lost in space: triangles of the brightest detections, keyed by their two side ratios, are
    looked up in a hash of catalogue triangles
    (:class:`~gcpmatch.star_tracks.patterns.StarPatternIndex`); each candidate
    gives an attitude hypothesis that is verified against the other detections, then refined
    by (a) [2]_.

Camera frame: ``x`` along increasing columns, ``y`` along increasing rows, ``z`` along the
boresight (right-handed); a pixel ``(row, col)`` (first pixel's centre at ``(0.5, 0.5)``) sees
the direction ``((col - c0) / f, (row - r0) / f, 1)``. With roll 0 the top of the image
(decreasing rows) points to the north celestial pole and east is on the left, as the sky is
seen; the roll is the position angle of the image's top, from north through east.

References
----------
.. [1] G. Wahba, "A least squares estimate of satellite attitude", SIAM Review 7, 409 (1965);
   W. Kabsch, Acta Cryst. A32, 922-923 (1976) (the SVD solution).
.. [2] C. C. Liebe, "Pattern recognition of star constellations for spacecraft applications",
   IEEE AES Magazine 8(1), 31-39 (1993) (angular-distance star patterns);
   G. Brown and ESA, tetra3 (lost-in-space solving by hashed star patterns, 2019).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from scipy.stats import binom

from gcpmatch.star_tracks.patterns import StarPatternIndex, angle_between
from sensor_models.errors import InputError

__all__ = ["CameraPointing", "StarIdentification", "identify_stars"]

ARCSEC_PER_RAD = 180.0 * 3600.0 / np.pi


@dataclass(frozen=True, eq=False)
class CameraPointing:
    """A pinhole camera's attitude and focal length, enough to project stars.

    Attributes
    ----------
    camera_to_gcrf : scipy.spatial.transform.Rotation
        Rotation taking camera-frame vectors (x = +col, y = +row, z = boresight) to GCRF.
    focal_px : float
        Focal length in pixels.
    principal_point_px : tuple of float
        ``(row, col)`` where the boresight meets the image.
    """

    camera_to_gcrf: Rotation
    focal_px: float
    principal_point_px: tuple[float, float]

    @classmethod
    def from_boresight(cls, ra_rad: float, dec_rad: float, roll_rad: float, *,
                       focal_px: float, principal_point_px) -> CameraPointing:
        """Pointing from the boresight's right ascension, declination and the roll.

        The roll is the position angle of the image's top (decreasing rows) measured from
        north through east; with roll 0, north is up and east left. Camera axes in GCRF:
        ``z = b`` (boresight), ``y = -up`` with ``up = cos(roll) n + sin(roll) e``,
        ``x = b x up`` (``n``, ``e``: north and east unit vectors at ``b``).

        Parameters
        ----------
        ra_rad, dec_rad : float
            Boresight right ascension and declination in GCRF, radians.
        roll_rad : float
            Position angle of the image's top, from north through east, radians.
        focal_px : float
            Focal length, pixels.
        principal_point_px : (float, float)
            ``(row, col)`` of the boresight, pixels (first pixel's centre at ``(0.5, 0.5)``).

        Returns
        -------
        CameraPointing
        """
        ca, sa, cd, sd = np.cos(ra_rad), np.sin(ra_rad), np.cos(dec_rad), np.sin(dec_rad)
        bore = np.array([cd * ca, cd * sa, sd])
        north = np.array([-sd * ca, -sd * sa, cd])
        east = np.array([-sa, ca, 0.0])
        up = np.cos(roll_rad) * north + np.sin(roll_rad) * east
        mat = np.column_stack([np.cross(bore, up), -up, bore])
        return cls(Rotation.from_matrix(mat), float(focal_px),
                   (float(principal_point_px[0]), float(principal_point_px[1])))

    @property
    def boresight_gcrf(self) -> np.ndarray:
        """Unit boresight vector in GCRF, shape (3,)."""
        return self.camera_to_gcrf.as_matrix()[:, 2]

    @property
    def ra_dec_roll_rad(self) -> tuple[float, float, float]:
        """Boresight right ascension, declination and roll (see :meth:`from_boresight`)."""
        mat = self.camera_to_gcrf.as_matrix()
        bore, up = mat[:, 2], -mat[:, 1]
        ra = float(np.mod(np.arctan2(bore[1], bore[0]), 2 * np.pi))
        dec = float(np.arctan2(bore[2], np.hypot(bore[0], bore[1])))
        ca, sa, cd, sd = np.cos(ra), np.sin(ra), np.cos(dec), np.sin(dec)
        north = np.array([-sd * ca, -sd * sa, cd])
        east = np.array([-sa, ca, 0.0])
        roll = float(np.mod(np.arctan2(up @ east, up @ north), 2 * np.pi))
        return ra, dec, roll

    def project(self, vectors_gcrf) -> tuple[np.ndarray, np.ndarray]:
        """Pixel positions of directions.

        Parameters
        ----------
        vectors_gcrf : array_like, shape (N, 3)
            Directions in GCRF (any length).

        Returns
        -------
        rowcol : ndarray, shape (N, 2)
            ``r0 + f y/z``, ``c0 + f x/z`` in the camera frame (NaN behind the camera).
        in_front : ndarray of bool, shape (N,)
        """
        v = np.asarray(vectors_gcrf, dtype=np.float64).reshape(-1, 3)
        cam = self.camera_to_gcrf.inv().apply(v) if v.shape[0] else v
        in_front = cam[:, 2] > 1e-9
        z = np.where(in_front, cam[:, 2], np.nan)
        r0, c0 = self.principal_point_px
        return np.stack([r0 + self.focal_px * cam[:, 1] / z,
                         c0 + self.focal_px * cam[:, 0] / z], axis=1), in_front

    def rays(self, rowcol) -> np.ndarray:
        """Unit GCRF directions seen by pixels.

        Parameters
        ----------
        rowcol : array_like, shape (N, 2)
            ``(row, col)`` in pixels, first pixel's centre at ``(0.5, 0.5)``.

        Returns
        -------
        ndarray, shape (N, 3)
            Unit vectors in GCRF.
        """
        cam = _camera_rays(np.asarray(rowcol, np.float64).reshape(-1, 2), self.focal_px,
                           self.principal_point_px)
        return self.camera_to_gcrf.apply(cam) if cam.shape[0] else cam


def _camera_rays(rowcol: np.ndarray, focal_px, principal_point_px) -> np.ndarray:
    r0, c0 = principal_point_px
    x = (rowcol[..., 1] - c0) / focal_px
    y = (rowcol[..., 0] - r0) / focal_px
    x, y = np.broadcast_arrays(x, y)
    v = np.stack([x, y, np.ones(x.shape)], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _kabsch(cam: np.ndarray, sky: np.ndarray, weights=None) -> np.ndarray:
    """Rotation(s) ``R`` minimising ``sum w |sky - R cam|^2`` (Wahba's problem, SVD).

    ``cam``, ``sky``: shape (..., K, 3); returns (..., 3, 3) with ``det R = +1``.
    """
    w = np.ones(cam.shape[:-1]) if weights is None else weights
    b = np.einsum("...k,...ki,...kj->...ij", w, sky, cam)
    u, _, vt = np.linalg.svd(b)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt


@dataclass(frozen=True, eq=False)
class StarIdentification:
    """Outcome of :func:`identify_stars` (``success=False`` with a message when it fails).

    Attributes
    ----------
    success : bool
    message : str
    catalog_index : ndarray of int, shape (N,)
        Catalogue row of each centroid, -1 where unidentified.
    pointing : CameraPointing or None
        Refined attitude and focal length.
    residuals_px : ndarray, shape (N, 2)
        Measured minus projected ``(row, col)`` for identified stars, NaN elsewhere.
    n_matched : int
    rms_px, rms_arcsec : float
        Root-mean-square residual length (NaN when nothing matched).
    false_alarm_probability : float
        Probability that at least this many matches arise by chance from random detections
        (binomial tail with the catalogue's density in the frame).
    method : str
        ``"pointing"`` (a) or ``"lost_in_space"`` (b).
    n_hypotheses : int
        Attitude hypotheses tested (lost in space).
    """

    success: bool
    message: str
    catalog_index: np.ndarray
    pointing: CameraPointing | None
    residuals_px: np.ndarray
    n_matched: int
    rms_px: float
    rms_arcsec: float
    false_alarm_probability: float
    method: str
    n_hypotheses: int = 0
    details: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """JSON-ready figures.

        Returns
        -------
        dict
            Success, message, method, match count, RMS residuals (px, arcsec), false-alarm
            probability, hypotheses, and with a pointing its RA, Dec, roll (degrees) and
            focal length (px).
        """
        out = {"success": self.success, "message": self.message, "method": self.method,
               "n_matched": self.n_matched, "rms_px": self.rms_px,
               "rms_arcsec": self.rms_arcsec,
               "false_alarm_probability": self.false_alarm_probability,
               "n_hypotheses": self.n_hypotheses}
        if self.pointing is not None:
            ra, dec, roll = self.pointing.ra_dec_roll_rad
            out.update(ra_deg=np.rad2deg(ra), dec_deg=np.rad2deg(dec),
                       roll_deg=np.rad2deg(roll), focal_px=self.pointing.focal_px)
        return out


def _failed(message, n, method, n_hyp=0) -> StarIdentification:
    return StarIdentification(False, message, np.full(n, -1), None, np.full((n, 2), np.nan), 0,
                              np.nan, np.nan, 1.0, method, n_hyp)


def identify_stars(
    centroids_px,
    catalog_vectors,
    *,
    image_shape,
    approximate_pointing: CameraPointing | None = None,
    fov_deg: float | None = None,
    focal_px: float | None = None,
    pixel_scale_arcsec: float | None = None,
    principal_point_px=None,
    catalog_magnitudes=None,
    pattern_index: StarPatternIndex | None = None,
    match_tolerance_px: float = 3.0,
    pointing_uncertainty_deg: float = 0.5,
    fov_tolerance: float = 0.1,
    refine_focal: bool = True,
    n_pattern_stars: int = 10,
    n_verify_stars: int = 30,
    min_matches: int = 6,
    false_alarm: float = 1e-9,
    max_iterations: int = 10,
) -> StarIdentification:
    """Identify detected stars against catalogue directions.

    Parameters
    ----------
    centroids_px : array_like, shape (N, 2)
        ``(row, col)`` of the detections, brightest first (as :func:`gcpmatch.star_tracks.detect_stars` returns).
    catalog_vectors : array_like, shape (M, 3)
        Catalogue unit vectors in GCRF (e.g. :func:`sensor_models.geometry.star_catalogue.apparent_directions`).
    image_shape : (int, int)
        ``(H, W)`` of the frame.
    approximate_pointing : CameraPointing, optional
        Known attitude and focal length: method (a). Without it, lost in space (b).
    fov_deg, focal_px, pixel_scale_arcsec : float, optional
        Approximate scale for lost in space, one of them: the horizontal field of view
        across ``W`` pixels, the focal length in pixels, or the pixel scale at the centre.
    principal_point_px : (float, float), optional
        ``(row, col)`` of the boresight; default the image centre ``(H / 2, W / 2)``.
    catalog_magnitudes : array_like, shape (M,), optional
        Needed by lost in space to pick the pattern stars (unless ``pattern_index`` is given).
    pattern_index : StarPatternIndex, optional
        A prebuilt index, reusable across frames and dates (it may hold catalogue positions
        while ``catalog_vectors`` are apparent places: only the hypotheses come from it);
        built with :meth:`StarPatternIndex.for_camera` otherwise (~1 s).
    match_tolerance_px : float, optional
        Final matching radius.
    pointing_uncertainty_deg, fov_tolerance : float, optional
        (a) Radius searched for the initial offset between the projected catalogue and the
        detections, degrees; (b) relative uncertainty of the given scale.
    refine_focal : bool, optional
        Estimate the focal length with the rotation.
    n_pattern_stars, n_verify_stars : int, optional
        (b) Brightest detections combined into triangles, and used to verify a hypothesis.
    min_matches : int, optional
        Fewest identified stars for success.
    false_alarm : float, optional
        Largest accepted probability that the matches are chance coincidences.
    max_iterations : int, optional
        Match / solve iterations in (a).

    Returns
    -------
    StarIdentification
    """
    rc, cat, (h, w), pp = _checked_inputs(centroids_px, catalog_vectors, image_shape, principal_point_px)
    n = rc.shape[0]
    if approximate_pointing is not None:
        if n < 3:
            return _failed(f"{n} detections; at least 3 are needed", n, "pointing")
        return _identify_near(rc, cat, approximate_pointing, (h, w), match_tolerance_px,
                              pointing_uncertainty_deg, refine_focal, min_matches, false_alarm,
                              max_iterations)
    f0 = _focal_from_scale((h, w), fov_deg, focal_px, pixel_scale_arcsec)
    pattern_index = _pattern_index_for(pattern_index, cat, catalog_magnitudes, (h, w), f0)
    if n < 4:
        return _failed(f"{n} detections; lost in space needs at least 4", n, "lost_in_space")
    return _lost_in_space(rc, cat, cKDTree(cat), pattern_index, (h, w), pp, f0, match_tolerance_px,
                          fov_tolerance, refine_focal, n_pattern_stars, n_verify_stars,
                          min_matches, false_alarm, max_iterations)


def _checked_inputs(centroids_px, catalog_vectors, image_shape, principal_point_px):
    """Centroids (N, 2), catalogue vectors (M, 3), ``(H, W)`` and the principal point, checked."""
    rc = np.asarray(centroids_px, dtype=np.float64).reshape(-1, 2)
    cat = np.asarray(catalog_vectors, dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(rc)):
        raise InputError("centroids hold NaN or infinite values", field="centroids_px")
    if cat.shape[0] == 0 or not np.all(np.isfinite(cat)):
        raise InputError("empty or non-finite catalogue vectors", field="catalog_vectors")
    h, w = (int(image_shape[0]), int(image_shape[1]))
    pp = (h / 2.0, w / 2.0) if principal_point_px is None else (
        float(principal_point_px[0]), float(principal_point_px[1]))
    return rc, cat, (h, w), pp


def _pattern_index_for(pattern_index, cat, catalog_magnitudes, shape, f0):
    """``pattern_index``, or one built for the camera from the catalogue and its magnitudes."""
    if pattern_index is not None:
        return pattern_index
    if catalog_magnitudes is None:
        raise InputError("lost in space needs catalog_magnitudes (or a pattern_index)",
                         field="catalog_magnitudes")
    return StarPatternIndex.for_camera(cat, catalog_magnitudes, image_shape=shape, focal_px=f0)


def _identify_near(rc, cat, ap: CameraPointing, shape, tol, uncertainty_deg, refine_focal,
                   min_matches, false_alarm, max_iterations) -> StarIdentification:
    """Method (a) on the catalogue stars around the approximate pointing only (a small tree
    instead of the whole sky's); catalogue indices are mapped back to ``cat``'s rows."""
    h, w = shape
    corner = np.hypot(max(ap.principal_point_px[0], h - ap.principal_point_px[0]),
                      max(ap.principal_point_px[1], w - ap.principal_point_px[1]))
    reach = np.arctan(corner / ap.focal_px) + np.deg2rad(uncertainty_deg) \
        + 20.0 * tol / ap.focal_px
    near = np.flatnonzero(cat @ ap.boresight_gcrf > np.cos(min(reach, np.pi)))
    if near.size == 0:
        return _failed("no catalogue star near the approximate pointing", rc.shape[0],
                       "pointing")
    result = _refine(rc, cat[near], cKDTree(cat[near]), ap, shape, tol, uncertainty_deg,
                     refine_focal, min_matches, false_alarm, max_iterations, "pointing", 0)
    known = result.catalog_index >= 0
    result.catalog_index[known] = near[result.catalog_index[known]]
    return result


def _focal_from_scale(shape, fov_deg, focal_px, pixel_scale_arcsec) -> float:
    """Focal length in pixels from exactly one of the three scale options."""
    scales = [x is not None for x in (fov_deg, focal_px, pixel_scale_arcsec)]
    if sum(scales) != 1:
        raise InputError("lost-in-space identification needs exactly one of fov_deg, "
                         "focal_px, pixel_scale_arcsec (or give approximate_pointing)")
    if fov_deg is not None:
        if not (0 < fov_deg < 120):
            raise InputError("must lie in (0, 120) degrees", field="fov_deg")
        f0 = (shape[1] / 2.0) / np.tan(np.deg2rad(fov_deg) / 2.0)
    elif focal_px is not None:
        f0 = float(focal_px)
    else:
        f0 = ARCSEC_PER_RAD / float(pixel_scale_arcsec)
    if not (f0 > 0 and np.isfinite(f0)):
        raise InputError("the scale must be positive and finite")
    return f0


def _false_alarm(n_matched: int, n_det: int, n_cat_in_frame: int, tol_px: float,
                 frame_area_px: float, n_given: int = 0) -> float:
    """Probability of ``>= n_matched`` chance matches among ``n_det`` random detections.

    A random detection falls within ``tol_px`` of one of ``n_cat_in_frame`` projected stars
    with probability ``p = n_cat pi tol^2 / area``; ``n_given`` matches are not counted
    (those that defined the hypothesis).
    """
    p = min(1.0, n_cat_in_frame * np.pi * tol_px ** 2 / frame_area_px)
    k = n_matched - n_given
    if k <= 0:
        return 1.0
    return float(binom.sf(k - 1, max(n_det - n_given, 0), p))


def _in_frame(pointing: CameraPointing, cat: np.ndarray, tree: cKDTree, shape, margin_px):
    """Catalogue rows projecting inside the frame (+ margin) and their pixel positions."""
    h, w = shape
    f = pointing.focal_px
    half_diag = np.hypot(h, w) / 2.0 + margin_px + np.hypot(
        pointing.principal_point_px[0] - h / 2, pointing.principal_point_px[1] - w / 2)
    radius = np.arctan(half_diag / f)
    idx = np.asarray(tree.query_ball_point(pointing.boresight_gcrf,
                                           2 * np.sin(min(radius, np.pi / 2.01) / 2)),
                     dtype=np.intp)
    if idx.size == 0:
        return idx, np.zeros((0, 2))
    proj, front = pointing.project(cat[idx])
    inside = front & (proj[:, 0] > -margin_px) & (proj[:, 0] < h + margin_px) \
        & (proj[:, 1] > -margin_px) & (proj[:, 1] < w + margin_px)
    return idx[inside], proj[inside]


def _mutual_matches(rc: np.ndarray, proj: np.ndarray, tol: float):
    """Mutual nearest neighbours within ``tol``: (detection index, projection index)."""
    if proj.shape[0] == 0 or rc.shape[0] == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    d1, j = cKDTree(proj).query(rc, distance_upper_bound=tol)
    _, i_back = cKDTree(rc).query(proj)
    det = np.flatnonzero(np.isfinite(d1))
    mutual = i_back[j[det]] == det
    return det[mutual], j[det[mutual]]


def _solve_pointing(rc, sky, pointing: CameraPointing, refine_focal: bool,
                    iterations: int = 5) -> CameraPointing:
    """Rotation by SVD (Wahba) alternating with the linear focal-length update.

    With the rotation fixed, the tangent-plane coordinates ``t = (x/z, y/z)`` of the catalogue
    directions in the camera frame and the measured ``m = (col - c0, row - r0)`` give
    ``f = sum m.t / sum t.t``.
    """
    f = pointing.focal_px
    pp = pointing.principal_point_px
    rot = pointing.camera_to_gcrf.as_matrix()
    m = np.stack([rc[:, 1] - pp[1], rc[:, 0] - pp[0]], axis=1)
    for _ in range(iterations if refine_focal else 1):
        rot = _kabsch(_camera_rays(rc, f, pp), sky)
        if not refine_focal or rc.shape[0] < 3:
            break
        cam = sky @ rot  # rows: R^T s
        t = cam[:, :2] / cam[:, 2:3]
        f_new = float(np.sum(m * t) / np.sum(t * t))
        if not (np.isfinite(f_new) and f_new > 0):
            break
        converged = abs(f_new - f) < 1e-9 * f
        f = f_new
        if converged:
            break
    return CameraPointing(Rotation.from_matrix(rot), f, pp)


def _offset_vote(rc: np.ndarray, proj: np.ndarray, radius: float, bin_px: float):
    """Most common offset ``detection - projection`` within ``radius``.

    The offsets of all pairs closer than ``radius`` are histogrammed in bins of ``bin_px``;
    the fullest bin's centre is then refined by two mean-shift steps (mean of the offsets
    within one bin of the estimate).
    """
    if proj.shape[0] == 0 or rc.shape[0] == 0:
        return np.zeros(2)
    pairs = cKDTree(proj).query_ball_point(rc, radius)
    det = np.repeat(np.arange(rc.shape[0]), [len(p) for p in pairs])
    if det.size == 0:
        return np.zeros(2)
    prj = np.fromiter((j for p in pairs for j in p), dtype=np.intp, count=det.size)
    diff = rc[det] - proj[prj]
    nbin = max(1, int(np.ceil(2 * radius / bin_px)))
    hist, er, ec = np.histogram2d(diff[:, 0], diff[:, 1], bins=nbin,
                                  range=[[-radius, radius], [-radius, radius]])
    i, j = np.unravel_index(np.argmax(hist), hist.shape)
    guess = np.array([(er[i] + er[i + 1]) / 2, (ec[j] + ec[j + 1]) / 2])
    for _ in range(2):
        near = np.linalg.norm(diff - guess, axis=1) < bin_px
        if not near.any():
            break
        guess = diff[near].mean(axis=0)
    return guess


def _robust_solve(rc, sky, pointing: CameraPointing, refine_focal: bool, tol: float):
    """:func:`_solve_pointing`, then again without the pairs whose residual exceeds
    ``max(3 x 1.4826 MAD, tol / 2)`` (mismatches caught in a wide search radius)."""
    solved = _solve_pointing(rc, sky, pointing, refine_focal)
    proj, _ = solved.project(sky)
    res = np.linalg.norm(rc - proj, axis=1)
    limit = max(3.0 * 1.4826 * np.median(res), tol / 2.0)
    keep = res <= limit
    if 3 <= keep.sum() < keep.size:
        solved = _solve_pointing(rc[keep], sky[keep], solved, refine_focal and keep.sum() >= 4)
    return solved


def _refine(rc, cat, tree, pointing: CameraPointing, shape, tol, uncertainty_deg,
            refine_focal, min_matches, false_alarm, max_iterations, method, n_hyp,
            n_given: int = 0) -> StarIdentification:
    """Method (a): offset vote, then match / solve with a shrinking radius until stable.

    The matching radius goes ``4 tol, 2 tol, tol`` (roll and scale errors of the starting
    pointing grow with the distance from the centre); each solve drops outlying pairs.
    """
    n = rc.shape[0]
    h, w = shape
    radius = pointing.focal_px * np.tan(np.deg2rad(uncertainty_deg))
    if radius > tol:
        idx, proj = _in_frame(pointing, cat, tree, shape, radius)
        shift = _offset_vote(rc, proj, radius, bin_px=2.0 * tol)
        det, prj = _mutual_matches(rc, proj + shift, 4.0 * tol)
        if det.size >= 3:
            pointing = _robust_solve(rc[det], cat[idx[prj]], pointing, False, 4.0 * tol)
    radii = (4.0 * tol, 2.0 * tol, tol)
    previous = None
    for it in range(max(max_iterations, len(radii))):
        radius_it = radii[min(it, len(radii) - 1)]
        idx, proj = _in_frame(pointing, cat, tree, shape, radius_it)
        det, prj = _mutual_matches(rc, proj, radius_it)
        if det.size < 3:
            return _failed(f"only {det.size} stars matched within {radius_it:.1f} px", n,
                           method, n_hyp)
        key = (radius_it, tuple(det), tuple(idx[prj]))
        if key == previous:
            break
        previous = key
        pointing = _robust_solve(rc[det], cat[idx[prj]], pointing,
                                 refine_focal and det.size >= 4, radius_it)
    idx, proj = _in_frame(pointing, cat, tree, shape, tol)
    det, prj = _mutual_matches(rc, proj, tol)
    catalog_index = np.full(n, -1)
    catalog_index[det] = idx[prj]
    residuals = np.full((n, 2), np.nan)
    residuals[det] = rc[det] - proj[prj]
    rms = float(np.sqrt(np.mean(np.sum(residuals[det] ** 2, axis=1)))) if det.size else np.nan
    fa = _false_alarm(det.size, n, idx.size, tol, float(h * w), n_given)
    ok = det.size >= min_matches and fa <= false_alarm
    msg = (f"{det.size} of {n} stars identified, residual RMS {rms:.3f} px"
           if ok else f"not identified: {det.size} matches (min {min_matches}), chance "
           f"probability {fa:.2g} (max {false_alarm:.2g})")
    return StarIdentification(
        ok, msg, catalog_index, pointing, residuals, int(det.size), rms,
        rms * ARCSEC_PER_RAD / pointing.focal_px, fa, method, n_hyp,
        details={"n_catalog_in_frame": int(idx.size)},
    )


def _image_triangles(n: int) -> np.ndarray:
    """Index triples ``i < j < k < n``, ordered so that triangles of brighter stars come first."""
    out = [(i, j, k) for k in range(2, n) for j in range(1, k) for i in range(j)]
    return np.array(out, dtype=np.intp).reshape(-1, 3)


def _lost_in_space(rc, cat, tree, index: StarPatternIndex, shape, pp, f0, tol, fov_tol,
                   refine_focal, n_pattern, n_verify, min_matches, false_alarm,
                   max_iterations) -> StarIdentification:
    """Method (b): triangle hypotheses from the index, verified, then refined by (a)."""
    n = rc.shape[0]
    h, w = shape
    rays0 = _camera_rays(rc, f0, pp)
    top = min(n, n_pattern)
    ver = min(n, n_verify)
    tris = _image_triangles(top)
    v = rays0[tris]
    opp = np.stack([angle_between(v[:, 1], v[:, 2]), angle_between(v[:, 0], v[:, 2]),
                    angle_between(v[:, 0], v[:, 1])], axis=1)
    order = np.argsort(opp, axis=1, kind="stable")
    tris = np.take_along_axis(tris, order, axis=1)
    sides = np.take_along_axis(opp, order, axis=1)
    # unambiguous vertex order and a size the index covers
    gap = np.minimum(sides[:, 1] - sides[:, 0], sides[:, 2] - sides[:, 1]) / sides[:, 2]
    usable = (gap > 2.0 * index.bin_width) & (sides[:, 2] <= index.max_side_rad * (1 + fov_tol)) \
        & (sides[:, 0] > 10.0 / f0)
    tris, sides = tris[usable], sides[usable]
    v = rays0[tris]
    hand = np.sign(np.einsum("ti,ti->t", v[:, 0], np.cross(v[:, 1], v[:, 2])))
    n_hyp = 0
    verify_tol = 2.0 * tol
    frame_area = float(h * w)
    for t in range(tris.shape[0]):
        r1, r2 = sides[t, 0] / sides[t, 2], sides[t, 1] / sides[t, 2]
        cand = index.query(r1, r2)
        if cand.size == 0:
            continue
        cand = cand[index.handedness[cand] == hand[t]]
        scale = sides[t, 2] / index.long_side_rad[cand]  # ~ f_true / f0
        cand = cand[np.abs(scale - 1.0) <= fov_tol]
        if cand.size == 0:
            continue
        scale = sides[t, 2] / index.long_side_rad[cand].astype(np.float64)
        n_hyp += cand.size
        f_h = f0 * scale
        # hypotheses: rotation from the three correspondences, rays with each focal length
        cam = _camera_rays(rc[tris[t]][None, :, :], f_h[:, None], pp)  # (H, 3, 3)
        sky = index.vectors[index.triangles[cand]]  # (H, 3, 3)
        rot = _kabsch(cam, sky)
        # verify: the brightest detections must land on catalogue stars
        cam_v = _camera_rays(rc[None, :ver, :], f_h[:, None], pp)  # (H, V, 3)
        sky_v = np.einsum("hij,hvj->hvi", rot, cam_v)
        tol_rad = verify_tol / f_h
        dist, _ = tree.query(sky_v.reshape(-1, 3), distance_upper_bound=float(tol_rad.max()))
        hits = (dist.reshape(cand.size, ver) <= tol_rad[:, None]).sum(axis=1)
        best = int(np.argmax(hits))
        if hits[best] < min(min_matches, ver):
            continue
        pointing = CameraPointing(Rotation.from_matrix(rot[best]), float(f_h[best]), pp)
        idx_in, _ = _in_frame(pointing, cat, tree, shape, 0.0)
        if _false_alarm(int(hits[best]), ver, idx_in.size, verify_tol, frame_area, 3) \
                > false_alarm:
            continue
        result = _refine(rc, cat, tree, pointing, shape, tol, 0.0, refine_focal, min_matches,
                         false_alarm, max_iterations, "lost_in_space", n_hyp, n_given=3)
        if result.success:
            return result
    return _failed(f"no verified attitude after {n_hyp} hypotheses from {tris.shape[0]} "
                   "triangles", n, "lost_in_space", n_hyp)
