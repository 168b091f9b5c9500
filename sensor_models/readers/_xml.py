"""Strict typed access to a vendor XML tree: every error names the file and the XML path.

Shared by the DIMAP readers (:mod:`sensor_models.readers.dimap`, ``dimap_v2``) and the
DigitalGlobe reader (:mod:`sensor_models.readers.worldview`). A reader subclasses
:class:`StrictXml` with its root element and what it calls the document; how an error names the
field (the caller's ``where`` alone, or ``where/rel``) is :meth:`StrictXml.field_path`.
"""

from __future__ import annotations


import numpy as np

from sensor_models.errors import ManifestError
from sensor_models.files.documents import parse_xml

__all__ = ["StrictXml"]


class StrictXml:
    """A parsed XML file whose root must be :attr:`ROOT`; typed getters raise :class:`ManifestError`.

    Parameters
    ----------
    path : str or Path
        The XML file.

    Raises
    ------
    ManifestError
        Unreadable file, malformed XML, or another root element.
    """

    #: the root element's tag
    ROOT = ""
    #: what the document is, for the wrong-root message
    DOCUMENT = "document"

    def __init__(self, path):
        self.path = str(path)
        self.root = parse_xml(path, error=ManifestError)
        if self.root.tag != self.ROOT:
            raise ManifestError(f"root element is <{self.root.tag}>, expected <{self.ROOT}>: not a {self.DOCUMENT}",
                                path=self.path, field=self.root.tag)

    def field_path(self, where: str, rel: str) -> str:
        """The field an error names for child ``rel`` of the element at ``where`` (default: ``where``).

        Parameters
        ----------
        where : str
            The caller's path of the parent (or of the field itself).
        rel : str
            The child looked up.

        Returns
        -------
        str
        """
        return where

    def error(self, where: str, message: str) -> ManifestError:
        """A :class:`ManifestError` naming the file and the field ``where``.

        Parameters
        ----------
        where : str
            The XML path of the field.
        message : str
            What is wrong.

        Returns
        -------
        ManifestError
        """
        return ManifestError(message, path=self.path, field=where)

    def node(self, parent, rel: str, where: str, *, optional: bool = False):
        """The first child ``rel`` of ``parent``; None when absent and ``optional``.

        Parameters
        ----------
        parent : xml.etree.ElementTree.Element
            Where to look.
        rel : str
            ElementTree path of the child.
        where : str
            The field's name in errors.
        optional : bool
            Return None instead of raising when absent.

        Returns
        -------
        xml.etree.ElementTree.Element or None
        """
        found = parent.find(rel)
        if found is None and not optional:
            raise self.error(self.field_path(where, rel), "is missing")
        return found

    def text(self, parent, rel: str, where: str, *, optional: bool = False):
        """The stripped, non-empty text of child ``rel`` (None when absent and ``optional``).

        Parameters
        ----------
        parent, rel, where, optional
            As :meth:`node`.

        Returns
        -------
        str or None
        """
        el = self.node(parent, rel, where, optional=optional)
        if el is None:
            return None
        value = (el.text or "").strip()
        if not value:
            raise self.error(self.field_path(where, rel), "is empty")
        return value

    def number(self, parent, rel: str, where: str, *, optional: bool = False, positive: bool = False):
        """A finite float (``positive``: > 0) from child ``rel``.

        Parameters
        ----------
        parent, rel, where, optional
            As :meth:`node`.
        positive : bool
            Require a value > 0.

        Returns
        -------
        float or None
        """
        value = self.text(parent, rel, where, optional=optional)
        if value is None:
            return None
        field = self.field_path(where, rel)
        try:
            x = float(value)
        except ValueError:
            raise self.error(field, f"must be a number, got {value!r}") from None
        if not np.isfinite(x):
            raise self.error(field, f"must be finite, got {value!r}")
        if positive and not x > 0.0:
            raise self.error(field, f"must be positive, got {value!r}")
        return x

    def integer(self, parent, rel: str, where: str, *, optional: bool = False, minimum=None):
        """An integer (``+`` sign allowed; ``>= minimum`` when given) from child ``rel``.

        Parameters
        ----------
        parent, rel, where, optional
            As :meth:`node`.
        minimum : int, optional
            Smallest value accepted.

        Returns
        -------
        int or None
        """
        value = self.text(parent, rel, where, optional=optional)
        if value is None:
            return None
        field = self.field_path(where, rel)
        try:
            x = int(value.lstrip("+"))
        except ValueError:
            raise self.error(field, f"must be an integer, got {value!r}") from None
        if minimum is not None and x < minimum:
            raise self.error(field, f"must be >= {minimum}, got {x}")
        return x
