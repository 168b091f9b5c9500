"""Stage action of ``gcpcal compensate``: seed 002's virtual-control-point compensation schemes.

Runs :func:`calibrate.schemes.compensation_study.run_seed002` (GF-4-like 10240 x 10240 camera, seed 002 table 1
distortion, table 2 installation errors) and writes ``OUT/table.json``, ``OUT/table.csv``,
``OUT/summary.md`` and ``OUT/figures/*.png`` atomically (:func:`calibrate.schemes.compensation_outputs.write_study`).
"""

from __future__ import annotations

from calibrate.actions._io import check_output_folder, final_paths, staged_folder

__all__ = ["compensation_study"]


def compensation_study(out_dir, *, step_px: float = 100.0, start_px: float = 0.0, stop_px: float = 10000.0,
                       noise_px: float = 0.0, seed: int = 0, schemes=None, figures: bool = True) -> dict:
    """Simulate seed 002's schemes on virtual control points and write the study.

    Parameters
    ----------
    out_dir : str or Path
        Output folder.
    step_px, start_px, stop_px : float
        Virtual control point grid: step, first and last pixel index.
    noise_px : float
        Gaussian noise added to the virtual control points, pixels.
    seed : int
        Seed of the noise.
    schemes : sequence of str, optional
        Schemes to run (``ICO``, ``ECO``, ``ECBIC``, ``ICBEC``, ``joint``, ``ICO-g``); None: all.
    figures : bool
        Write the PNG figures.

    Returns
    -------
    dict
        The document written to ``table.json`` (``settings``, ``best_scheme``, ``rows``, ...).
    """
    from calibrate.schemes.compensation_outputs import write_study
    from calibrate.schemes.compensation_study import run_seed002

    check_output_folder(out_dir)  # before any work
    study = run_seed002(step_px=step_px, start_px=start_px, stop_px=stop_px, noise_px=noise_px, seed=seed,
                        schemes=list(schemes) if schemes else None)
    with staged_folder(out_dir, ".compensate-") as stage:
        doc = write_study(study, stage, figures=figures)
    return final_paths(doc, stage, out_dir)
