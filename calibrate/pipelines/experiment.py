"""``gcpcal experiment``: run a seed experiment and write its folder.

The experiments (:mod:`calibrate.experiments`) are library code: the one that runs the user's
chain (seed 003: simulate -> match -> calibrate -> truth error) is handed the scene pipeline
(:func:`calibrate.pipelines.scene.scene_pipeline`), so it runs the very stage actions a user runs
and never imports them itself. Simulated data go to a scratch folder beside the output (removed afterwards); the outputs
(``experiment.json``, ``sensitivity/*.json|png``, ``report.html``) are staged and moved into
``OUT`` whole (:func:`calibrate.actions._io.staged_folder`).
"""

from __future__ import annotations

import shutil
from pathlib import Path

from calibrate.actions._io import staged_folder

__all__ = ["experiment_stage"]


def experiment_stage(seed: str, out_dir, *, profile: str = "ideal", quick: bool = False, source=None,
                     frames: int | None = None) -> dict:
    """Run experiment ``seed`` under ``profile`` and write ``out_dir``.

    Parameters
    ----------
    seed : str
        ``000``, ``002``, ``003`` or ``004``.
    out_dir : str or Path
        Output folder (written on success: gcpcal's earlier files replaced, a user's kept).
    profile : str
        ``ideal``, ``realistic`` or the seed's ``paper-*``.
    quick : bool
        The reduced run.
    source : str or Path, optional
        Source radiance raster of experiment 003's ``realistic`` scene (default: procedural).
    frames : int, optional
        Experiment 000: frames per session (default 120, 30 with ``quick``).

    Returns
    -------
    dict
        The document written to ``experiment.json``.
    """
    from calibrate.actions._staging import make_stage_dir
    from calibrate.experiments.registry import run_experiment
    from calibrate.experiments.report import write_experiment
    from calibrate.pipelines.scene import scene_pipeline

    with staged_folder(out_dir, ".experiment-", inputs=[source]) as stage:
        work = make_stage_dir(stage.parent, f"{Path(out_dir).name}-work")  # named so a later run can clean it
        try:
            result = run_experiment(seed, profile, quick=quick, work_dir=work, source=source, pipeline=scene_pipeline,
                                    frames=frames)
        finally:
            shutil.rmtree(work, ignore_errors=True)
        return write_experiment(result, stage)
