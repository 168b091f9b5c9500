"""The reader of a model file, told by its name (or, for ``.xml``, by its root element).

See the table in :mod:`sensor_models.readers`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

from sensor_models.errors import InputError

__all__ = ["OpenedModel", "open_model", "open_model_with_provenance", "xml_root"]

#: Bytes of an XML file read to find its root element (prolog and comments come before it).
_XML_HEAD_BYTES = 1 << 20

#: Root element of a vendor XML file -> (module, reader function) of its geometric reader, which
#: returns a :class:`~sensor_models.readers.scene_value.ProductReading`
#: ``(model, product check, product metadata)``.
_XML_READERS = {
    "Dimap_Document": ("sensor_models.readers.dimap_v2", "read_dimap_v2_checked"),
    "isd": ("sensor_models.readers.worldview", "read_worldview_checked"),
}


class OpenedModel(NamedTuple):
    """What :func:`open_model_with_provenance` read: the model and what the file said about it.

    Attributes
    ----------
    model : SensorModel
        The model the file describes.
    rasters : dict
        A manifest's ``image.rasters`` (band -> ``RasterRef``, absolute path); empty for every
        other kind (:func:`~sensor_models.readers.scene_input.open_scene` finds their rasters).
    product_check : ProductCheck or None
        A vendor product's self-check; None for manifests and RPC files.
    metadata : ProductMetadata or None
        What a vendor product's reader parsed and derived
        (:class:`~sensor_models.readers.scene_value.ProductMetadata`); None for manifests and
        RPC files.
    """

    model: Any
    rasters: dict
    product_check: Any
    metadata: Any = None


def open_model(path, *, self_check: str = "refuse", **kwargs):
    """Open a sensor model from any supported file (see the module table).

    Parameters
    ----------
    path : str or Path
        The model file; its kind is told by its name (``.json``, ``.dim``, ``.xml`` by its root
        element, anything else RPC).
    self_check : {"refuse", "warn"}
        For a vendor product (``.DIM``, DIMAP v2 or DigitalGlobe ``.XML``): what its reader does
        when the model disagrees with the product's own corners or RPC beyond the tolerance
        (:mod:`sensor_models.readers.self_check`): raise
        :class:`~sensor_models.errors.ProductDisagreementError`, or return the model (the
        disagreement is ``open_scene(...).product_check``).
    **kwargs
        Passed to the reader of that kind (:func:`~sensor_models.readers.scene.read_manifest`,
        :func:`~sensor_models.readers.dimap.read_dimap`, :func:`~sensor_models.readers.rpc_files.read_rpc`).

    Returns
    -------
    SensorModel
        The model the file describes, alone: a manifest's rasters and a product's self-check
        and metadata come with :func:`~sensor_models.readers.scene_input.open_scene` (or
        :func:`open_model_with_provenance`).

    Raises
    ------
    InputError
        If the file does not exist or its kind is not recognized (naming the file); for an
        ``.xml`` product whose reader is not installed, "reader not available".
    """
    return open_model_with_provenance(path, self_check=self_check, **kwargs).model


def open_model_with_provenance(path, *, self_check: str = "refuse", **kwargs) -> OpenedModel:
    """Open a sensor model with the rasters a manifest lists and a vendor product's self-check and metadata.

    Parameters
    ----------
    path, self_check, **kwargs
        As :func:`open_model`. Manifests and RPC files state nothing about themselves to check:
        their ``product_check`` and ``metadata`` are None.

    Returns
    -------
    OpenedModel
        ``(model, rasters, product_check, metadata)``.

    Raises
    ------
    InputError
        As :func:`open_model`.
    """
    from sensor_models.readers.self_check import check_policy

    check_policy(self_check)
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path=str(path))
    name = path.name.lower()
    if name.endswith(".dim"):
        from sensor_models.readers.dimap import read_dimap_checked

        model, check, metadata = read_dimap_checked(path, self_check=self_check, **kwargs)
        return OpenedModel(model, {}, check, metadata)
    if name.endswith(".xml"):
        model, check, metadata = _read_vendor_xml(path, self_check=self_check, **kwargs)
        return OpenedModel(model, {}, check, metadata)
    if name.endswith(".json"):
        from sensor_models.readers.scene import read_manifest_and_rasters

        model, rasters = read_manifest_and_rasters(path, **kwargs)
        return OpenedModel(model, rasters, None)
    from sensor_models.readers.rpc_files import read_rpc

    return OpenedModel(read_rpc(path, **kwargs), {}, None)


def xml_root(path) -> str:
    """The local name of an XML file's root element (namespace dropped).

    Parameters
    ----------
    path : str or Path
        The XML file; only its first element is parsed.

    Returns
    -------
    str
        E.g. ``"Dimap_Document"`` or ``"isd"``.

    Raises
    ------
    InputError
        Not XML, or empty.
    """
    import xml.etree.ElementTree as ET

    try:
        with open(path, "rb") as fh:
            head = fh.read(_XML_HEAD_BYTES)
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path=str(path)) from None
    if b"\x00" in head:
        raise InputError("NUL byte: not an XML text file", path=str(path))
    parser = ET.XMLPullParser(events=("start",))
    try:
        parser.feed(head)  # one call: expat re-scans an unfinished token on every feed
        for _, elem in parser.read_events():
            return elem.tag.rsplit("}", 1)[-1]
    except ET.ParseError as exc:
        raise InputError(f"not readable XML ({exc})", path=str(path)) from None
    if not head.strip():
        raise InputError("empty XML file", path=str(path))
    raise InputError(f"no root element in the first {_XML_HEAD_BYTES >> 10} KiB: not an XML product", path=str(path))


def _read_vendor_xml(path: Path, **kwargs):
    """``(model, product check, product metadata)`` of a DIMAP v2 or WorldView XML file, told by its root element."""
    import importlib

    root = xml_root(path)
    if root not in _XML_READERS:
        raise InputError(f"unknown XML product (root element {root!r}); gcpcal reads DIMAP v2 "
                         "(Dimap_Document) and WorldView (isd) XML", path=str(path))
    module_name, function_name = _XML_READERS[root]
    try:
        reader = getattr(importlib.import_module(module_name), function_name)
    except (ImportError, AttributeError):
        raise InputError(f"reader not available for {root} XML ({module_name}.{function_name})",
                         path=str(path)) from None
    return reader(path, **kwargs)
