"""Coarse stage: SIFT matches between the scene and the DOM, RANSAC, model pre-correction.

1. The scene band is averaged down by an integer factor ``f`` (longest side <= ``target_px``, but
   the shorter side kept at ``MIN_REDUCED_SIDE_PX`` or more: a wide swath over few lines stays
   a strip SIFT can work in);
   the DOM is read over the model's predicted footprint plus a search margin of
   ``max_offset_px`` scene pixels, averaged down to the same ground resolution.
2. The reduced scene is warped into the DOM's frame by the affine map the current model
   predicts (image -> map at mid-DEM height). Raw push-broom images are mirrored and rotated
   against north-up maps and SIFT descriptors are not mirror invariant; after this warp what
   is left is the model's error (offset, a few degrees of rotation, scale), which SIFT and
   RANSAC absorb.
3. SIFT (OpenCV) on both, approximate nearest neighbours (FLANN randomized k-d trees, Muja &
   Lowe 2009, seeded; with the torch backends the exact two nearest neighbours, found on the
   device: :mod:`gcpmatch._features_torch`) with Lowe's ratio test (0.8), and RANSAC of an
   affine map between the warped scene and the DOM (threshold ``ransac_px``). The feature budget adapts to the scene:
   the strongest ``FIRST_FEATURE_BUDGET`` keypoints of the scene first (``n_features`` in the
   DOM), and only where RANSAC keeps fewer than ``MIN_FIRST_INLIERS`` of their matches (clouds,
   texture-poor ground, a large error), the full ``n_features`` in both.
4. The inliers become ground points (DOM position, DEM height) and the model's exterior is
   fitted to them in ground space (:func:`gcpmatch.precorrect.fit_exterior_in_ground`), then all
   ratio-test matches are re-screened against the corrected model and each CCD's offset is
   removed (:func:`gcpmatch.precorrect.fit_ccd_offsets`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import pyproj

from gcpmatch.coarse_skip import within_fine_radius
from gcpmatch.precorrect import fit_ccd_offsets, fit_exterior_in_ground, ground_distance_m
from gcpmatch.reference import grid_resolution_m, scene_gsd_m
from sensor_models.errors import GcpcalError

__all__ = ["MIN_REDUCED_SIDE_PX", "CoarseResult", "coarse_match", "reduction_factor", "to_uint8"]


class CoarseMatchError(GcpcalError, RuntimeError):
    """The coarse stage found no consistent set of matches."""


@dataclass
class CoarseResult:
    """Outcome of :func:`coarse_match`.

    Attributes
    ----------
    model : SensorModel
        The pre-corrected model.
    n_keypoints_scene, n_keypoints_dom : int
        SIFT keypoints detected in the warped, reduced scene and in the reduced DOM.
    n_matches : int
        Matches passing Lowe's ratio test.
    n_ransac_inliers : int
        Matches consistent with the RANSAC map.
    n_inliers : int
        Matches kept after re-screening against the corrected model.
    rms_m : float
        Ground-space RMS of the kept matches about the corrected model, metres.
    factor : int
        Scene reduction factor of the coarse stage.
    ccd_offsets_px : dict
        Per-CCD offsets removed, pixels (empty for models without CCDs).
    points : dict of ndarray, shape (n_inliers,)
        ``row, col`` (continuous scene pixels, first pixel's centre at (0.5, 0.5)), ``lon,
        lat`` (degrees) and ``h`` (metres above the ellipsoid) of the kept matches.
    """

    model: object
    n_keypoints_scene: int
    n_keypoints_dom: int
    n_matches: int
    n_ransac_inliers: int
    n_inliers: int
    rms_m: float
    factor: int
    ccd_offsets_px: dict = field(default_factory=dict)
    points: dict = field(default_factory=dict)  # row, col, lon, lat, h of the final inliers
    dem_coverage: float = 1.0  # fraction of the searched DOM with DEM heights
    note: str = ""

    def summary(self) -> dict:
        """The counts and fit figures as a JSON-ready dict (no model, no points).

        Returns
        -------
        dict
            Keypoints, ratio matches, RANSAC inliers, kept inliers, ``rms_m``, ``factor``,
            ``ccd_offsets_px`` (keys as strings), ``dem_coverage`` (fraction of the DOM searched
            around the scene that has DEM heights) and ``note`` (says when the search was
            restricted to that part).
        """
        return {
            "keypoints_scene": self.n_keypoints_scene, "keypoints_dom": self.n_keypoints_dom,
            "ratio_matches": self.n_matches, "ransac_inliers": self.n_ransac_inliers,
            "inliers": self.n_inliers, "rms_m": self.rms_m, "factor": self.factor,
            "ccd_offsets_px": {str(k): v for k, v in self.ccd_offsets_px.items()},
            "dem_coverage": self.dem_coverage, "note": self.note,
        }


def to_uint8(img: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Stretch the 1-99 % range of the valid pixels to 0..255 (invalid -> 0).

    Parameters
    ----------
    img : ndarray, shape (H, W)
        Image, any real dtype.
    valid : ndarray of bool, shape (H, W), optional
        Pixels to use and keep; default: the finite ones.

    Returns
    -------
    ndarray of uint8, shape (H, W)
        The stretched image, 0 where not valid (all 0 when nothing is valid).
    """
    valid = np.isfinite(img) if valid is None else valid
    if not valid.any():
        return np.zeros(img.shape, np.uint8)
    lo, hi = np.percentile(img[valid], [1.0, 99.0])
    out = (np.clip((img - lo) / max(hi - lo, 1e-6), 0.0, 1.0) * 255.0)
    return np.where(valid, out, 0.0).astype(np.uint8)


def _border(model, band, n=24):
    """Rows and columns of ``n`` points along each of the four image edges (pixel centres)."""
    n_rows, n_cols = model.image_shape
    along = np.linspace(0.5, n_rows - 0.5, n)
    across = np.linspace(0.5, n_cols - 0.5, n)
    rows = np.concatenate([np.full(n, 0.5), np.full(n, n_rows - 0.5), along, along])
    cols = np.concatenate([across, across, np.full(n, 0.5), np.full(n, n_cols - 0.5)])
    return rows, cols


def scene_height_m(model, dem, *, band=None, iterations: int = 3) -> float:
    """Median DEM height under the scene's predicted footprint (fixed point from mid-range).

    A DEM tile can span kilometres of relief around a scene; localizing at its mid-range would
    displace the predicted footprint of an oblique view by hundreds of metres.

    Parameters
    ----------
    model : SensorModel
        Model of the scene, localized at 9 x 9 pixel centres over the image.
    dem : Dem
        Terrain heights above the ellipsoid, metres.
    band : str, optional
        Band of ``model`` (default: the model's reference band).
    iterations : int
        Fixed-point iterations (localize at ``h``, take the median DEM height there).

    Returns
    -------
    float
        Height above the ellipsoid, metres (mid-range of the DEM if the footprint misses it).
    """
    h_lo, h_hi = dem.height_range_m
    h = 0.5 * (h_lo + h_hi)
    n_rows, n_cols = model.image_shape
    gr, gc = np.meshgrid(np.linspace(0.5, n_rows - 0.5, 9), np.linspace(0.5, n_cols - 0.5, 9), indexing="ij")
    for _ in range(iterations):
        lon, lat, _ = model.image_to_ground(gr.ravel(), gc.ravel(), height=h, band=band)
        z = dem.height_m(lon, lat)
        if not np.isfinite(z).any():
            break
        h = float(np.nanmedian(z))
    return h


#: Scene keypoints of the first SIFT pass (the DOM keeps the full budget: its search window is
#: larger than the scene, and where clouds or bare ground leave the scene few features, the DOM's
#: strongest ones would lie elsewhere). Measured, one thread, CPU time of the coarse stage with
#: the brute-force matcher and 12 000 features against FLANN and this budget: realistic demo 2.72
#: -> 0.93 s (pre-correction against the TRUE model 2.37 px rms both), Pleiades tutorial pair
#: 1.42 -> 0.48 s (the two pre-corrections 0.69 px apart), a 60 %-cloud scene 0.23 -> 0.22 px
#: against the TRUE model.
FIRST_FEATURE_BUDGET = 4000
#: RANSAC inliers below which the first pass is not trusted and the full budget runs: an affine
#: map has 6 parameters, and the pre-correction then fits the exterior to the inliers in ground
#: space; 50 leaves it determined several times over where a few outliers survive RANSAC.
MIN_FIRST_INLIERS = 50
#: FLANN randomized k-d trees and leaves checked per query (OpenCV's FlannBasedMatcher).
FLANN_TREES, FLANN_CHECKS = 4, 64


def _sift_features(img, mask, n_features):
    """OpenCV SIFT keypoints and descriptors of a uint8 image, the ``n_features`` strongest
    (``mask`` True where usable)."""
    return cv2.SIFT_create(nfeatures=n_features, contrastThreshold=0.01).detectAndCompute(
        img, mask.astype(np.uint8) * 255)


def _flann_ratio_pairs(des_a, des_b, *, seed: int = 0):
    """FLANN k-d tree two nearest neighbours with Lowe's ratio test (0.8): (query, train) indices.

    The trees are randomized by OpenCV's generator of the calling thread, seeded here, so the
    matches do not depend on what ran before in the process.
    """
    cv2.setRNGSeed(seed)
    matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": FLANN_TREES}, {"checks": FLANN_CHECKS})
    pairs = matcher.knnMatch(des_a, des_b, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.8 * p[1].distance]
    return (np.array([m.queryIdx for m in good], dtype=np.intp), np.array([m.trainIdx for m in good], dtype=np.intp))


def _sift_matches_opencv(scene_features, dom_features, *, seed: int = 0, device=None):
    """Ratio-test matches of two images' SIFT features: FLANN on the CPU (``device`` None), else the
    exact two nearest neighbours on the torch ``device`` (:mod:`gcpmatch._features_torch`).

    Returns
    -------
    pa, pb : ndarray of float32, shape (m, 2)
        Matched keypoint positions (x, y) in each image (OpenCV pixels).
    n_a, n_b : int
        Keypoints of each image.
    """
    (kp_a, des_a), (kp_b, des_b) = scene_features, dom_features
    if des_a is None or des_b is None or len(kp_a) < 2 or len(kp_b) < 2:
        return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32), len(kp_a), len(kp_b)
    if device is None:
        query, train = _flann_ratio_pairs(des_a, des_b, seed=seed)
    else:
        from gcpmatch._features_torch import ratio_test_pairs

        query, train = ratio_test_pairs(des_a, des_b, ratio=0.8, device=device)
    pa = np.float32([kp_a[i].pt for i in query]).reshape(-1, 2)
    pb = np.float32([kp_b[j].pt for j in train]).reshape(-1, 2)
    return pa, pb, len(kp_a), len(kp_b)


