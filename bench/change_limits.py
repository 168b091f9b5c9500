"""What limits matching across the Sentinel-2 bands: each window's error against its content.

The scenes of :mod:`bench.change_pairs` (a realistic push-broom scene rendered from one real
Sentinel-2 band) are cut into the matcher's windows once per (direction, seed, reference) by
:func:`bench_matcher_realism.prepare_windows` (coarse stage, reference chips, screening, the TRUE
shift at each window centre) and cached. The cross-band truth has the bands' whole-crop
displacement (:data:`change_pairs.BAND_OFFSET_M`) taken out. The same seed renders the same
geometry from either band, so a window index names the same ground in the four caches of a seed:
red scene on NIR (``A``), NIR scene on red (``B``), and each scene on its own band (``SA``,
``SB``). Printed:

* ``kept``: the windows the matcher keeps with the given options (default: the change options,
  :data:`CHANGE`), their cross-band truth error, the same windows' same-band error and their
  share on water (B08 under :data:`change_pairs` 500 DN on at least 60 % of the window);
* ``decomposition``: on the windows every one of the four correlations matches (phase
  correlation as production, no rejection), land and water apart: the change's error
  ``c = cross - same`` of each direction split into the part that flips sign when the bands swap
  roles, ``(c_A - c_B) / 2`` (a displacement of the content between the bands, or a bias that
  the content difference drives: either way fixed by the two bands' content), and the part that
  does not, ``(c_A + c_B) / 2``;
* ``detection``: per seed, the median over the matched windows of the spectral spread over the
  matching noise the score predicts (:func:`gcpmatch.window_match.spectral_spread_px`,
  :func:`gcpmatch.uncertainty.score_sigma_px`) and the share above 1, for each reference;
* ``candidates``: truth error of window-level estimators on all matched windows, land and water
  apart, across and on the same band: the production phase correlation (``pc``); the reference
  mapped through the conditional mean of the scene given the reference's grey level at the
  phase-correlation shift, then phase-correlated again (``lut``: a per-window radiometric map that
  need not be monotone; Roche et al. 1998, correlation ratio); correlation of the doubled-angle
  gradient orientations weighted by gradient magnitude, refined by Newton from the phase shift
  (``orientation``: blind to the sign of the contrast; Fitch et al. 2002); mutual information of
  the grey levels maximised from the phase shift (``mi``; Viola and Wells 1997).

Usage: ``python bench/change_limits.py [--cache DIR] [--seeds 11,12,13,14] [--json FILE]``.

References: A. Roche, G. Malandain, X. Pennec, N. Ayache, "The correlation ratio as a new
similarity measure for multimodal image registration", MICCAI 1998, 1115-1124. A. J. Fitch,
A. Kadyrov, W. J. Christmas, J. Kittler, "Orientation correlation", BMVC 2002, 133-142. P. Viola,
W. M. Wells, "Alignment by maximization of mutual information", IJCV 24(2):137-154, 1997.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import fft as sfft
from scipy.ndimage import gaussian_filter
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import change_pairs  # noqa: E402

DIRECTIONS = ("s2_red_vs_nir", "s2_nir_vs_red")
#: a window is water when at least this share of its near-infrared chip is under ``WATER_DN``
WATER_SHARE = 0.6
#: Sentinel-2 B08 digital number under which a pixel is water (as ``change_pairs.water_fraction``)
WATER_DN = 500.0
#: a candidate's shift further than this from the phase-correlation shift on an axis, px, counts as lost
LOST_PX = 1.0
#: margin (px) of a window left out of the conditional-mean and mutual-information fits
FIT_MARGIN_PX = 6


def change_options():
    """The change options of ``bench/bench_change.py`` (spread in sigma, spread rejection at 1)."""
    from gcpmatch.options import MatchOptions

    return MatchOptions(spectral_spread_sigma=True, max_spectral_spread=1.0)


def windows(cache: Path, name: str, seed: int, kind: str) -> dict:
    """Windows of the ``name`` scene of ``seed`` against its ``kind`` reference (cached npz)."""
    import bench_matcher_realism as bmr
    from gcpmatch.options import MatchOptions

    path = cache / f"{name}_seed{seed}_{kind}_windows.npz"
    if not path.exists():
        source, refs = change_pairs.PAIRS[name]
        scene = change_pairs.render_scene(cache / f"{name}_seed{seed}", change_pairs.DATA / source, seed)
        dom = change_pairs.DATA / refs[kind]
        offset = None
        if kind == "cross" and name in change_pairs.BAND_OFFSET_M:
            offset = (*change_pairs.BAND_OFFSET_M[name], change_pairs.dom_crs(dom))
        arrays = bmr.prepare_windows(scene, replace(MatchOptions(), reference_sigma_m=0.0), dom_path=dom,
                                     band_offset=offset)
        np.savez(path, **arrays)
    with np.load(path) as data:
        win = dict(data)
    win["status"] = win["status"].astype(object)
    return win


def water_share(cache: Path, seed: int) -> np.ndarray:
    """Share of each window of ``seed`` whose near-infrared chip is under :data:`WATER_DN`, shape (n,)."""
    nir = windows(cache, "s2_red_vs_nir", seed, "cross")["wr"]
    return (nir < WATER_DN).mean(axis=(1, 2))


def matched(win: dict, options=None) -> tuple[np.ndarray, np.ndarray]:
    """Indices and shifts (n, 2) px of the screened windows phase correlation matches (no rejection)."""
    from gcpmatch.options import MatchOptions
    from gcpmatch.window_match import correlate_pairs

    go = np.flatnonzero((win["status"] == "") & np.isfinite(win["true_shift"]).all(axis=1))
    res = correlate_pairs(win["wr"][go], win["ws"][go], options or MatchOptions())
    ok = res.status == ""
    return go[ok], res.shift_px[ok]


def kept(win: dict, options) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices, shifts (n, 2) px and ``sigma_px`` of the windows the matcher keeps with ``options``."""
    from gcpmatch.extract import reject_outliers
    from gcpmatch.window_match import correlate_pairs

    idx, shift, sigma = [], [], []
    for i, (n_r, n_c) in enumerate(win["grid"]):
        sel = np.flatnonzero(win["ccd"] == i)
        status = win["status"][sel].copy()
        sh = np.full((sel.size, 2), np.nan)
        go = np.flatnonzero(status == "")
        res = correlate_pairs(win["wr"][sel[go]], win["ws"][sel[go]], options)
        sh[go], status[go] = res.shift_px, res.status
        quality = {k: np.full(sel.size, np.nan) for k in res.quality}
        for k, v in res.quality.items():
            quality[k][go] = v
        keep, _, _, sig = reject_outliers(status, win["std_r"][sel], sh, win["rr"][sel], win["cc"][sel],
                                          (int(n_r), int(n_c)), int(win["first_col"][i]), options, quality=quality)
        idx.append(sel[keep])
        shift.append(sh[keep])
        sigma.append(sig)
    idx, shift, sigma = np.concatenate(idx), np.concatenate(shift), np.concatenate(sigma)
    ok = np.isfinite(win["true_shift"][idx]).all(axis=1)
    return idx[ok], shift[ok], sigma[ok]


