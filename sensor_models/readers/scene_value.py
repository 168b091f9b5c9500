"""The :class:`Scene` value: a sensor model with where its pixels are and where it came from.

:func:`~sensor_models.readers.scene_input.open_scene` returns a :class:`Scene`: the model, the
rasters of its bands, the file opened, where a crop lies in the full scene and the verdict of a
vendor product's self-check. Commands read those fields from the value instead of probing the
model for attributes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["Scene"]


@dataclass(frozen=True)
class Scene:
    """A SCENE as opened: the model and the provenance of its pixels.

    Parameters
    ----------
    model : SensorModel
        The sensor model; a crop's model describes the crop's pixels.
    rasters : dict
        Band -> ``{"path": str, "index": int}`` (absolute path, 1-based raster band); empty when
        no raster was found.
    source : Path
        The file opened (manifest, model file or raster).
    raster_candidates : tuple of str
        The files looked for when no raster was found, else empty.
    raster_tiles : int
        Number of tiles a tiled DIMAP product names (0 when the product is not tiled).
    crop : tuple or None
        ``(row0, col0, full_shape)`` when the raster is a crop of the full scene: the full-scene
        row and column of the crop's first pixel corner and the full model's ``image_shape``.
    product_check : ProductCheck or None
        A vendor product's self-check (None for manifests and RPCs).
    """

    model: Any
    rasters: dict = field(default_factory=dict)
    source: Path | None = None
    raster_candidates: tuple = ()
    raster_tiles: int = 0
    crop: tuple | None = None
    product_check: Any = None

    def raster_of(self, band=None) -> tuple[str, int] | None:
        """Where the pixels of ``band`` are.

        Parameters
        ----------
        band : str, optional
            Band name (default: the model's reference band).

        Returns
        -------
        tuple of (str, int) or None
            ``(path, index)`` (1-based raster band), or None when the scene has no raster for it.
        """
        key = band if band is not None else getattr(self.model, "reference_band", None)
        ref = self.rasters.get(key)
        if ref is None:
            return None
        return str(ref["path"]), int(ref.get("index", 1))