def coarse_match(scene: np.ndarray, model, dem, dom, *, band: str | None = None, max_offset_px: float = 1000.0,
                 target_px: int = 1600, ransac_px: float = 2.0, n_features: int = 12000,
                 seed: int = 0, backend: str = "cpu", device=None, skip_within_px: float | None = None) -> CoarseResult:
    """Pre-correct ``model`` so that it lands within a few pixels of the truth (see module doc).

    Parameters
    ----------
    scene : ndarray, shape (n_rows, n_cols)
        The scene band (NaN or 0 = no data are ignored).
    model : SensorModel
        Current model of the scene (e.g. the LAB model).
    dem : Dem
        Terrain heights above the ellipsoid, metres: the height of the matched ground points.
    dom : MapImage
        Reference orthoimage (any projected or geographic CRS).
    band : str, optional
        Band of ``model`` the scene belongs to (default: the model's reference band).
    max_offset_px : float
        Largest expected error of the model, in scene pixels (the DOM search margin).
    target_px : int
        The scene is averaged down by an integer factor until its longest side is at most
        this many pixels, or its shorter side would fall below ``MIN_REDUCED_SIDE_PX``
        (:func:`reduction_factor`).
    ransac_px : float
        RANSAC inlier threshold, reduced-scene pixels.
    n_features : int
        Most SIFT keypoints kept per image.
    seed : int
        Seed of the RANSAC draws.
    backend : {"cpu", "torch"}
        OpenCV SIFT, FLANN ratio-test matching and affine RANSAC; or the same SIFT features and
        RANSAC with the descriptors' exact two nearest neighbours found on the torch ``device``
        (:mod:`gcpmatch._features_torch`: the matches of a brute-force matcher).
    device : str or torch.device, optional
        Torch device of the ``"torch"`` backend (``None``: CUDA if available, else the CPU).
    skip_within_px : float, optional
        The fine stage's search radius, pixels: when a few windows' phase correlation shows
        the model already within half of it, SIFT is skipped and ``model`` is returned
        unchanged, with the note "coarse stage skipped: model within N px"
        (:func:`gcpmatch.coarse_skip.within_fine_radius`); else SIFT runs. None: always SIFT.

    Returns
    -------
    CoarseResult
        The pre-corrected model, match counts, the ground-space RMS (metres) and the final
        inliers (``row, col`` continuous scene pixels, first pixel's centre at (0.5, 0.5)).

    Raises
    ------
    CoarseMatchError
        Too few consistent matches (no texture, wrong area, all clouds), or a DEM that covers
        none of the scene.

    Notes
    -----
    Matches need DEM heights. When the DEM covers only part of the scene the search is
    restricted to that part before SIFT: the DOM is blanked where the DEM has no height (a
    test in true ground coordinates, independent of the model's error), so whatever the DOM
    the same part is searched; the result's ``note`` says so, an error names the coverage.
    """
    if skip_within_px is not None:
        note = within_fine_radius(scene, model, dem, dom, band=band or model.reference_band,
                                  radius_px=float(skip_within_px))
        if note is not None:  # the model as it is, no match counts, the note saying so
            return CoarseResult(model=model, n_keypoints_scene=0, n_keypoints_dom=0, n_matches=0, n_ransac_inliers=0,
                                n_inliers=0, rms_m=float("nan"), factor=1, note=note)
    n_rows, n_cols = scene.shape
    small, small_valid, f = _reduce_scene(scene, target_px)
    h_mid = scene_height_m(model, dem, band=band)
    gsd = scene_gsd_m(model, band=band, height_m=h_mid)
    coarse_res = gsd * f  # metres per reduced pixel
    win = _dom_window(model, dom, band=band, h_mid=h_mid, gsd=gsd, coarse_res=coarse_res,
                      max_offset_px=max_offset_px)
    dem_cover, note = _restrict_to_dem(win, dem)
    a_pred = _predicted_affine(model, band, h_mid, scene.shape, f, win)
    warped, warped_valid = _warp_to_dom(small, small_valid, a_pred)
    ps, pd, n_kp_s, n_kp_d, ransac_in = _sift_ransac(warped, warped_valid, win.dom_small, n_features=n_features,
                                                     ransac_px=ransac_px, seed=seed, backend=backend, device=device)
    row, col, glon, glat, gh = _matches_on_ground(ps, pd, a_pred, f, win, dem)
    inside = (row > 0) & (row < n_rows) & (col > 0) & (col < n_cols) & np.isfinite(gh)
    sel = ransac_in & inside
    if sel.sum() < 6:
        where = "" if not note else f" ({note})"
        raise CoarseMatchError(f"too few RANSAC inliers inside the scene and the DEM: {int(sel.sum())} < 6{where}")
    corrected, keep, rms_m, offsets = _precorrect(model, band, row, col, glon, glat, gh, sel=sel, inside=inside,
                                                  min_scale_m=0.5 * coarse_res)
    return CoarseResult(
        model=corrected, n_keypoints_scene=n_kp_s, n_keypoints_dom=n_kp_d, n_matches=len(ps),
        n_ransac_inliers=int(ransac_in.sum()), n_inliers=int(keep.size), rms_m=rms_m, factor=f,
        ccd_offsets_px=offsets,
        points={"row": row[keep], "col": col[keep], "lon": glon[keep], "lat": glat[keep], "h": gh[keep]},
        dem_coverage=dem_cover, note=note,
    )