def rms2(err: np.ndarray) -> float:
    """2-D rms of (n, 2) errors, px (NaN for none)."""
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1)))) if len(err) else float("nan")


def fourier_moved(win: np.ndarray, shift_px: np.ndarray) -> np.ndarray:
    """``out[k](x) = win[k](x - shift_px[k])`` by the Fourier shift theorem, shape (n, h, w)."""
    _, h, w = win.shape
    kr = np.fft.fftfreq(h)[None, :, None]
    kc = np.fft.fftfreq(w)[None, None, :]
    ramp = np.exp(-2j * np.pi * (kr * shift_px[:, 0, None, None] + kc * shift_px[:, 1, None, None]))
    return np.fft.ifft2(np.fft.fft2(win) * ramp).real


def lut_shift(reference: np.ndarray, scene: np.ndarray, start_px: np.ndarray, bins: int = 16) -> np.ndarray:
    """``lut`` candidate: the reference mapped through ``E[scene | reference]`` at ``start_px``
    (``bins`` quantile bins of the reference, piecewise linear, continued linearly beyond the end
    bins), phase-correlated again."""
    from gcpmatch.phase import phase_correlate

    ref = np.asarray(reference, dtype=float)
    aligned = fourier_moved(ref, start_px)
    m, h = FIT_MARGIN_PX, ref.shape[-1]
    mapped = np.empty_like(ref)
    for k in range(ref.shape[0]):
        a, b = aligned[k, m:h - m, m:h - m].ravel(), np.asarray(scene[k, m:h - m, m:h - m], dtype=float).ravel()
        which = np.clip(np.searchsorted(np.quantile(a, np.linspace(0, 1, bins + 1)), a, side="right") - 1, 0, bins - 1)
        count = np.bincount(which, minlength=bins)
        full = count > 0
        x = np.bincount(which, a, bins)[full] / count[full]
        y = np.bincount(which, b, bins)[full] / count[full]
        order = np.argsort(x)
        mapped[k] = _interp_linear_ends(ref[k], x[order], y[order])
    return phase_correlate(mapped, scene, max_shift_px=h / 4.0).shift_px


