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
   When the warped scene or its DOM window would need more memory than ``sift_budget_bytes``
   for SIFT's scale space (``SIFT_BYTES_PER_PX`` a pixel of the larger of the two), steps 1-3
   run by overlapping tiles of the reduced scene (:func:`plan_tiles`: the coarsest grid whose
   every tile fits, tile sides kept at ``MIN_REDUCED_SIDE_PX`` or more), each warped by its own
   predicted map against the DOM window around its own footprint, with its own RANSAC; the
   matches in each tile's core are merged in full-scene coordinates. A scene within the budget
   is matched whole, as above.
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

from gcpmatch.ccd_search import search_missing_ccds
from gcpmatch.coarse_fast import fast_pass, spread_over_arrays
from gcpmatch.coarse_reduce import reduce_scene
from gcpmatch.coarse_sift import CoarseMatchError, sift_ransac, to_uint8
from gcpmatch.coarse_skip import within_fine_radius
from gcpmatch.precorrect import precorrect_matches
from gcpmatch.reference import grid_resolution_m, scene_gsd_m

__all__ = ["MIN_REDUCED_SIDE_PX", "SEARCHES", "SIFT_BUDGET_BYTES", "SIFT_BYTES_PER_PX", "CoarseMatchError",
           "CoarseResult", "Tile",
           "coarse_match", "plan_tiles", "reduction_factor", "to_uint8"]


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
    tiles: int = 1  # SIFT passes: 1 for the whole scene, else the tiles of plan_tiles
    ccd_search: dict = field(default_factory=dict)  # CCD -> report of gcpmatch.ccd_search
    fast_pass: bool = False  # the half-resolution pass was trusted (gcpmatch.coarse_fast)

    def summary(self) -> dict:
        """The counts and fit figures as a JSON-ready dict (no model, no points).

        Returns
        -------
        dict
            Keypoints, ratio matches, RANSAC inliers, kept inliers, ``rms_m``, ``factor``,
            ``ccd_offsets_px`` (keys as strings), ``dem_coverage`` (fraction of the DOM searched
            around the scene that has DEM heights), ``note`` (says when the search was
            restricted to that part), ``tiles`` (SIFT passes: 1 for the whole scene) and, when
            a CCD had too few SIFT matches, ``ccd_search`` (:func:`gcpmatch.ccd_search.search_ccd_offsets`).
        """
        return {
            "keypoints_scene": self.n_keypoints_scene, "keypoints_dom": self.n_keypoints_dom,
            "ratio_matches": self.n_matches, "ransac_inliers": self.n_ransac_inliers,
            "inliers": self.n_inliers, "rms_m": self.rms_m, "factor": self.factor,
            "ccd_offsets_px": {str(k): v for k, v in self.ccd_offsets_px.items()},
            "dem_coverage": self.dem_coverage, "note": self.note, "tiles": self.tiles,
            **({"ccd_search": {str(k): v for k, v in self.ccd_search.items()}} if self.ccd_search else {}),
        }


def _border(model, band, n=24, part=None):
    """Rows and columns of ``n`` points along each of the four edges (pixel centres) of the image,
    or of its rectangle ``part = (row0, row1, col0, col1)`` (scene pixels, half-open)."""
    n_rows, n_cols = model.image_shape
    row0, row1, col0, col1 = (0, n_rows, 0, n_cols) if part is None else part
    along = np.linspace(row0 + 0.5, row1 - 0.5, n)
    across = np.linspace(col0 + 0.5, col1 - 0.5, n)
    rows = np.concatenate([np.full(n, row0 + 0.5), np.full(n, row1 - 0.5), along, along])
    cols = np.concatenate([across, across, np.full(n, col0 + 0.5), np.full(n, col1 - 0.5)])
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


