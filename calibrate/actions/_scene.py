"""Reading a scene for a stage: moved to :mod:`sensor_models.readers.scene_input`.

Stages open their SCENE with :func:`sensor_models.readers.open_scene`, which finds the raster and
crops the model to it; ``crop_to_raster`` stays importable from here for branches that still do.
"""

from __future__ import annotations

from sensor_models.readers.scene_input import crop_to_raster

__all__ = ["crop_to_raster"]
