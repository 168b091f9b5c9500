"""Star frames in: the frame list, the frames' camera, the pixels and the detections (seed 000 step 1).

A star sequence is a frame list (``frames.json``, :func:`read_frame_list`) naming the frame
rasters, their exposure instants and the manifest of the camera that took them.
:func:`check_frames_camera` refuses frames of another camera (image size, pixel angle within
:data:`IFOV_TOLERANCE`), :func:`check_frame_seconds` the instants out of time order,
:func:`load_frame` reads one frame (an array, FITS or any raster GDAL reads) and
:func:`detect_frames` detects and centroids the stars of every frame
(:func:`gcpmatch.star_tracks.detect_stars`; seed 000 eq. 1 is the intensity-weighted centroid).
The pipeline that uses them is :func:`calibrate.star_calibration.process_frames`.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from sensor_models.errors import InputError
from sensor_models.files.documents import load_json

__all__ = ["IFOV_TOLERANCE", "check_frame_seconds", "check_frames_camera", "detect_frames", "load_frame",
           "read_frame_list"]


# --------------------------------------------------------------------------- inputs
def read_frame_list(path):
    """Read a frame list (``frames.json``, written by ``gcpcal simulate geo-stars``).

    Format (JSON, ``format_version`` 1, ``kind: "geo_star_frames"``)::

        {"format_version": 1, "kind": "geo_star_frames", "epoch_utc": "...",
         "manifest": "manifest.json",
         "frames": [{"path": "frames/frame_0000.tif", "seconds": 0.0}, ...]}

    Paths are relative to the list's folder; seconds count from the manifest's epoch and must
    increase strictly. ``path`` may also be the folder holding ``frames.json``.

    Parameters
    ----------
    path : path
        ``frames.json`` or the folder holding it.

    Returns
    -------
    frames : list of Path
    seconds : ndarray, shape (F,)
    manifest : Path or None
    """
    path = Path(path)
    if path.is_dir():
        path = path / "frames.json"
    if not path.is_file():
        raise InputError("frame list not found", path=str(path))
    doc = load_json(path)
    if not isinstance(doc, dict) or doc.get("kind") != "geo_star_frames":
        raise InputError("not a star frame list (kind must be 'geo_star_frames')", path=str(path), field="kind")
    unknown = set(doc) - {"format_version", "kind", "epoch_utc", "manifest", "frames"}
    if unknown:
        raise InputError(f"unknown keys {sorted(unknown)}", path=str(path))
    if doc.get("format_version") != 1:
        raise InputError(f"unsupported version {doc.get('format_version')!r}", path=str(path), field="format_version")
    entries = doc.get("frames")
    if not isinstance(entries, list) or not entries:
        raise InputError("must be a non-empty list", path=str(path), field="frames")
    frames, seconds = [], []
    for k, e in enumerate(entries):
        if not isinstance(e, dict) or set(e) != {"path", "seconds"}:
            raise InputError("each frame needs exactly 'path' and 'seconds'", path=str(path), field=f"frames[{k}]")
        frames.append(path.parent / e["path"])
        seconds.append(float(e["seconds"]))
    manifest = path.parent / doc["manifest"] if doc.get("manifest") else None
    try:
        checked = check_frame_seconds(seconds, len(frames))
    except InputError as exc:  # name the frame list: the times are its fields
        raise InputError(exc.reason, path=str(path),
                         field="frames[].seconds") from None
    return frames, checked, manifest


#: Largest relative difference of the pixel angle (IFOV) between the camera of a star sequence
#: and the camera it calibrates (a LAB focal length is off by far less; another camera by more).
IFOV_TOLERANCE = 0.02


def _frame_shape(frame) -> tuple[int, int]:
    """``(n_rows, n_cols)`` of a frame raster (FITS through astropy, anything else through GDAL)."""
    if Path(frame).suffix.lower() in (".fits", ".fit", ".fts"):
        return tuple(int(n) for n in load_frame(frame).shape)
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    with warnings.catch_warnings():  # star frames have no map geometry: no warning line
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        try:
            with rasterio.open(frame) as ds:
                return int(ds.height), int(ds.width)
        except RasterioError as exc:
            raise InputError(f"cannot read the star frame ({exc})", path=str(frame)) from None


def check_frames_camera(frames, listed_model, model, *, frames_source, model_source) -> None:
    """Refuse star frames taken by another camera than the one ``model`` describes.

    The frames must have the model's image size (``n_rows x n_cols``, read from the first
    frame's header), and the camera the frame list names (its manifest) must have the model's
    image size and pixel angle (IFOV, within :data:`IFOV_TOLERANCE`).

    Parameters
    ----------
    frames : list of Path
        The frame rasters (:func:`read_frame_list`).
    listed_model : SensorModel or None
        Model of the manifest the frame list names (None when it names none).
    model : SensorModel
        The camera to calibrate (the scene's or ``--manifest``'s model).
    frames_source, model_source : str or Path
        The frame list and the model's file (named in the message).

    Returns
    -------
    None

    Raises
    ------
    InputError
        Naming both files, both sizes or both pixel angles (microradians).
    """
    want = tuple(int(x) for x in model.image_shape)
    shapes = [("frames", _frame_shape(frames[0]))]
    if listed_model is not None:
        shapes.append(("its manifest", tuple(int(x) for x in listed_model.image_shape)))
    for what, shape in shapes:
        if shape != want:
            raise InputError(f"the star frames belong to another camera: {what} {shape[0]} x {shape[1]} px, "
                             f"{model_source} {want[0]} x {want[1]} px", path=str(frames_source))
    ifov_a, ifov_b = getattr(listed_model, "ifov_rad", None), getattr(model, "ifov_rad", None)
    if ifov_a is not None and ifov_b is not None and abs(ifov_a / ifov_b - 1.0) > IFOV_TOLERANCE:
        raise InputError(f"the star frames belong to another camera: pixel angle {1e6 * ifov_a:.3f} urad, "
                         f"{model_source} {1e6 * ifov_b:.3f} urad", path=str(frames_source))


def check_frame_seconds(seconds, n_frames: int) -> np.ndarray:
    """The exposure instants of ``n_frames`` frames, checked: one per frame, finite, increasing.

    Parameters
    ----------
    seconds : array_like, shape (F,)
        Exposure instants, seconds.
    n_frames : int
        Number of frames they belong to.

    Returns
    -------
    ndarray of float64, shape (F,)
        The instants.

    Raises
    ------
    InputError
        A count other than ``n_frames``, a non-finite time, or frames out of time order
        (field ``seconds``, naming the first frame that does not follow its predecessor).
    """
    t = np.asarray(seconds, dtype=np.float64).reshape(-1)
    if t.size != n_frames:
        raise InputError(f"{t.size} times for {n_frames} frames", field="seconds")
    if not np.all(np.isfinite(t)):
        raise InputError("frame times must be finite", field="seconds")
    bad = np.flatnonzero(np.diff(t) <= 0.0)
    if bad.size:
        k = int(bad[0]) + 1
        raise InputError(f"frames out of time order: frame {k} at {t[k]:g} s does not follow {t[k - 1]:g} s",
                         field="seconds")
    return t


def load_frame(frame) -> np.ndarray:
    """A frame as a float32 array (H, W): an array, a FITS file or any raster rasterio reads.

    Parameters
    ----------
    frame : ndarray (H, W) or path
        An image already in memory, a FITS file or a raster file.

    Returns
    -------
    ndarray of float32, shape (H, W)
        Pixel values (counts).
    """
    if isinstance(frame, np.ndarray):
        if frame.ndim != 2:
            raise InputError(f"a frame must be 2-D, got shape {frame.shape}")
        return frame.astype(np.float32, copy=False)
    path = Path(frame)
    if not path.is_file():
        raise InputError("frame not found", path=str(path))
    if path.suffix.lower() in (".fits", ".fit", ".fts"):
        from gcpmatch.star_tracks import read_fits_image

        return read_fits_image(path)[0].astype(np.float32)
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        try:
            with rasterio.open(path) as src:
                return src.read(1, out_dtype=np.float32)
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"cannot read the frame: {exc}", path=str(path)) from None


# --------------------------------------------------------------------------- detection
def detect_frames(frames, *, threshold_sigma: float = 5.0, centroid: str = "iwc", border_px: float = 4.0,
                  saturation: float | None = None, max_stars: int | None = 200):
    """Detect and centroid stars in every frame.

    Parameters
    ----------
    frames : sequence of ndarray (H, W) or path
        Frames in time order (:func:`load_frame`).
    threshold_sigma : float
        Detection threshold above the local background, noise sigmas.
    centroid : {"iwc", "gaussian", "windowed"}
        Centroid estimator (:func:`gcpmatch.star_tracks.detect_stars`).
    border_px : float
        Detections closer than this to the frame edge are dropped, pixels.
    saturation : float, optional
        Saturation level in counts (:func:`gcpmatch.star_tracks.detect_stars`); detections it
        flags as saturated are dropped.
    max_stars : int, optional
        Most detections per frame (:func:`gcpmatch.star_tracks.detect_stars`); None: all.

    Returns
    -------
    list of StarTable
        One per frame, detections closer than ``border_px`` to the edge removed (a cut PSF
        biases the centroid), as are saturated ones when ``saturation`` is given.
    shapes : list of (int, int)
    """
    from gcpmatch.star_tracks import FLAG_SATURATED, detect_stars

    tables, shapes = [], []
    for frame in frames:
        img = load_frame(frame)
        tab = detect_stars(img, threshold_sigma=threshold_sigma, centroid=centroid, saturation=saturation,
                           max_stars=max_stars)
        h, w = img.shape
        keep = ((tab.row_px > border_px) & (tab.row_px < h - border_px) & (tab.col_px > border_px)
                & (tab.col_px < w - border_px) & np.isfinite(tab.row_px) & np.isfinite(tab.col_px)
                & ((tab.flags & FLAG_SATURATED) == 0))
        tables.append(tab.select(keep))
        shapes.append((h, w))
    return tables, shapes