def _interp_linear_ends(v: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Piecewise-linear ``y(x)`` at ``v``, continued by the end segments beyond ``x``'s range."""
    out = np.interp(v, x, y)
    if x.size < 2:
        return out
    low, high = v < x[0], v > x[-1]
    out[low] = y[0] + (v[low] - x[0]) * (y[1] - y[0]) / max(x[1] - x[0], 1e-12)
    out[high] = y[-1] + (v[high] - x[-1]) * (y[-1] - y[-2]) / max(x[-1] - x[-2], 1e-12)
    return out


def _orientation_channels(win: np.ndarray, sigma_px: float = 1.0):
    """``|g| cos 2t`` and ``|g| sin 2t`` of the Gaussian-derivative gradient ``g`` of each window."""
    g_r = gaussian_filter(win, (0, sigma_px, sigma_px), order=(0, 1, 0))
    g_c = gaussian_filter(win, (0, sigma_px, sigma_px), order=(0, 0, 1))
    mag = np.maximum(np.hypot(g_r, g_c), 1e-12)
    return (g_c**2 - g_r**2) / mag, 2.0 * g_r * g_c / mag


def orientation_shift(reference: np.ndarray, scene: np.ndarray, start_px: np.ndarray) -> np.ndarray:
    """``orientation`` candidate: maximum of the doubled-angle orientation correlation near ``start_px``."""
    from gcpmatch.phase_newton import newton_refine, surface_grid

    ref, mov = np.asarray(reference, dtype=float), np.asarray(scene, dtype=float)
    h = ref.shape[-1]
    taper = np.outer(np.hanning(h + 2)[1:-1], np.hanning(h + 2)[1:-1])
    cross = 0.0
    for a, b in zip(_orientation_channels(ref), _orientation_channels(mov)):
        a = (a - a.mean(axis=(1, 2), keepdims=True)) * taper
        b = (b - b.mean(axis=(1, 2), keepdims=True)) * taper
        cross = cross + sfft.rfft2(b) * np.conj(sfft.rfft2(a))
    centre, _ = newton_refine(np.ascontiguousarray(cross), np.asarray(start_px, dtype=float),
                              surface_grid((h, h), np.float64), max_iterations=8)
    return centre


def _mutual_information(a: np.ndarray, b: np.ndarray, bins: int = 16) -> float:
    lim_a, lim_b = np.quantile(a, [0.005, 0.995]), np.quantile(b, [0.005, 0.995])
    hist, _, _ = np.histogram2d(np.clip(a, *lim_a), np.clip(b, *lim_b), bins=bins, range=[lim_a, lim_b])
    p = gaussian_filter(hist, 0.7)
    p /= p.sum()
    outer = p.sum(axis=1, keepdims=True) @ p.sum(axis=0, keepdims=True)
    nz = p > 0
    return float(np.sum(p[nz] * np.log(p[nz] / outer[nz])))


def mi_shift(reference: np.ndarray, scene: np.ndarray, start_px: np.ndarray) -> np.ndarray:
    """``mi`` candidate: mutual information (16 x 16 bins) maximised by Nelder-Mead from ``start_px``."""
    h, m = reference.shape[-1], FIT_MARGIN_PX
    kr, kc = np.fft.fftfreq(h)[:, None], np.fft.fftfreq(h)[None, :]
    out = np.empty_like(np.asarray(start_px, dtype=float))
    for k in range(reference.shape[0]):
        spectrum = np.fft.fft2(np.asarray(reference[k], dtype=float))
        b = np.asarray(scene[k, m:h - m, m:h - m], dtype=float).ravel()

        def cost(d, spectrum=spectrum, b=b):
            moved = np.fft.ifft2(spectrum * np.exp(-2j * np.pi * (kr * d[0] + kc * d[1]))).real
            return -_mutual_information(moved[m:h - m, m:h - m].ravel(), b)

        simplex = start_px[k] + np.array([[0.0, 0.0], [0.2, 0.0], [0.0, 0.2]])
        out[k] = minimize(cost, start_px[k], method="Nelder-Mead",
                          options={"xatol": 0.005, "fatol": 1e-7, "initial_simplex": simplex}).x
    return out


CANDIDATES = {"lut": lut_shift, "orientation": orientation_shift, "mi": mi_shift}


def kept_report(cache: Path, seeds, options) -> dict:
    """Per direction: GCPs kept with ``options`` across the bands, their truth error, the same
    windows' same-band error (default options), their share on water and ``rms(error / sigma)``."""
    from gcpmatch.options import MatchOptions

    out = {}
    for name in DIRECTIONS:
        err, same, wet, z = [], [], [], []
        for seed in seeds:
            cross, own = windows(cache, name, seed, "cross"), windows(cache, name, seed, "same")
            idx, shift, sigma = kept(cross, options)
            e = shift - cross["true_shift"][idx]
            err.append(e)
            z.append(e / sigma[:, None])
            wet.append(water_share(cache, seed)[idx] >= WATER_SHARE)
            m_idx, m_shift = matched(own, MatchOptions())
            pos = np.searchsorted(m_idx, idx)
            found = (pos < m_idx.size) & (m_idx[np.minimum(pos, m_idx.size - 1)] == idx)
            same.append(m_shift[pos[found]] - own["true_shift"][idx[found]])
        err, same, wet, z = (np.concatenate(v) for v in (err, same, wet, z))
        out[name] = {"n": int(len(err)), "cross_rms_px": rms2(err), "same_band_rms_px": rms2(same),
                     "n_same": int(len(same)), "water_share": float(wet.mean()),
                     "z": float(np.sqrt(np.mean(z**2))), "mean_px": err.mean(axis=0).round(4).tolist()}
    return out


def detection(cache: Path, seeds) -> dict:
    """Per (direction, reference): per seed, the median over the matched windows of the spectral
    spread over the matching noise the score predicts, and the share of windows above 1 (the
    ``max_spectral_spread=1`` rejection): how a scene tells a reference that shows its ground
    otherwise from a faithful one."""
    from gcpmatch.options import MatchOptions
    from gcpmatch.uncertainty import score_sigma_px
    from gcpmatch.window_match import correlate_pairs

    out = {}
    for name in DIRECTIONS:
        for kind in ("same", "cross"):
            rows = []
            for seed in seeds:
                win = windows(cache, name, seed, kind)
                go = np.flatnonzero(win["status"] == "")
                res = correlate_pairs(win["wr"][go], win["ws"][go], MatchOptions(spectral_spread_sigma=True))
                ok = res.status == ""
                ratio = res.quality["spectral_spread_px"][ok] / score_sigma_px(res.quality["score"][ok])
                rows.append([float(np.median(ratio)), float(np.mean(ratio > 1.0))])
            out[f"{name} {kind}"] = rows
    return out


def _common(cache: Path, seed: int):
    """Matched shifts minus truth of the four correlations of ``seed`` on their common windows."""
    errors, indices = [], []
    for name in DIRECTIONS:
        for kind in ("cross", "same"):
            win = windows(cache, name, seed, kind)
            idx, shift = matched(win)
            errors.append(dict(zip(idx, shift - win["true_shift"][idx])))
            indices.append(idx)
    common = indices[0]
    for idx in indices[1:]:
        common = np.intersect1d(common, idx)
    a, sa, b, sb = (np.array([e[i] for i in common]).reshape(-1, 2) for e in errors)
    return common, a, sa, b, sb


def decomposition(cache: Path, seeds) -> dict:
    """Change error ``c = cross - same`` of both directions on common windows, land and water apart:
    the part that flips sign with the bands' roles and the part that does not (module docstring)."""
    parts = {k: [] for k in ("a", "sa", "b", "sb", "wet")}
    for seed in seeds:
        common, a, sa, b, sb = _common(cache, seed)
        for k, v in zip(("a", "sa", "b", "sb"), (a, sa, b, sb)):
            parts[k].append(v)
        parts["wet"].append(water_share(cache, seed)[common] >= WATER_SHARE)
    a, sa, b, sb, wet = (np.concatenate(parts[k]) for k in ("a", "sa", "b", "sb", "wet"))
    c_a, c_b = a - sa, b - sb
    flips, stays = 0.5 * (c_a - c_b), 0.5 * (c_a + c_b)
    out = {}
    for label, sel in (("water", wet), ("land", ~wet)):
        if not sel.any():
            continue
        f = flips[sel]
        out[label] = {
            "n": int(sel.sum()), "cross_rms_px": [rms2(a[sel]), rms2(b[sel])],
            "same_band_rms_px": [rms2(sa[sel]), rms2(sb[sel])],
            "corr_change_a_b": [float(np.corrcoef(c_a[sel, k], c_b[sel, k])[0, 1]) for k in (0, 1)],
            "flipping_mean_px": f.mean(axis=0).round(4).tolist(),
            "flipping_std_px": f.std(axis=0).round(4).tolist(),
            "staying_rms_px": np.sqrt(np.mean(stays[sel] ** 2, axis=0)).round(4).tolist()}
    return out


def candidates(cache: Path, seeds, names=tuple(CANDIDATES)) -> dict:
    """Per (direction, reference, candidate) and content (land, water): windows, 2-D truth rms px of
    the candidate on all matched windows, and the windows it lost (moved :data:`LOST_PX` or more
    from the phase shift, or not finite)."""
    out = {}
    for name in DIRECTIONS:
        for kind in ("cross", "same"):
            err = {k: [] for k in ("pc", *names)}
            wet = []
            for seed in seeds:
                win = windows(cache, name, seed, kind)
                idx, shift = matched(win)
                truth = win["true_shift"][idx]
                wet.append(water_share(cache, seed)[idx] >= WATER_SHARE)
                err["pc"].append(shift - truth)
                for k in names:
                    found = CANDIDATES[k](win["wr"][idx], win["ws"][idx], shift)
                    # a candidate that finds nothing within LOST_PX of the phase shift has lost the window
                    lost = ~(np.abs(found - shift) < LOST_PX).all(axis=1)
                    err[k].append(np.where(lost[:, None], np.nan, found - truth))
            wet = np.concatenate(wet)
            for k, v in err.items():
                e = np.concatenate(v)
                lost = ~np.isfinite(e).all(axis=1)
                out[f"{name} {kind} {k}"] = {
                    part: [int((sel & ~lost).sum()), rms2(e[sel & ~lost]), int((sel & lost).sum())]
                    for part, sel in (("land", ~wet), ("water", wet))}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, help="folder of the scenes and windows (kept); default: temporary")
    ap.add_argument("--seeds", default="11,12,13,14")
    ap.add_argument("--candidates", default=",".join(CANDIDATES), help="window-level candidates ('' for none)")
    ap.add_argument("--json", type=Path, help="write the figures there")
    a = ap.parse_args(argv)
    if not change_pairs.DATA.is_dir():
        print(f"real test data not found at {change_pairs.DATA}", file=sys.stderr)
        return 1
    seeds = [int(s) for s in a.seeds.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        cache = a.cache or Path(tmp)
        cache.mkdir(parents=True, exist_ok=True)
        result = {"seeds": seeds, "kept": kept_report(cache, seeds, change_options()),
                  "decomposition": decomposition(cache, seeds), "detection": detection(cache, seeds)}
        print(f"seeds {seeds}; kept with the change options (cross-band GCPs / truth rms px / the same windows "
              "on the same band: n, rms px / share on water / rms(error / sigma) / mean error px)")
        for name, r in result["kept"].items():
            print(f"  {name:14s} {r['n']:4d} / {r['cross_rms_px']:.4f} / {r['n_same']}, {r['same_band_rms_px']:.4f}"
                  f" / {r['water_share']:.2f} / {r['z']:.2f} / {r['mean_px']}")
        print("decomposition on windows all four correlations match (red scene on NIR, NIR scene on red):")
        for label, r in result["decomposition"].items():
            print(f"  {label:5s} {r['n']:4d} windows  cross rms {r['cross_rms_px'][0]:.4f}, {r['cross_rms_px'][1]:.4f}"
                  f"  same band {r['same_band_rms_px'][0]:.4f}, {r['same_band_rms_px'][1]:.4f}"
                  f"  corr(change A, change B) (row, col) {r['corr_change_a_b'][0]:+.2f}, {r['corr_change_a_b'][1]:+.2f}"
                  f"  flipping part mean {r['flipping_mean_px']} std {r['flipping_std_px']}"
                  f"  staying part rms {r['staying_rms_px']}")
        print("spectral spread over the noise its score predicts: median (share > 1) per seed")
        for key, rows in result["detection"].items():
            print(f"  {key:20s} " + "  ".join(f"{m:.2f} ({f:.2f})" for m, f in rows))
        names = [n for n in a.candidates.split(",") if n]
        if names:
            result["candidates"] = candidates(cache, seeds, names)
            print(f"candidates on all matched windows (n, 2-D truth rms px, lost: moved {LOST_PX} px or more):")
            for key, r in result["candidates"].items():
                print(f"  {key:34s} " + "  ".join(f"{part} {n:4d} {v:.4f} lost {m}" for part, (n, v, m) in r.items()))
    if a.json:
        a.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