#: Bytes of memory per pixel of the image OpenCV SIFT runs on (its scale space: the first
#: octave at twice the image's size, 6 Gaussian and 5 difference-of-Gaussian float32 levels per
#: octave, about 176 bytes a pixel in the first octave, 4/3 of that over all octaves). Measured
#: (OpenCV 5.0, ``detectAndCompute`` of a uint8 image, peak resident memory of a fresh process
#: before and after; tests/test_coarse_tiles.py): 228-231 bytes a pixel from 1 to 6 M pixels,
#: 1 to 4 threads, 4 000 to 40 000 features.
#: The DOM's features are found before the scene's and only their keypoints and descriptors
#: stay, so the coarse stage's peak follows the larger of the two images, not their sum.
SIFT_BYTES_PER_PX = 230
#: Memory the coarse stage's SIFT may take, bytes: a scene whose warped image or DOM window
#: would need more is matched by tiles (:func:`plan_tiles`). 1 GiB holds 4.67 M pixels: every
#: scene of the tests and tutorials stays whole (0.92 M pixels at most); a 512-line strip of the
#: seed-003 width (reduced twice, a 31.3 M pixel DOM window) runs as 7 tiles.
SIFT_BUDGET_BYTES = 1 << 30
#: the coarse stage's searches (:func:`coarse_match`)
SEARCHES = ("adaptive", "fast", "exhaustive")
#: Tiles overlap by this many reduced pixels: a keypoint near a tile's edge has its
#: descriptor's support (about 10 times its scale) in the neighbour, where it is kept.
TILE_OVERLAP_PX = 64


