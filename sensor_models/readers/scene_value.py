"""The :class:`Scene` value: a sensor model with where its pixels are and where it came from.

:func:`~sensor_models.readers.scene_input.open_scene` returns a :class:`Scene`: the model, the
rasters of its bands, the file opened, where a crop lies in the full scene, the verdict of a
vendor product's self-check and what the vendor reader parsed and derived
(:class:`ProductMetadata`). Commands read those fields from the value instead of probing the
model for attributes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

__all__ = ["ProductMetadata", "ProductReading", "Scene"]


@dataclass(frozen=True)
class ProductMetadata:
    """What a vendor product's reader parsed from the file and derived while building the model.

    None of it is used by the model's geometry (the model holds its orbit, attitude and look
    polynomials); it says where the model came from and how well the reader's fits hold.

    Parameters
    ----------
    parsed : DimapMetadata or DimapV2Metadata or WorldViewMetadata
        The reader's parse of the metadata file
        (:func:`~sensor_models.readers.dimap_parse.parse_dimap`,
        :func:`~sensor_models.readers.dimap_v2.parse_dimap_v2`,
        :func:`~sensor_models.readers.worldview.parse_worldview`).
    look_fits : dict or None
        SPOT 1-5 DIMAP: model band -> ``LookFit``, the ``tan psi`` polynomials fitted to the
        detector look angles and their residuals
        (:func:`~sensor_models.readers.dimap_interior.fit_look_polynomials`); else None.
    extension_s : tuple of float or None
        DIMAP v2: ``(before, after)``, seconds by which the orbit and attitude were extended
        beyond the image (``EXTENSION_LINES`` lines); else None.
    fold : dict or None
        WorldView: the statistics of folding aberration and refraction into straight rays
        (``refraction_height_m``, ``central_correction_urad``, ``refraction_shift_m`` (min,
        max) and per band ``time_residual_px`` and ``polynomial_residual_px``; see
        :func:`~sensor_models.readers.worldview_los.build_model`); else None.
    """

    parsed: Any
    look_fits: dict | None = None
    extension_s: tuple | None = None
    fold: dict | None = None


class ProductReading(NamedTuple):
    """What a vendor product's ``*_checked`` reader returns.

    Attributes
    ----------
    model : PushbroomModel
        The model the product describes.
    check : ProductCheck
        Its self-check against the product's own statements (``Scene.product_check``).
    metadata : ProductMetadata
        What the reader parsed and derived (``Scene.metadata``).
    """

    model: Any
    check: Any
    metadata: ProductMetadata


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
    metadata : ProductMetadata or None
        What a vendor product's reader parsed and derived (None for manifests and RPCs); it
        describes the full product when the model is a crop's.
    """

    model: Any
    rasters: dict = field(default_factory=dict)
    source: Path | None = None
    raster_candidates: tuple = ()
    raster_tiles: int = 0
    crop: tuple | None = None
    product_check: Any = None
    metadata: ProductMetadata | None = None

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
