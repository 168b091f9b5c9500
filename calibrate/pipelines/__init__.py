"""Pipelines: compositions of the stage actions a user runs, one module per composition.

A pipeline calls the very functions the ``gcpcal`` stage commands call (:mod:`calibrate.actions`:
``match`` -> ``calibrate`` -> ``relative``, ``truth error``, ``stars``), in the folder layout of
:mod:`.scene`, so that what a composition reports is what a user's own run of the stages gives.

* :mod:`.scene`: match -> calibrate -> relative (-> truth error) on one scene;
* :mod:`.demo`: ``gcpcal demo``, the scene pipeline on an embedded fixture, scored against its
  TRUE model;
* :mod:`.run`: ``gcpcal run``, match, then calibrate from the GCPs or from star frames;
* :mod:`.campaign`: ``gcpcal campaign``, the run pipeline on many scenes, one Dask task each;
  :mod:`.campaign_resume`, which scene folders of an earlier campaign ``--resume`` keeps;
* :mod:`.experiment`: ``gcpcal experiment``, a seed experiment (:mod:`calibrate.experiments`),
  handed the scene pipeline where it runs the user's chain (seed 003).

The arrows run one way: :mod:`calibrate.cli` -> pipelines -> :mod:`calibrate.actions` -> the
library (the rest of ``calibrate``, :mod:`calibrate.experiments` included). Actions and the library
never import a pipeline; ``tests/test_layers.py`` checks it.
"""
