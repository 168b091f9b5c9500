"""Strict reading of nested JSON-like mappings: every field typed, unknown keys are errors."""

from __future__ import annotations

import math

import numpy as np

from sensor_models.errors import ManifestError

_MISSING = object()


class Fields:
    """Typed access to one JSON object; :meth:`finish` rejects keys nobody asked for.

    Parameters
    ----------
    obj : object
        The decoded JSON value (must be a mapping).
    where : str
        Dotted path of ``obj`` in the document, used in messages (``""`` for the root).
    path : str
        The file, used in messages.
    """

    def __init__(self, obj, where: str, path: str):
        self.where = where
        self.path = path
        if not isinstance(obj, dict):
            raise ManifestError(f"must be an object, got {type(obj).__name__}", path=path, field=where or "(root)")
        self.obj = obj
        self.seen: set[str] = set()

    def _name(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def error(self, key: str, message: str) -> ManifestError:
        """An error about field ``key`` of this object (to raise).

        Parameters
        ----------
        key : str
            Field name inside this object.
        message : str
            What is wrong.

        Returns
        -------
        ManifestError
            Naming the file and the dotted field path.
        """
        return ManifestError(message, path=self.path, field=self._name(key))

    def raw(self, key: str, default=_MISSING):
        """The undecoded value of ``key``, marked as read.

        Parameters
        ----------
        key : str
            Field name.
        default : object, optional
            Returned when the field is absent; without it an absent field is an error.

        Returns
        -------
        object
            The JSON value (or ``default``).
        """
        self.seen.add(key)
        if key not in self.obj:
            if default is _MISSING:
                raise ManifestError("is missing", path=self.path, field=self._name(key))
            return default
        return self.obj[key]

    def has(self, key: str) -> bool:
        """Whether field ``key`` is present (does not mark it as read).

        Parameters
        ----------
        key : str
            Field name.

        Returns
        -------
        bool
        """
        return key in self.obj

    def sub(self, key: str) -> "Fields":
        """The nested object ``key`` (required).

        Parameters
        ----------
        key : str
            Field name.

        Returns
        -------
        Fields
            Over the nested object, with the dotted path extended by ``key``.
        """
        return Fields(self.raw(key), self._name(key), self.path)

    def string(self, key: str, default=_MISSING, *, choices=None) -> str:
        """A string field.

        Parameters
        ----------
        key : str
            Field name.
        default : object, optional
            Returned unchecked when the field is absent; without it the field is required.
        choices : sequence of str, optional
            The allowed values.

        Returns
        -------
        str
        """
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {type(value).__name__}")
        if choices is not None and value not in choices:
            raise self.error(key, f"must be one of {', '.join(map(repr, choices))}, got {value!r}")
        return value

    def number(self, key: str, default=_MISSING, *, positive=False) -> float:
        """A finite number field (JSON integer or float; booleans rejected).

        Parameters
        ----------
        key : str
            Field name.
        default : object, optional
            Returned unchecked when the field is absent; without it the field is required.
        positive : bool
            Require a value > 0.

        Returns
        -------
        float
        """
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f"must be a number, got {type(value).__name__}")
        if not math.isfinite(value):
            raise self.error(key, "must be finite")
        if positive and not value > 0:
            raise self.error(key, f"must be positive, got {value}")
        return float(value)

    def integer(self, key: str, default=_MISSING, *, minimum=None) -> int:
        """An integer field (booleans and floats rejected).

        Parameters
        ----------
        key : str
            Field name.
        default : object, optional
            Returned unchecked when the field is absent; without it the field is required.
        minimum : int, optional
            Smallest allowed value.

        Returns
        -------
        int
        """
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return value
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"must be an integer, got {type(value).__name__}")
        if minimum is not None and value < minimum:
            raise self.error(key, f"must be >= {minimum}, got {value}")
        return value

    def array(self, key: str, shape, default=_MISSING) -> np.ndarray:
        """A numeric array field, every element finite.

        Parameters
        ----------
        key : str
            Field name.
        shape : tuple of (int or None)
            Required shape; ``None`` leaves a dimension free.
        default : object, optional
            Returned unchecked when the field is absent; without it the field is required.

        Returns
        -------
        ndarray of float64
            Of shape ``shape``.
        """
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return value
        try:
            arr = np.asarray(value)
        except (TypeError, ValueError):  # ragged nesting
            raise self.error(key, "must be an array of numbers") from None
        if arr.dtype.kind not in "iuf" and not (arr.dtype.kind == "O" and arr.size == 0):
            raise self.error(key, "must be an array of numbers (no strings, booleans or nulls)")
        arr = arr.astype(np.float64)
        if arr.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, arr.shape)):
            want = "x".join("N" if s is None else str(s) for s in shape)
            raise self.error(key, f"must have shape {want}, got {'x'.join(map(str, arr.shape)) or 'scalar'}")
        if not np.all(np.isfinite(arr)):
            bad = np.argwhere(~np.isfinite(arr))[0]
            raise self.error(key, f"holds a NaN or infinite value at index {tuple(int(i) for i in bad)}")
        return arr

    def finish(self) -> None:
        """Reject the keys of this object that no accessor has read (one error naming them all)."""
        unknown = sorted(set(self.obj) - self.seen)
        if unknown:
            raise ManifestError(
                f"unknown key{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}",
                path=self.path,
                field=self.where or "(root)",
            )
