"""Child process of ``bench/bench_localization.py --shareloc-python PATH``: shareloc's C++ RPC
localization over a DEM, timed on one thread.

Runs in a separate Python environment that has shareloc (CNES, Apache-2.0) installed; it
imports only numpy and shareloc, never gcpcal, so gcpcal does not depend on shareloc. Reads from
``FOLDER`` (written by the parent):

* ``rpc.tif``: a GeoTIFF whose RPC tags gcpcal's ``write_rpc`` wrote; shareloc reads it with
  its own reader (``RPCoptim.load``: rasterio, ``topleftconvention=True``, which adds 0.5 to the
  line and sample offsets, so its ``(row, col)`` are GDAL's: the first pixel's centre at
  ``(0.5, 0.5)``, as gcpcal's);
* ``dem.tif``: ellipsoidal heights (float32, NaN voids), read by shareloc's ``dtm_reader``
  without a geoid (its heights are then taken as ellipsoidal), voids filled by its default
  strategy (``rio_fillnodata``);
* ``rows.npy``, ``cols.npy``: the pixels, float64.

Times ``bindings_cpp.RPC.direct_loc_dtm(rpc, rows, cols, dtm)`` (shareloc's full C++ path for an
EPSG:4326 DTM: per point, the line of sight between the DTM's lowest and highest height, each
end from the inverse RPC by Newton to 1e-6 px, then the walk through the DTM cells) with the
conversion of its output to a numpy array, and the public Python wrapper
``RPCoptim.direct_loc_dtm``; best of ``--repeat`` each. Writes ``shareloc_lonlath.npy``
(3, n: lon, lat, h) and prints one JSON line with the timings.

Usage: ``PYTHON bench/shareloc_child.py FOLDER [--repeat 3]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from importlib.metadata import version  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def load_inputs(folder: Path):
    """shareloc's RPC and C++ DTM, and the pixels, from the parent's files.

    Parameters
    ----------
    folder : Path
        The folder with ``rpc.tif``, ``dem.tif``, ``rows.npy`` and ``cols.npy``.

    Returns
    -------
    rpc : shareloc.geomodels.rpc_optim.RPCoptim
    dtm : bindings_cpp.DTMIntersection
    rows, cols : numpy.ndarray, shape (n,)
        Pixel coordinates, GDAL convention.
    filled : int
        DEM nodes that shareloc's reader filled (voids).
    """
    import bindings_cpp
    from shareloc.dtm_reader import dtm_reader
    from shareloc.geomodels.rpc_optim import RPCoptim

    rpc = RPCoptim.load(str(folder / "rpc.tif"))
    image = dtm_reader(str(folder / "dem.tif"))
    filled = int(np.count_nonzero(image.mask == 0))
    dtm = bindings_cpp.DTMIntersection(image.epsg, image.alt_data, image.nb_rows, image.nb_columns,
                                       image.transform)
    rows, cols = np.load(folder / "rows.npy"), np.load(folder / "cols.npy")
    return rpc, dtm, rows, cols, filled


def time_localization(rpc, dtm, rows, cols, repeat: int) -> tuple[dict, np.ndarray]:
    """Best-of-``repeat`` times of the C++ call and of the Python wrapper.

    Parameters
    ----------
    rpc, dtm
        From :func:`load_inputs`.
    rows, cols : numpy.ndarray, shape (n,)
    repeat : int

    Returns
    -------
    seconds : dict
        ``cpp`` (binding call + ``np.array`` of its output) and ``wrapper``
        (``RPCoptim.direct_loc_dtm``), best of ``repeat``, CPU seconds (``time.process_time``).
    lonlath : numpy.ndarray, shape (3, n)
        Longitude, latitude (degrees), ellipsoidal height (m) from the C++ call; NaN where the
        line of sight misses the DTM.
    """
    import bindings_cpp

    best = {"cpp": np.inf, "wrapper": np.inf}
    lonlath = None
    for _ in range(repeat):
        t0 = time.process_time()
        lonlath = np.array(bindings_cpp.RPC.direct_loc_dtm(rpc, rows, cols, dtm))
        best["cpp"] = min(best["cpp"], time.process_time() - t0)
        t0 = time.process_time()
        wrapped = rpc.direct_loc_dtm(rows, cols, dtm)
        best["wrapper"] = min(best["wrapper"], time.process_time() - t0)
    if not np.array_equal(wrapped.T, lonlath, equal_nan=True):
        raise SystemExit("shareloc's wrapper and C++ call disagree")
    return best, lonlath


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    rpc, dtm, rows, cols, filled = load_inputs(args.folder)
    seconds, lonlath = time_localization(rpc, dtm, rows, cols, args.repeat)
    np.save(args.folder / "shareloc_lonlath.npy", lonlath)
    print(json.dumps({"seconds": seconds, "shareloc_version": version("shareloc"),
                      "python": platform.python_version(), "dem_nodes_filled": filled,
                      "threads": {k: os.environ[k] for k in ("OMP_NUM_THREADS", "NUMBA_NUM_THREADS")}}))


if __name__ == "__main__":
    main()
