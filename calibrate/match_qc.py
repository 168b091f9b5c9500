"""The match's quality-control figure: where the GCPs are, how the scene is off, how they scatter.

``gcpcal match`` writes ``<table>_qc.png`` beside its GCP table (:func:`write_match_qc`), drawn
from the residual layer of the table against the input model (:mod:`calibrate.residual_layer`):

- left: the image with one arrow per point, from the point to where the input model puts its
  ground point (observed minus modelled row and column, the shift the calibration will remove),
  scaled so that the median arrow is about a twentieth of the image; GCPs blue, check points
  orange; the scale is stated in the title;
- right: per detector array (CCD), histograms of the residuals about a smooth surface fitted to
  the array's residuals (least squares in ``1, row, col, row col, row^2, col^2``), along and
  across track: the spread the matcher leaves once the model's smooth error is set apart, with
  its robust sigma (1.4826 MAD) in the legend.

The figure is a PNG written atomically; it reads nothing but the layer's columns.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["write_match_qc"]

_KIND_COLORS = {"gcp": "#1f5fa8", "check": "#e67e22", "outlier": "#c0392b"}


def _about_smooth_surface(values: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    """``values`` minus their least-squares quadratic surface in (row, col) (the median with < 12 points)."""
    if values.size < 12:
        return values - np.median(values)
    r = (row - row.mean()) / max(np.ptp(row), 1.0)
    c = (col - col.mean()) / max(np.ptp(col), 1.0)
    design = np.column_stack([np.ones_like(r), r, c, r * c, r * r, c * c])
    coef, *_ = np.linalg.lstsq(design, values, rcond=None)
    return values - design @ coef


def _robust_sigma(values: np.ndarray) -> float:
    values = values[np.isfinite(values)]
    return float(1.4826 * np.median(np.abs(values - np.median(values)))) if values.size else float("nan")


def write_match_qc(layer: dict, image_shape, path) -> Path:
    """Draw the match's QC figure (module docstring) into ``path`` (PNG), atomically.

    Parameters
    ----------
    layer : dict of str to ndarray, shape (N,)
        A residual layer (:func:`calibrate.residual_layer.model_residual_layer`): ``row``,
        ``col``, ``kind``, ``ccd``, ``resid_along_px``, ``resid_across_px``.
    image_shape : (int, int)
        Rows and columns of the scene.
    path : str or Path
        The PNG.

    Returns
    -------
    Path
        ``path``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from sensor_models.files.atomic import atomic_file

    path = Path(path)
    row, col = np.asarray(layer["row"], float), np.asarray(layer["col"], float)
    d_row, d_col = np.asarray(layer["resid_along_px"], float), np.asarray(layer["resid_across_px"], float)
    kind, ccd = np.asarray(layer["kind"]).astype(str), np.asarray(layer["ccd"]).astype(str)
    ok = np.isfinite(d_row) & np.isfinite(d_col)
    n_rows, n_cols = image_shape
    length = np.hypot(d_row, d_col)[ok]
    median = float(np.median(length)) if length.size else 0.0
    scale = (0.05 * max(n_rows, n_cols) / median) if median > 0 else 1.0
    fig = Figure(figsize=(13.0, 6.0), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_axes([0.05, 0.1, 0.42, 0.8])
    for k, color in _KIND_COLORS.items():
        sel = ok & (kind == k)
        if sel.any():
            ax.quiver(col[sel], row[sel], d_col[sel] * scale, -d_row[sel] * scale, color=color, angles="xy",
                      scale_units="xy", scale=1.0, width=0.002, label=f"{k} ({int(sel.sum())})")
    ax.set_xlim(0, n_cols)
    ax.set_ylim(n_rows, 0)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    ax.set_title(f"observed minus input model: arrows x{scale:.3g} (median {median:.3g} px)", loc="left",
                 fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    arrays = [a for a in dict.fromkeys(ccd[ok])] or [""]
    for j, (values, label) in enumerate(((d_row, "along track (row)"), (d_col, "across track (column)"))):
        hx = fig.add_axes([0.55, 0.1 + 0.45 * (1 - j), 0.42, 0.33])
        for a in arrays:
            sel = ok & (ccd == a)
            v = _about_smooth_surface(values[sel], row[sel], col[sel]) if sel.any() else np.empty(0)
            if v.size:
                hx.hist(v, bins=40, histtype="step", label=f"{a or 'image'}: {_robust_sigma(v):.3g} px")
        hx.set_title(f"{label}: residual about each array's smooth surface", loc="left", fontsize=10)
        hx.set_xlabel("px")
        hx.legend(fontsize=7, loc="upper right", title="robust sigma", title_fontsize=7)
        hx.grid(True, lw=0.3, alpha=0.5)
    with atomic_file(path, ".png") as tmp:
        fig.savefig(tmp, format="png")
    return path