def coarse_match(scene: np.ndarray, model, dem, dom, *, band: str | None = None, max_offset_px: float = 1000.0,
                 target_px: int = 1600, ransac_px: float = 2.0, n_features: int = 12000,
                 seed: int = 0, backend: str = "cpu", device=None, skip_within_px: float | None = None,
                 sift_budget_bytes: int = SIFT_BUDGET_BYTES, capture_px: float = 16.0,
                 search: str = "adaptive", threads: int = 1) -> CoarseResult:
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
    ransac_px, n_features, seed : float, int, int
        RANSAC inlier threshold (reduced-scene pixels), most SIFT keypoints kept per image,
        seed of the RANSAC draws.
    backend, device : {"cpu", "torch"}, str or torch.device, optional
        ``"torch"``: the descriptors' exact two nearest neighbours on the torch ``device``
        (None: CUDA if available) instead of FLANN (:mod:`gcpmatch.coarse_sift`).
    skip_within_px : float, optional
        The fine stage's search radius, pixels: when a few windows' phase correlation shows
        the model already within half of it, SIFT is skipped and ``model`` is returned
        unchanged, with the note "coarse stage skipped: model within N px"
        (:func:`gcpmatch.coarse_skip.within_fine_radius`); else SIFT runs. None: always SIFT.
    sift_budget_bytes : int
        Memory SIFT's scale space may take, bytes: when the warped scene or its DOM window would
        need more (``SIFT_BYTES_PER_PX`` a pixel), SIFT runs by overlapping tiles
        (:func:`plan_tiles`), each against the DOM around its own footprint, and the matches
        are merged in scene coordinates before the one pre-correction fit.
    capture_px : float
        The fine stage's capture radius, pixels: sets the search of a CCD without SIFT matches
        (:func:`gcpmatch.ccd_search.search_missing_ccds`) and how precisely the fast pass must
        pin the pre-correction.
    search : {"adaptive", "fast", "exhaustive"}
        ``"adaptive"``: full-resolution SIFT with the adaptive scene budget (:func:`gcpmatch.coarse_sift.sift_ransac`);
        ``"fast"``: the pass of :mod:`gcpmatch.coarse_fast` where trusted (a scene matched whole), else
        ``"adaptive"``; ``"exhaustive"``: the full budget in both images, brute force (docs/matching.md,
        "Coarse stage searches").
    threads : int
        Threads of the scene's reduction (the result does not depend on it).

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
    if search not in SEARCHES:
        raise ValueError(f"search must be one of {', '.join(SEARCHES)}, got {search!r}")
    skipped = _skipped(scene, model, dem, dom, band, skip_within_px)
    if skipped is not None:
        return skipped
    small, small_valid, f = _reduce_scene(scene, target_px, threads)
    h_mid = scene_height_m(model, dem, band=band)
    gsd = scene_gsd_m(model, band=band, height_m=h_mid)
    coarse_res = gsd * f  # metres per reduced pixel
    geo = {"band": band, "h_mid": h_mid, "gsd": gsd, "coarse_res": coarse_res, "max_offset_px": max_offset_px}
    sift = {"n_features": n_features, "ransac_px": ransac_px, "seed": seed, "backend": backend, "device": device,
            "exhaustive": search == "exhaustive"}
    tiles = plan_tiles(model, dom, small.shape, f, budget_px=int(sift_budget_bytes // SIFT_BYTES_PER_PX), **geo)
    found, fitted = _found_and_fitted(small, small_valid, f, scene.shape, tiles, model, dom, dem, geo, sift,
                                      capture_px / f if search == "fast" else None)
    row, col, glon, glat, gh, ransac_in = found.matches
    note = found.note
    corrected, keep, rms_m, offsets = fitted
    corrected, searched = search_missing_ccds(scene, corrected, dem, dom, band=band or corrected.reference_band,
                                              removed=offsets, capture_px=capture_px, h_mid=h_mid)
    return CoarseResult(
        model=corrected, n_keypoints_scene=found.n_kp_scene, n_keypoints_dom=found.n_kp_dom, n_matches=row.size,
        n_ransac_inliers=int(ransac_in.sum()), n_inliers=int(keep.size), rms_m=rms_m, factor=f,
        ccd_offsets_px=offsets, ccd_search=searched,
        points={"row": row[keep], "col": col[keep], "lon": glon[keep], "lat": glat[keep], "h": gh[keep]},
        dem_coverage=found.dem_cover, note=note, tiles=1 if tiles is None else len(tiles), fast_pass=found.fast,
    )


def _found_and_fitted(small, small_valid, f, shape, tiles, model, dom, dem, geo, sift, fast_capture_px):
    """The matches (:class:`_Found`) and their pre-correction (:func:`_precorrect`): by tiles, or the
    whole scene, there first by the fast pass when ``fast_capture_px`` (the fine stage's capture
    radius, reduced pixels) is given and the full search where the fast pass is refused."""
    if tiles is not None:
        found = _tiled_matches(small, small_valid, f, tiles, model, dom, dem, geo, sift)
        return found, _precorrect(found, model, geo["band"], shape, geo["coarse_res"])
    fast = None if fast_capture_px is None else {"capture_px": fast_capture_px}
    found = _whole_matches(small, small_valid, f, shape, model, dom, dem, geo, sift, fast)
    fitted = _precorrect(found, model, geo["band"], shape, geo["coarse_res"], fast=found.fast)
    if fitted is None:  # the fast pass's kept matches miss a detector array: the full search instead
        found = _whole_matches(small, small_valid, f, shape, model, dom, dem, geo, sift)
        fitted = _precorrect(found, model, geo["band"], shape, geo["coarse_res"])
    return found, fitted


def _precorrect(found, model, band, shape, coarse_res, fast: bool = False):
    """:func:`gcpmatch.precorrect.precorrect_matches` of ``found``'s matches inside the scene and
    the DEM. ``fast``: the matches of the half-resolution pass, whose result is None (not an
    error) when they are too few or the kept ones miss a detector array with matches
    (:func:`gcpmatch.coarse_fast.spread_over_arrays`)."""
    row, col, glon, glat, gh, ransac_in = found.matches
    inside = (row > 0) & (row < shape[0]) & (col > 0) & (col < shape[1]) & np.isfinite(gh)
    sel = ransac_in & inside
    if sel.sum() < 6:
        if fast:
            return None
        where = "" if not found.note else f" ({found.note})"
        raise CoarseMatchError(f"too few RANSAC inliers inside the scene and the DEM: {int(sel.sum())} < 6{where}")
    out = precorrect_matches(model, band, row, col, glon, glat, gh, sel=sel, inside=inside,
                             min_scale_m=0.5 * coarse_res)
    if fast and not spread_over_arrays(model, band, col[out[1]], col[inside]):
        return None
    return out


def _skipped(scene, model, dem, dom, band, skip_within_px) -> CoarseResult | None:
    """The model as it is, with no match counts and the note saying so, when a few windows'
    phase correlation shows it already within ``skip_within_px`` (None: not asked, or not so)."""
    if skip_within_px is None:
        return None
    note = within_fine_radius(scene, model, dem, dom, band=band or model.reference_band,
                              radius_px=float(skip_within_px))
    if note is None:
        return None
    return CoarseResult(model=model, n_keypoints_scene=0, n_keypoints_dom=0, n_matches=0, n_ransac_inliers=0,
                        n_inliers=0, rms_m=float("nan"), factor=1, note=note)


@dataclass
class _Found:
    """SIFT matches of the coarse stage in full-scene coordinates, before the pre-correction.

    ``matches`` is ``(row, col, lon, lat, h, ransac_in)``: scene pixels (continuous), ground
    degrees, DEM height (metres) and the RANSAC verdict of every ratio-test match.
    """

    matches: tuple
    n_kp_scene: int
    n_kp_dom: int
    dem_cover: float
    note: str
    fast: bool = False


def _whole_matches(small, small_valid, f, shape, model, dom, dem, geo, sift, fast=None) -> _Found:
    """SIFT of the whole reduced scene against the whole DOM window around it (one RANSAC); with
    ``fast`` (``{"capture_px": reduced pixels}``) the half-resolution pass first, kept when it is
    trusted (:mod:`gcpmatch.coarse_fast`)."""
    band, h_mid = geo["band"], geo["h_mid"]
    win = _dom_window(model, dom, **geo)
    dem_cover, note = _restrict_to_dem(win, dem)
    a_pred = _predicted_affine(model, band, h_mid, shape, f, win)
    warped, warped_valid = _warp_to_dom(small, small_valid, a_pred)
    if fast is not None:
        found = _fast_matches(warped, warped_valid, win, a_pred, f, dem, sift, fast["capture_px"])
        if found is not None:
            return _Found(found[0], found[1], found[2], dem_cover, note, fast=True)
    ps, pd, n_kp_s, n_kp_d, ransac_in = sift_ransac(warped, warped_valid, win.dom_small, **sift)
    row, col, glon, glat, gh = _matches_on_ground(ps, pd, a_pred, f, win, dem)
    return _Found((row, col, glon, glat, gh, ransac_in), n_kp_s, n_kp_d, dem_cover, note)


def _fast_matches(warped, warped_valid, win, a_pred, f, dem, sift, capture_px):
    """The half-resolution pass's matches on the ground and its keypoint counts, or None where it
    is not trusted (:func:`gcpmatch.coarse_fast.fast_pass`)."""
    dom_valid = np.isfinite(win.dom_small)
    device = None if sift["backend"] == "cpu" else (sift["device"] or "auto")
    found = fast_pass(warped, warped_valid, to_uint8(win.dom_small, dom_valid), dom_valid,
                      n_features=sift["n_features"], ransac_px=sift["ransac_px"], seed=sift["seed"],
                      capture_px=capture_px, device=device)
    if found is None:
        return None
    ps, pd, n_kp_s, n_kp_d, ransac_in = found
    return _matches_on_ground(ps, pd, a_pred, f, win, dem) + (ransac_in,), n_kp_s, n_kp_d


def _tiled_matches(small, small_valid, f, tiles, model, dom, dem, geo, sift) -> _Found:
    """SIFT tile by tile (each against the DOM window around its own footprint, its own RANSAC);
    the matches whose scene position falls in a tile's core, merged in full-scene coordinates.

    A tile without a consistent set (clouds, water, a DOM or DEM that misses it) adds nothing;
    none at all raises :class:`CoarseMatchError`.
    """
    merged, n_kp_s, n_kp_d, covered, searched, reasons = [], 0, 0, 0.0, 0, []
    for t in tiles:
        r0, r1, c0, c1 = t.box
        try:
            win = _dom_window(model, dom, part=(r0 * f, r1 * f, c0 * f, c1 * f), **geo)
            cover, _ = _restrict_to_dem(win, dem)
            a_pred = _predicted_affine(model, geo["band"], geo["h_mid"], ((r1 - r0) * f, (c1 - c0) * f), f, win,
                                       origin=(r0, c0))
            warped, warped_valid = _warp_to_dom(small[r0:r1, c0:c1], small_valid[r0:r1, c0:c1], a_pred)
            ps, pd, kp_s, kp_d, ransac_in = sift_ransac(warped, warped_valid, win.dom_small, **sift)
        except CoarseMatchError as exc:
            reasons.append(str(exc))
            continue
        n_kp_s, n_kp_d = n_kp_s + kp_s, n_kp_d + kp_d
        searched += win.dom_small.size
        covered += cover * win.dom_small.size
        row, col, glon, glat, gh = _matches_on_ground(ps, pd, a_pred, f, win, dem, origin=(r0, c0))
        k0, k1, j0, j1 = t.core
        core = (row >= k0 * f) & (row < k1 * f) & (col >= j0 * f) & (col < j1 * f)
        merged.append([a[core] for a in (row, col, glon, glat, gh, ransac_in)])
    if not merged:
        raise CoarseMatchError(f"no tile of the {len(tiles)} found a consistent set of SIFT matches "
                               f"(first: {reasons[0]})")
    cover = covered / max(searched, 1)
    name = getattr(dem, "source", None) or "the DEM"
    note = "" if cover >= _FULL_COVER else (
        f"the DEM covers {100 * cover:.0f} % of the reference searched around the scene ({name}); "
        "the coarse search was restricted to that part")
    return _Found(tuple(np.concatenate(parts) for parts in zip(*merged)), n_kp_s, n_kp_d, cover, note)


@dataclass(frozen=True)
class Tile:
    """One SIFT pass of a tiled coarse stage, in reduced-scene pixels (half-open, ``row0, row1,
    col0, col1``): ``box`` is what SIFT sees, ``core`` where its matches are kept (the tiles'
    cores partition the plane, the outer ones open-ended); ``cost_px`` is the larger of its warped image and
    its DOM window, pixels."""

    box: tuple
    core: tuple
    cost_px: int


def _split(n: int, k: int, overlap: int) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """``k`` boxes along ``range(n)``: cores partitioning it (the outer ones open-ended, so a match
    the warp puts just outside the reduced scene stays with its tile), each widened by
    ``overlap // 2`` on its inner sides."""
    edges = np.round(np.linspace(0, n, k + 1)).astype(int)
    half = overlap // 2
    return [((max(0, int(a) - half), min(n, int(b) + half)), (float(a) if i else -np.inf, float(b) if i < k - 1 else np.inf))
            for i, (a, b) in enumerate(zip(edges[:-1], edges[1:]))]


def _cost_px(model, dom, f, box, geo) -> int:
    """Pixels of the larger image SIFT sees for reduced-scene ``box``: its warped canvas or its
    DOM window (placed and sized, not read)."""
    r0, r1, c0, c1 = box
    win = _dom_window(model, dom, part=(r0 * f, r1 * f, c0 * f, c1 * f), read=False, **geo)
    a_pred = _predicted_affine(model, geo["band"], geo["h_mid"], ((r1 - r0) * f, (c1 - c0) * f), f, win,
                               origin=(r0, c0))
    w, h = _warp_canvas((r1 - r0, c1 - c0), a_pred)
    return int(max(w * h, win.dom_small.shape[0] * win.dom_small.shape[1]))


def _grid(model, dom, f, small_shape, k_rows, k_cols, geo) -> list[Tile]:
    """The tiles of a ``k_rows x k_cols`` split of the reduced scene, with their costs."""
    rows = _split(small_shape[0], k_rows, TILE_OVERLAP_PX)
    cols = _split(small_shape[1], k_cols, TILE_OVERLAP_PX)
    tiles = []
    for (r0, r1), core_r in rows:
        for (c0, c1), core_c in cols:
            box = (r0, r1, c0, c1)
            tiles.append(Tile(box, (*core_r, *core_c), _cost_px(model, dom, f, box, geo)))
    return tiles


def plan_tiles(model, dom, small_shape, f, *, budget_px, **geo) -> list[Tile] | None:
    """The SIFT passes of the coarse stage under a memory budget: None when the whole reduced
    scene and its DOM window fit, else the coarsest grid of overlapping tiles that does.

    Parameters
    ----------
    model : SensorModel
        Current model (places each tile's footprint in the DOM).
    dom : MapImage
        Reference orthoimage (only its grid is used: nothing is read).
    small_shape : (int, int)
        Reduced scene, pixels.
    f : int
        Reduction factor (scene pixels per reduced pixel).
    budget_px : int
        Most pixels of one image SIFT may run on: ``SIFT budget (bytes) / SIFT_BYTES_PER_PX``.
    **geo
        ``band``, ``h_mid``, ``gsd``, ``coarse_res``, ``max_offset_px`` of :func:`coarse_match`.

    Returns
    -------
    list of Tile or None
        None: one pass over the whole scene. Else tiles of ``k_rows x k_cols``: ``k_rows`` from 1
        up, and for each the fewest ``k_cols`` (bisection) whose every tile's cost is at most
        ``budget_px``; tile sides are kept at ``MIN_REDUCED_SIDE_PX`` or more (the whole side
        where it is shorter), so SIFT keeps rows and columns to work in. When even the finest
        such grid is over the budget, that grid (the least memory the search margin allows).

    Notes
    -----
    A tile's DOM window is its footprint plus ``max_offset_px`` scene pixels on each side, so
    the margin, not the tile, sets the floor of the cost: ``(2 m + t)^2`` pixels for a tile of
    ``t`` and a margin of ``m`` reduced pixels.
    """
    if _cost_px(model, dom, f, (0, small_shape[0], 0, small_shape[1]), geo) <= budget_px:
        return None
    k_max = [max(1, n // MIN_REDUCED_SIDE_PX) for n in small_shape]
    long_axis = int(small_shape[1] >= small_shape[0])  # 1: columns are the longer side
    finest = None
    for k_short in range(1, k_max[1 - long_axis] + 1):
        def grid(k_long):
            k = (k_short, k_long) if long_axis else (k_long, k_short)
            return _grid(model, dom, f, small_shape, *k, geo)
        lo, hi = 1, k_max[long_axis]
        finest = grid(hi)
        if max(t.cost_px for t in finest) > budget_px:
            continue
        best = finest
        while lo < hi:  # fewest tiles along the long side that fit (costs fall as tiles shrink)
            mid = (lo + hi) // 2
            tiles = grid(mid)
            if max(t.cost_px for t in tiles) <= budget_px:
                best, hi = tiles, mid
            else:
                lo = mid + 1
        return best
    return finest


#: the reduced scene's shorter side is kept at this many pixels or more (when the scene has them):
#: reduced by its longest side alone, a strip of seed 003's full width (21 800 detectors) over 512
#: lines would be 1557 x 36 px, and SIFT then finds too few matches for RANSAC (measured: "RANSAC
#: found no consistent set of SIFT matches" on that strip, profile realistic; the realistic demo
#: fixture reduced to 73 x 109 px fails the same way, at 256 x 384 px it matches)
MIN_REDUCED_SIDE_PX = 256

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


def _reduce_scene(scene: np.ndarray, target_px: int, threads: int = 1):
    """The scene averaged down by the integer factor ``f`` of :func:`reduction_factor`.

    Returns
    -------
    small : ndarray of float32, shape (n_rows // f, n_cols // f)
        Block means, no-data as 0 (:func:`gcpmatch.coarse_reduce.reduce_scene`).
    small_valid : ndarray of bool, same shape
        Blocks that hold valid pixels only.
    f : int
        The reduction factor.
    """
    f = reduction_factor(*scene.shape, target_px)
    small, small_valid = reduce_scene(scene, f, threads=threads)
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


def _dom_window(model, dom, *, band, h_mid, gsd, coarse_res, max_offset_px, part=None, read=True) -> _DomWindow:
    """The DOM over the predicted footprint of the scene (or of its rectangle ``part``, scene
    pixels ``(row0, row1, col0, col1)``) plus ``max_offset_px`` scene pixels of margin.

    ``read=False`` places the window and sizes ``dom_small`` (an empty array of its shape) without
    reading the DOM: what the tile planner needs.
    """
    dom_res = grid_resolution_m(dom.grid)
    to_map = pyproj.Transformer.from_crs("EPSG:4326", dom.grid.crs, always_xy=True)
    from_map = pyproj.Transformer.from_crs(dom.grid.crs, "EPSG:4326", always_xy=True)
    win = _DomWindow(None, 0, 0, 1.0, 1.0, dom.grid.index_affine(), to_map, from_map)
    # predicted footprint in DOM indices, plus the search margin
    br, bc = _border(model, band, part=part)
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
    win.dom_small = dom.read_decimated(r0, r1, c0, c1, out_shape) if read else np.empty((*out_shape, 0), np.uint8)
    win.r0, win.c0 = r0, c0
    win.sy, win.sx = (r1 - r0) / out_shape[0], (c1 - c0) / out_shape[1]  # DOM px per reduced DOM px
    return win


def _predicted_affine(model, band, h_mid, shape, f, win: _DomWindow, origin=(0, 0)) -> np.ndarray:
    """(2, 3) affine map reduced scene -> reduced DOM as the model predicts, re-positioned.

    ``shape`` is the scene's (or a tile's) size in scene pixels and ``origin`` its first pixel in
    reduced-scene pixels (a tile's ``(row, col)``; the map then acts on the tile's own pixels).
    It keeps the predicted mirror, rotation and scale but not the position: the model may be
    off by more than the scene's size, so the warped scene gets a canvas of its own.
    """
    n_rows, n_cols = shape
    gr, gc = np.meshgrid(np.linspace(0.5, n_rows - 0.5, 12), np.linspace(0.5, n_cols - 0.5, 12), indexing="ij")
    lon, lat, _ = model.image_to_ground(gr.ravel() + origin[0] * f, gc.ravel() + origin[1] * f, height=h_mid,
                                        band=band)
    uu, vv = win.ground_to_index(lon, lat)
    src = np.stack([gc.ravel() / f - 0.5, gr.ravel() / f - 0.5], axis=-1)
    dst = np.stack([(uu - win.c0 + 0.5) / win.sx - 0.5, (vv - win.r0 + 0.5) / win.sy - 0.5], axis=-1)
    return np.linalg.lstsq(np.c_[src, np.ones(len(src))], dst, rcond=None)[0].T  # (2, 3)


def _warp_canvas(shape, a_pred):
    """Canvas ``(width, height)`` that holds an image of ``shape`` warped by ``a_pred``; sets
    ``a_pred``'s translation in place so that the warped image starts at (0, 0)."""
    h_s, w_s = shape
    corners = np.array([[0, 0], [w_s, 0], [0, h_s], [w_s, h_s]], dtype=np.float64) - 0.5
    moved = corners @ a_pred[:, :2].T
    a_pred[:, 2] = -moved.min(axis=0)
    return tuple(int(np.ceil(v)) + 1 for v in (moved.max(axis=0) - moved.min(axis=0)))


def _warp_to_dom(small, small_valid, a_pred):
    """Warp the reduced scene (uint8) and its validity with ``a_pred`` onto a canvas that holds it.

    ``a_pred``'s translation is set in place so that the warped scene starts at (0, 0).
    """
    canvas = _warp_canvas(small.shape, a_pred)
    warped = cv2.warpAffine(to_uint8(small, small_valid), a_pred, canvas, flags=cv2.INTER_LINEAR)
    warped_valid = cv2.warpAffine(small_valid.astype(np.uint8), a_pred, canvas, flags=cv2.INTER_NEAREST)
    return warped, warped_valid


def _matches_on_ground(ps, pd, a_pred, f, win: _DomWindow, dem, origin=(0, 0)):
    """Scene ``row, col`` (continuous pixels, the warp undone) and DOM ground ``lon, lat, h``
    of every ratio-test match (``h`` from the DEM, metres above the ellipsoid); ``origin`` is the
    first reduced-scene pixel ``(row, col)`` of the tile the matches were found in."""
    inv = cv2.invertAffineTransform(a_pred)
    sc = ps @ inv[:, :2].T + inv[:, 2]
    col = (sc[:, 0] + origin[1] + 0.5) * f
    row = (sc[:, 1] + origin[0] + 0.5) * f
    ui, vi = win.small_to_index(pd[:, 0].astype(np.float64), pd[:, 1].astype(np.float64))
    inv_index = ~win.index
    xm = inv_index.a * ui + inv_index.b * vi + inv_index.c
    ym = inv_index.d * ui + inv_index.e * vi + inv_index.f
    glon, glat = win.from_map.transform(xm, ym)
    glon, glat = np.asarray(glon), np.asarray(glat)
    gh = dem.height_m(glon, glat)
    return row, col, glon, glat, gh