#: the reduced scene's shorter side is kept at this many pixels or more (when the scene has them):
#: reduced by its longest side alone, a strip of seed 003's full width (21 800 detectors) over 512
#: lines would be 1557 x 36 px, and SIFT then finds too few matches for RANSAC (measured: "RANSAC
#: found no consistent set of SIFT matches" on that strip, profile realistic; the realistic demo
#: fixture reduced to 73 x 109 px fails the same way, at 256 x 384 px it matches)
MIN_REDUCED_SIDE_PX = 256

#: the re-screening refit on every ratio match is rejected when it moves the RANSAC consensus
#: (median distance) by more than this many times the consensus's own robust spread about the
#: first fit. Measured: 2.4-3.5 on same-band scenes (cloudy ideal scene of tests/test_match.py,
#: Sentinel-2 scenes of bench/change_pairs.py), 43-80 for Sentinel-2 red against
#: near-infrared, where about 20 % of the ratio matches are right
PULLED_FACTOR = 10.0

#: below this fraction of the searched DOM with DEM heights, the search is restricted to them
_FULL_COVER = 0.99


def _restrict_to_dem(win: _DomWindow, dem, step: int = 4):
    """Blank the searched DOM where the DEM has no height (matches need one); coverage and a note.

    The test is on the DOM side, in true ground coordinates, so it does not depend on the
    model's error; it is made on every ``step``-th reduced DOM pixel and enlarged.
    """
    small = win.dom_small
    valid = np.isfinite(small)
    rows = np.arange(0, small.shape[0], step) + 0.5 * min(step, small.shape[0]) - 0.5
    cols = np.arange(0, small.shape[1], step) + 0.5 * min(step, small.shape[1]) - 0.5
    px, py = np.meshgrid(np.minimum(cols, small.shape[1] - 1), np.minimum(rows, small.shape[0] - 1))
    ui, vi = win.small_to_index(px.ravel(), py.ravel())
    inv = ~win.index
    lon, lat = win.from_map.transform(inv.a * ui + inv.b * vi + inv.c, inv.d * ui + inv.e * vi + inv.f)
    with np.errstate(invalid="ignore"):
        has = np.isfinite(dem.height_m(np.asarray(lon), np.asarray(lat))).reshape(px.shape).astype(np.uint8)
    has = cv2.resize(has, (small.shape[1], small.shape[0]), interpolation=cv2.INTER_NEAREST).astype(bool)
    cover = float((has & valid).sum() / max(valid.sum(), 1))
    name = getattr(dem, "source", None) or "the DEM"
    if cover <= 0.0:
        raise CoarseMatchError(f"the DEM covers 0 % of the reference around the scene ({name})")
    if cover >= _FULL_COVER:
        return cover, ""
    win.dom_small = np.where(has, small, np.nan).astype(small.dtype)
    return cover, (f"the DEM covers {100 * cover:.0f} % of the reference searched around the scene ({name}); "
                   "the coarse search was restricted to that part")


