"""Text documents read as a user's input: every way a file can be malformed becomes an InputError.

Each reader of a JSON, YAML, XML or CSV file decodes it here, so a file that is not what it
claims to be ends as one line naming the file and where it breaks, never as a foreign
exception (``UnicodeDecodeError``, ``RecursionError``, ``csv.Error``, ``MemoryError``):

====================================  ========================================================
malformation                          message (after ``<file>: ``)
====================================  ========================================================
unreadable (permission, a folder)     ``cannot read: <reason>``
larger than :data:`MAX_DOCUMENT_BYTES` ``is <n> MiB; a <kind> document is at most ...``
not UTF-8 (a Latin-1 byte, binary)    ``line L, column C: not UTF-8 text (byte 0xe9: ...)``
NUL bytes                             ``line L: NUL byte; not a text file``
syntax                                ``is not valid JSON (line L, column C: ...)`` and alike
nesting deeper than Python recurses   ``nesting deeper than <n> levels ...``
a CSV field over the csv limit        ``line L: malformed CSV (field larger than ...)``
====================================  ========================================================

A UTF-8 byte-order mark is accepted and dropped.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

from sensor_models.errors import InputError

__all__ = ["MAX_DOCUMENT_BYTES", "csv_error", "load_json", "load_yaml", "parse_xml", "read_bytes", "read_text"]

#: Largest JSON, YAML or XML document read, bytes (256 MiB). Parsing builds Python objects of
#: roughly 10 to 50 times a document's size (a JSON number costs 24 to 32 bytes plus its list
#: slot), so a larger "manifest" would exhaust memory before any field is checked. The largest
#: real metadata gcpcal reads are a few MiB (a SPOT 5 DIMAP listing every detector, a
#: WorldView XML with its ephemeris and attitude); a scene manifest of a full 40 000-line scene
#: with per-line times stays under a few tens of MiB.
MAX_DOCUMENT_BYTES = 256 << 20

_MIB = float(1 << 20)


def _err(error, message: str, path) -> InputError:
    return error(message, path=str(path))


def read_bytes(path, *, error=InputError, max_bytes: int | None = None, kind: str = "text") -> bytes:
    """The bytes of a user's file, refusing what cannot be read or is too large.

    Parameters
    ----------
    path : str or Path
        The file.
    error : type, optional
        The :class:`~sensor_models.errors.InputError` subclass raised (e.g. ``ManifestError``).
    max_bytes : int, optional
        Refuse a larger file (default: no limit).
    kind : str
        What the document is, for the size message (``"JSON"``).

    Returns
    -------
    bytes
    """
    path = Path(path)
    try:
        if max_bytes is not None:
            size = path.stat().st_size
            if size > max_bytes:
                raise _err(error, f"is {size / _MIB:.0f} MiB; a {kind} document is at most {max_bytes / _MIB:.0f} MiB "
                                  "(is this the right file?)", path)
        return path.read_bytes()
    except OSError as exc:
        raise _err(error, f"cannot read: {exc.strerror or exc}", path) from None
    except MemoryError:
        raise _err(error, "cannot read: out of memory", path) from None


def _line_col(data: bytes, offset: int) -> tuple[int, int]:
    line = data.count(b"\n", 0, offset) + 1
    return line, offset - (data.rfind(b"\n", 0, offset) + 1) + 1


def decode_text(data: bytes, path, *, error=InputError, errors: str = "strict") -> str:
    """UTF-8 text of ``data`` (a BOM dropped), refusing other encodings and NUL bytes.

    Parameters
    ----------
    data : bytes
        The file's bytes.
    path : str or Path
        The file, named in messages.
    error : type, optional
        The InputError subclass raised.
    errors : {"strict", "replace"}
        ``"replace"`` accepts bytes that are not UTF-8 (formats whose readers check every value
        they use, e.g. RPC keyword lists); NUL bytes are refused either way.

    Returns
    -------
    str
    """
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    nul = data.find(b"\x00")
    if nul >= 0:
        line, col = _line_col(data, nul)
        raise _err(error, f"line {line}, column {col}: NUL byte; not a text file", path)
    try:
        return data.decode("utf-8", errors=errors)
    except UnicodeDecodeError as exc:
        line, col = _line_col(data, exc.start)
        raise _err(error, f"line {line}, column {col}: not UTF-8 text (byte {data[exc.start]:#04x}: {exc.reason}); "
                          "save it as UTF-8", path) from None


def read_text(path, *, error=InputError, max_bytes: int | None = None, kind: str = "text",
              errors: str = "strict") -> str:
    """A user's text file as ``str``: :func:`read_bytes` then :func:`decode_text`.

    Parameters
    ----------
    path : str or Path
        The file.
    error : type, optional
        The InputError subclass raised.
    max_bytes : int, optional
        Refuse a larger file.
    kind : str
        What the document is, for messages.
    errors : {"strict", "replace"}
        See :func:`decode_text`.

    Returns
    -------
    str
    """
    return decode_text(read_bytes(path, error=error, max_bytes=max_bytes, kind=kind), path, error=error,
                       errors=errors)


def _too_deep(kind: str) -> str:
    return (f"is not valid {kind}: nesting deeper than {sys.getrecursionlimit()} levels "
            "(no gcpcal document nests more than a few)")


def load_json(path, *, error=InputError):
    """Decode a JSON document (:data:`MAX_DOCUMENT_BYTES` at most).

    Parameters
    ----------
    path : str or Path
        The file.
    error : type, optional
        The InputError subclass raised.

    Returns
    -------
    object
        The decoded document (the caller checks its type).
    """
    import json

    text = read_text(path, error=error, max_bytes=MAX_DOCUMENT_BYTES, kind="JSON")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise _err(error, f"is not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})", path) from None
    except RecursionError:
        raise _err(error, _too_deep("JSON"), path) from None
    except MemoryError:
        raise _err(error, "is too large to decode in the memory available", path) from None


def load_yaml(path, *, error=InputError):
    """Decode a YAML document with ``yaml.safe_load`` (:data:`MAX_DOCUMENT_BYTES` at most).

    Parameters
    ----------
    path : str or Path
        The file.
    error : type, optional
        The InputError subclass raised.

    Returns
    -------
    object
        The decoded document; None for an empty one.
    """
    import yaml

    text = read_text(path, error=error, max_bytes=MAX_DOCUMENT_BYTES, kind="YAML")
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or "syntax error"
        raise _err(error, f"is not valid YAML{where}: {problem}", path) from None
    except RecursionError:
        raise _err(error, _too_deep("YAML"), path) from None
    except MemoryError:
        raise _err(error, "is too large to decode in the memory available", path) from None


def parse_xml(path, *, error=InputError):
    """Parse an XML document into an ElementTree root (:data:`MAX_DOCUMENT_BYTES` at most).

    The bytes are read first and given to the parser in one call (the parser's encoding
    declaration applies; a file fed in pieces costs time quadratic in a very long line).

    Parameters
    ----------
    path : str or Path
        The file.
    error : type, optional
        The InputError subclass raised.

    Returns
    -------
    xml.etree.ElementTree.Element
        The root element.
    """
    import xml.etree.ElementTree as ET

    data = read_bytes(path, error=error, max_bytes=MAX_DOCUMENT_BYTES, kind="XML")
    nul = data.find(b"\x00")
    if nul >= 0:
        line, col = _line_col(data, nul)
        raise _err(error, f"line {line}, column {col}: NUL byte; not a text file", path)
    try:
        parser = ET.XMLParser()
        parser.feed(data)
        return parser.close()
    except ET.ParseError as exc:
        raise _err(error, f"is not well-formed XML ({exc})", path) from None
    except RecursionError:
        raise _err(error, _too_deep("XML"), path) from None
    except MemoryError:
        raise _err(error, "is too large to parse in the memory available", path) from None


def csv_error(exc: csv.Error, path, line: int, *, error=InputError, field: str | None = None) -> InputError:
    """The InputError of a ``csv.Error`` (bad quoting, a field over the csv module's size limit).

    Parameters
    ----------
    exc : csv.Error
        The error the reader raised.
    path : str or Path
        The CSV file.
    line : int
        The reader's ``line_num`` (1-based; the header is line 1).
    error : type, optional
        The InputError subclass returned.
    field : str, optional
        The column concerned.

    Returns
    -------
    InputError
        To raise ``from None``.
    """
    return error(f"line {max(int(line), 1)}: malformed CSV ({exc})", path=str(path), field=field)