def reduction_factor(n_rows: int, n_cols: int, target_px: int) -> int:
    """The integer factor of the coarse stage: longest side <= ``target_px``, shorter side kept at
    ``MIN_REDUCED_SIDE_PX`` or more where the scene has that many pixels.

    Parameters
    ----------
    n_rows, n_cols : int
        Scene size, pixels.
    target_px : int
        Largest reduced side wanted, pixels.

    Returns
    -------
    int
        ``max(1, min(ceil(max(n_rows, n_cols) / target_px), min(n_rows, n_cols) // MIN_REDUCED_SIDE_PX))``.
    """
    by_long = int(np.ceil(max(n_rows, n_cols) / target_px))
    by_short = min(n_rows, n_cols) // MIN_REDUCED_SIDE_PX
    return max(1, min(by_long, by_short))


def _reduce_scene(scene: np.ndarray, target_px: int):
    """The scene averaged down by the integer factor ``f`` of :func:`reduction_factor`.

    Returns
    -------
    small : ndarray of float32, shape (n_rows // f, n_cols // f)
        Block means, no-data as 0.
    small_valid : ndarray of bool, same shape
        Blocks that hold valid pixels only.
    f : int
        The reduction factor.
    """
    n_rows, n_cols = scene.shape
    f = reduction_factor(n_rows, n_cols, target_px)
    valid = np.isfinite(scene) & (scene > 0)
    small = cv2.resize(np.where(valid, scene, 0).astype(np.float32), (n_cols // f, n_rows // f), interpolation=cv2.INTER_AREA)
    small_valid = cv2.resize(valid.astype(np.float32), (n_cols // f, n_rows // f), interpolation=cv2.INTER_AREA) > 0.99
    return small, small_valid, f


@dataclass
class _DomWindow:
    """The DOM read over the scene's predicted footprint plus margin, decimated to the coarse scale.

    ``(r0, c0)`` is the window's first DOM pixel; ``sy, sx`` are DOM pixels per reduced pixel.
    """

    dom_small: np.ndarray
    r0: int
    c0: int
    sy: float
    sx: float
    index: object  # Affine: map (x, y) -> DOM (col, row) index
    to_map: pyproj.Transformer
    from_map: pyproj.Transformer

    def small_to_index(self, px, py):
        """DOM (col, row) indices of reduced-DOM pixel coordinates (OpenCV: centre of [0, 0] at 0)."""
        return self.c0 + (px + 0.5) * self.sx - 0.5, self.r0 + (py + 0.5) * self.sy - 0.5

    def ground_to_index(self, lon, lat):
        """DOM (col, row) indices of WGS84 ``lon, lat`` (degrees)."""
        x, y = self.to_map.transform(lon, lat)
        index = self.index
        u = index.a * np.asarray(x) + index.b * np.asarray(y) + index.c
        v = index.d * np.asarray(x) + index.e * np.asarray(y) + index.f
        return u, v


def _dom_window(model, dom, *, band, h_mid, gsd, coarse_res, max_offset_px) -> _DomWindow:
    """Read the DOM over the predicted footprint plus ``max_offset_px`` scene pixels of margin."""
    dom_res = grid_resolution_m(dom.grid)
    to_map = pyproj.Transformer.from_crs("EPSG:4326", dom.grid.crs, always_xy=True)
    from_map = pyproj.Transformer.from_crs(dom.grid.crs, "EPSG:4326", always_xy=True)
    win = _DomWindow(None, 0, 0, 1.0, 1.0, dom.grid.index_affine(), to_map, from_map)
    # predicted footprint in DOM indices, plus the search margin
    br, bc = _border(model, band)
    lon, lat, _ = model.image_to_ground(br, bc, height=h_mid, band=band)
    u, v = win.ground_to_index(lon, lat)
    margin = max_offset_px * gsd / dom_res
    dr, dc = dom.grid.shape
    r0, r1 = max(0, int(np.nanmin(v) - margin)), min(dr, int(np.nanmax(v) + margin) + 1)
    c0, c1 = max(0, int(np.nanmin(u) - margin)), min(dc, int(np.nanmax(u) + margin) + 1)
    if r1 - r0 < 16 or c1 - c0 < 16:
        raise CoarseMatchError("the DOM does not overlap the scene's predicted footprint")
    k = coarse_res / dom_res  # DOM pixels per reduced pixel
    out_shape = (max(8, int(round((r1 - r0) / k))), max(8, int(round((c1 - c0) / k))))
    win.dom_small = dom.read_decimated(r0, r1, c0, c1, out_shape)
    win.r0, win.c0 = r0, c0
    win.sy, win.sx = (r1 - r0) / out_shape[0], (c1 - c0) / out_shape[1]  # DOM px per reduced DOM px
    return win


def _predicted_affine(model, band, h_mid, shape, f, win: _DomWindow) -> np.ndarray:
    """(2, 3) affine map reduced scene -> reduced DOM as the model predicts, re-positioned.

    It keeps the predicted mirror, rotation and scale but not the position: the model may be
    off by more than the scene's size, so the warped scene gets a canvas of its own.
    """
    n_rows, n_cols = shape
    gr, gc = np.meshgrid(np.linspace(0.5, n_rows - 0.5, 12), np.linspace(0.5, n_cols - 0.5, 12), indexing="ij")
    lon, lat, _ = model.image_to_ground(gr.ravel(), gc.ravel(), height=h_mid, band=band)
    uu, vv = win.ground_to_index(lon, lat)
    src = np.stack([gc.ravel() / f - 0.5, gr.ravel() / f - 0.5], axis=-1)
    dst = np.stack([(uu - win.c0 + 0.5) / win.sx - 0.5, (vv - win.r0 + 0.5) / win.sy - 0.5], axis=-1)
    return np.linalg.lstsq(np.c_[src, np.ones(len(src))], dst, rcond=None)[0].T  # (2, 3)


def _warp_to_dom(small, small_valid, a_pred):
    """Warp the reduced scene (uint8) and its validity with ``a_pred`` onto a canvas that holds it.

    ``a_pred``'s translation is set in place so that the warped scene starts at (0, 0).
    """
    h_s, w_s = small.shape
    corners = np.array([[0, 0], [w_s, 0], [0, h_s], [w_s, h_s]], dtype=np.float64) - 0.5
    moved = corners @ a_pred[:, :2].T
    a_pred[:, 2] = -moved.min(axis=0)
    canvas = tuple(int(np.ceil(v)) + 1 for v in (moved.max(axis=0) - moved.min(axis=0)))
    warped = cv2.warpAffine(to_uint8(small, small_valid), a_pred, canvas, flags=cv2.INTER_LINEAR)
    warped_valid = cv2.warpAffine(small_valid.astype(np.uint8), a_pred, canvas, flags=cv2.INTER_NEAREST)
    return warped, warped_valid


def _sift_ransac(warped, warped_valid, dom_small, *, n_features, ransac_px, seed, backend, device):
    """SIFT matches (ratio test) between the warped scene and the DOM, and their RANSAC inliers.

    Both backends adapt the feature budget (module docstring, step 3); ``backend`` other than
    ``"cpu"`` matches the descriptors on the torch ``device`` (None: CUDA if available).

    Returns
    -------
    ps, pd : ndarray of float32, shape (m, 2)
        Matched (x, y) positions in the warped scene and in the reduced DOM (OpenCV pixels).
    n_kp_s, n_kp_d : int
        Keypoints found in each image.
    ransac_in : ndarray of bool, shape (m,)
        Matches consistent with one affine map.
    """
    dom_valid = np.isfinite(dom_small)
    dom_u8 = to_uint8(dom_small, dom_valid)
    device = (device or "auto") if backend != "cpu" else None  # None: FLANN on the CPU
    dom_features = _sift_features(dom_u8, dom_valid, n_features)  # the full budget in both passes
    first = min(n_features, FIRST_FEATURE_BUDGET)
    if first < n_features:  # the full budget in the scene only where the first is not enough
        try:
            found = _sift_ransac_opencv(_sift_features(warped, warped_valid > 0, first), dom_features,
                                        ransac_px, seed, device)
            if int(found[-1].sum()) >= MIN_FIRST_INLIERS:
                return found
        except CoarseMatchError:
            pass
    return _sift_ransac_opencv(_sift_features(warped, warped_valid > 0, n_features), dom_features, ransac_px, seed,
                               device)


def _sift_ransac_opencv(scene_features, dom_features, ransac_px, seed, device=None):
    """Ratio matches of the scene's and the DOM's SIFT features (FLANN, or exact on a torch
    ``device``), seeded affine RANSAC."""
    ps, pd, n_kp_s, n_kp_d = _sift_matches_opencv(scene_features, dom_features, seed=seed, device=device)
    _check_matches(ps, n_kp_s, n_kp_d)
    cv2.setRNGSeed(seed)
    _, mask = cv2.estimateAffine2D(ps, pd, method=cv2.RANSAC, ransacReprojThreshold=ransac_px,
                                   maxIters=10000, confidence=0.999)
    ransac_in = np.zeros(len(ps), bool) if mask is None else mask.ravel().astype(bool)
    return ps, pd, n_kp_s, n_kp_d, _enough(ransac_in)


def _check_matches(ps, n_kp_s, n_kp_d) -> None:
    if n_kp_s < 8 or n_kp_d < 8:
        raise CoarseMatchError(f"too few SIFT keypoints (scene {n_kp_s}, DOM {n_kp_d}): no texture?")
    if len(ps) < 8:
        raise CoarseMatchError(f"only {len(ps)} SIFT matches pass the ratio test")


def _enough(ransac_in: np.ndarray) -> np.ndarray:
    if ransac_in.sum() < 6:
        raise CoarseMatchError("RANSAC found no consistent set of SIFT matches")
    return ransac_in


def _matches_on_ground(ps, pd, a_pred, f, win: _DomWindow, dem):
    """Scene ``row, col`` (continuous pixels, the warp undone) and DOM ground ``lon, lat, h``
    of every ratio-test match (``h`` from the DEM, metres above the ellipsoid)."""
    inv = cv2.invertAffineTransform(a_pred)
    sc = ps @ inv[:, :2].T + inv[:, 2]
    col = (sc[:, 0] + 0.5) * f
    row = (sc[:, 1] + 0.5) * f
    ui, vi = win.small_to_index(pd[:, 0].astype(np.float64), pd[:, 1].astype(np.float64))
    inv_index = ~win.index
    xm = inv_index.a * ui + inv_index.b * vi + inv_index.c
    ym = inv_index.d * ui + inv_index.e * vi + inv_index.f
    glon, glat = win.from_map.transform(xm, ym)
    glon, glat = np.asarray(glon), np.asarray(glat)
    gh = dem.height_m(glon, glat)
    return row, col, glon, glat, gh


def _precorrect(model, band, row, col, glon, glat, gh, *, sel, inside, min_scale_m):
    """Fit the exterior to the RANSAC inliers, re-screen all matches, remove CCD offsets.

    Returns
    -------
    corrected : SensorModel
        The pre-corrected model.
    keep : ndarray of intp
        Indices of the matches kept by the re-screening.
    rms_m : float
        Ground-space RMS of the re-screened fit, metres.
    offsets : dict
        Per-CCD offsets removed, pixels (empty for models without CCDs).
    """
    # models whose detector arrays carry their own interior (push-broom CCDs) get CCD offsets
    per_array = any(g.startswith("interior.") for g in model.parameter_groups())
    ccd = model.detector_index(col, band=band) if per_array else None
    fit = fit_exterior_in_ground(model, row[sel], col[sel], glon[sel], glat[sel], gh[sel], band=band,
                                 ccd=None if ccd is None else ccd[sel], min_scale_m=min_scale_m)
    # re-screen every ratio-test match against the corrected model: a robust refit on all of them
    # picks up the matches the affine RANSAC left out (CCD offsets, parallax), unless most ratio
    # matches are wrong (bands whose contrast inverts): then it is pulled off the RANSAC
    # consensus (PULLED_FACTOR), and only the matches within 3 of the consensus's own spread
    # are refitted
    fit2 = fit_exterior_in_ground(fit.model, row[inside], col[inside], glon[inside], glat[inside], gh[inside],
                                  band=band, ccd=None if ccd is None else ccd[inside], min_scale_m=min_scale_m)
    consensus = np.flatnonzero(sel)[fit.inlier]
    kw = {"band": band}
    before = ground_distance_m(fit.model, row[consensus], col[consensus], glon[consensus], glat[consensus],
                               gh[consensus], ccd=None if ccd is None else ccd[consensus], **kw)
    after = ground_distance_m(fit2.model, row[consensus], col[consensus], glon[consensus], glat[consensus],
                              gh[consensus], ccd=None if ccd is None else ccd[consensus], **kw)
    scale = max(min_scale_m, 1.4826 * float(np.median(before)))
    near = inside
    if not np.median(after) < PULLED_FACTOR * scale:
        dist = np.full(row.size, np.inf)
        dist[inside] = ground_distance_m(fit.model, row[inside], col[inside], glon[inside], glat[inside],
                                         gh[inside], ccd=None if ccd is None else ccd[inside], **kw)
        near = inside & (dist < 3.0 * scale)
        fit2 = fit_exterior_in_ground(fit.model, row[near], col[near], glon[near], glat[near], gh[near],
                                      band=band, ccd=None if ccd is None else ccd[near], min_scale_m=min_scale_m)
    keep = np.flatnonzero(near)[fit2.inlier]
    corrected = fit2.model
    offsets = {}
    if ccd is not None:
        corrected, offsets = fit_ccd_offsets(corrected, row[keep], col[keep], glon[keep], glat[keep], gh[keep],
                                             ccd[keep], band=band or corrected.reference_band)
    return corrected, keep, fit2.rms_m, offsets
