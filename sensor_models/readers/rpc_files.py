"""RPC00B files: read and write the RPC of a :class:`~sensor_models.models.rpc.RpcModel`.

Formats: OSSIM keyword lists (``*.geom``, ``polynomial_format: B``), DigitalGlobe-style
``*.RPB``, ``*_RPC.TXT``, GeoTIFF RPC tags (any raster GDAL opens whose RPC metadata it finds,
side-cars included), and GDAL's ``RPC`` metadata domain (``rasterio.rpc.RPC``). Every file is in
RPC space (first pixel centre at ``(line, samp) = (0, 0)``, see
:mod:`sensor_models.models.rpc`); the writers fold the model's bias correction into the offsets
and scales (exact for ``a0, a1, b0, b2`` only). Reading is strict: a missing or non-numeric field
raises :class:`~sensor_models.errors.RpcError` naming the file and the field. Writing is atomic
(a temporary file in the same folder, then renamed).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from sensor_models.errors import InputError, RpcError
from sensor_models.files.atomic import atomic_file
from sensor_models.models.rpc import RpcModel

__all__ = [
    "read_rpc",
    "rpc_from_gdal_metadata",
    "rpc_from_rasterio",
    "rpc_to_gdal_metadata",
    "rpc_to_rasterio",
    "write_rpc",
]

# Offsets and scales: our attribute name -> (GDAL metadata key, OSSIM .geom key, .RPB key).
_NORM_FIELDS = {
    "line_off": ("LINE_OFF", "line_off", "lineOffset"),
    "samp_off": ("SAMP_OFF", "samp_off", "sampOffset"),
    "lat_off": ("LAT_OFF", "lat_off", "latOffset"),
    "lon_off": ("LONG_OFF", "long_off", "longOffset"),
    "height_off": ("HEIGHT_OFF", "height_off", "heightOffset"),
    "line_scale": ("LINE_SCALE", "line_scale", "lineScale"),
    "samp_scale": ("SAMP_SCALE", "samp_scale", "sampScale"),
    "lat_scale": ("LAT_SCALE", "lat_scale", "latScale"),
    "lon_scale": ("LONG_SCALE", "long_scale", "longScale"),
    "height_scale": ("HEIGHT_SCALE", "height_scale", "heightScale"),
}
_COEF_FIELDS = {
    "line_num": ("LINE_NUM_COEFF", "line_num_coeff", "lineNumCoef"),
    "line_den": ("LINE_DEN_COEFF", "line_den_coeff", "lineDenCoef"),
    "samp_num": ("SAMP_NUM_COEFF", "samp_num_coeff", "sampNumCoef"),
    "samp_den": ("SAMP_DEN_COEFF", "samp_den_coeff", "sampDenCoef"),
}
_UNITS_TXT = {
    "line_off": "pixels", "samp_off": "pixels", "lat_off": "degrees", "lon_off": "degrees",
    "height_off": "meters", "line_scale": "pixels", "samp_scale": "pixels",
    "lat_scale": "degrees", "lon_scale": "degrees", "height_scale": "meters",
}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------
def read_rpc(path, *, image_shape=None) -> RpcModel:
    """Read an RPC from a file.

    Accepts an OSSIM keyword list (``*.geom``, ``polynomial_format: B``), a standalone
    ``*.RPB`` or ``*_RPC.TXT`` file, or any raster GDAL opens whose RPC metadata it finds
    (GeoTIFF RPC tags, or a side-car ``.RPB`` / ``_RPC.TXT`` beside the raster). For a
    raster, ``image_shape`` is the raster's; for a ``.geom`` it is ``number_lines``,
    ``number_samples`` when present; otherwise it is derived from the offsets. Pass
    ``image_shape=(n_rows, n_cols)`` to set it (for a raster it must match the raster).

    Parameters
    ----------
    path : str or Path
        The file.
    image_shape : (int, int), optional
        ``(n_rows, n_cols)``.

    Returns
    -------
    RpcModel

    Raises
    ------
    RpcError
        The file is unreadable, holds no RPC, a field is missing or not numeric (the
        message names the file and the field), a ``.geom`` holds non-zero OSSIM
        adjustments, or ``image_shape`` contradicts the raster.
    """
    path = Path(path)
    name = path.name.lower()
    if name.endswith(".geom"):
        model = _read_ossim_geom(path)
    elif name.endswith(".rpb"):
        model = _read_rpb(path)
    elif name.endswith("_rpc.txt"):
        model = _read_rpc_txt(path)
    else:
        model = _read_raster(path)
        if image_shape is not None and tuple(image_shape) != model.image_shape:
            raise RpcError(f"image_shape {tuple(image_shape)} contradicts the raster's "
                           f"{model.image_shape}", path=str(path))  # fmt: skip
    if image_shape is None:
        return model
    kw = model.init_kwargs()
    kw["image_shape"] = image_shape
    return RpcModel(**kw)


def rpc_from_gdal_metadata(metadata, *, image_shape=None, source=None) -> RpcModel:
    """Build a model from GDAL ``RPC``-domain metadata (``src.tags(ns="RPC")``), strictly.

    Parameters
    ----------
    metadata : mapping of str to str
        The RPC domain's keys (any case) and values.
    image_shape : (int, int), optional
        ``(n_rows, n_cols)``; default: from the offsets.
    source : str, optional
        Where the metadata come from (for messages).

    Returns
    -------
    RpcModel

    Raises
    ------
    RpcError
        A field is missing or not numeric (the message names it).
    """
    md = {str(k).upper(): v for k, v in dict(metadata).items()}
    kw = {}
    for name, keys in _NORM_FIELDS.items():
        kw[name] = _number(md, keys[0], source, first_token=True)
    for name, keys in _COEF_FIELDS.items():
        if keys[0] not in md:
            raise RpcError("missing", path=source, field=keys[0])
        tokens = str(md[keys[0]]).split()
        if len(tokens) != 20:
            raise RpcError(f"needs 20 coefficients, got {len(tokens)}", path=source,
                           field=keys[0])  # fmt: skip
        kw[name] = [_to_float(t, source, f"{keys[0]}[{i}]") for i, t in enumerate(tokens)]
    for key in ("ERR_BIAS", "ERR_RAND"):
        if key in md:
            kw[key.lower()] = _number(md, key, source, first_token=True)
    return RpcModel(**kw, image_shape=image_shape, source=source)


def rpc_from_rasterio(rpcs, *, image_shape=None, source=None) -> RpcModel:
    """Build a model from a ``rasterio.rpc.RPC`` (e.g. ``src.rpcs``).

    Parameters
    ----------
    rpcs : rasterio.rpc.RPC
    image_shape : (int, int), optional
        ``(n_rows, n_cols)``; default: from the offsets.
    source : str, optional
        Where the RPC comes from (for messages).

    Returns
    -------
    RpcModel
    """
    return rpc_from_gdal_metadata(rpcs.to_gdal(), image_shape=image_shape, source=source)


# ---------------------------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------------------------
def write_rpc(model: RpcModel, path, *, fmt=None, template=None) -> Path:
    """Write an RPC (bias folded in, see :func:`rpc_to_gdal_metadata`) atomically.

    Parameters
    ----------
    model : RpcModel
        The model to write.
    path : str or Path
        Output file. It is first written to a temporary file in the same folder and then
        renamed, so a failure leaves no partial output.
    fmt : {"rpc_txt", "rpb", "geotiff"}, optional
        Default: from the name (``*_RPC.TXT``, ``*.RPB``, ``*.tif``/``*.tiff``).
    template : str or Path, optional
        GeoTIFF only: a raster whose pixels and profile are copied into the output. Without
        it an empty, sparse single-band uint8 GeoTIFF of ``model.image_shape`` is written.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    if fmt is None:
        name = path.name.lower()
        if name.endswith("_rpc.txt"):
            fmt = "rpc_txt"
        elif name.endswith(".rpb"):
            fmt = "rpb"
        elif name.endswith((".tif", ".tiff")):
            fmt = "geotiff"
        else:
            raise RpcError(
                "cannot tell the RPC format from the name; use fmt='rpc_txt', 'rpb' or "
                "'geotiff' (or name it *_RPC.TXT, *.RPB, *.tif)", path=str(path),
            )  # fmt: skip
    if fmt not in ("rpc_txt", "rpb", "geotiff"):
        raise InputError(f"fmt must be 'rpc_txt', 'rpb' or 'geotiff', got {fmt!r}")
    if template is not None and fmt != "geotiff":
        raise InputError("template= applies to fmt='geotiff' only")
    if fmt == "geotiff":
        _write_geotiff(model, path, template)
    else:
        text = _rpc_txt_text(model) if fmt == "rpc_txt" else _rpb_text(model)
        with atomic_file(path) as tmp:
            tmp.write_text(text, encoding="ascii")
    return path


def rpc_to_gdal_metadata(model: RpcModel) -> dict[str, str]:
    """An RPC's GDAL ``RPC`` metadata domain (keys ``LINE_OFF`` ... ``SAMP_DEN_COEFF``), bias folded.

    Parameters
    ----------
    model : RpcModel

    Returns
    -------
    dict of str to str
        Numbers as text (coefficients space-separated), RPC pixel convention.

    Raises
    ------
    RpcError
        The bias has cross terms (``a2`` or ``b1`` non-zero).
    """
    f = _folded(model)
    md = {keys[0]: repr(float(f[name])) for name, keys in _NORM_FIELDS.items()}
    for name, keys in _COEF_FIELDS.items():
        md[keys[0]] = " ".join(repr(float(x)) for x in f[name])
    if model.err_bias is not None:
        md["ERR_BIAS"] = repr(model.err_bias)
    if model.err_rand is not None:
        md["ERR_RAND"] = repr(model.err_rand)
    return md


def rpc_to_rasterio(model: RpcModel):
    """An RPC (bias folded, see :func:`rpc_to_gdal_metadata`) as a rasterio object.

    Parameters
    ----------
    model : RpcModel

    Returns
    -------
    rasterio.rpc.RPC
    """
    from rasterio.rpc import RPC

    return RPC.from_gdal(rpc_to_gdal_metadata(model))


def _folded(model: RpcModel) -> dict:
    """Offsets/scales with the bias folded in (exact for a0, a1, b0, b2 only)."""
    a0, a1, a2, b0, b1, b2 = model.bias
    if a2 != 0.0 or b1 != 0.0:
        raise RpcError(
            "the bias has cross terms (a2, b1) that an RPC cannot hold exactly; "
            "refit with fit_rpc(model, ...) and write the fitted model",
            path=model.source,
        )
    # row = (1 + a1) * (line_n * ls + lo + 0.5) + a0  =>  ls' = (1+a1) ls,
    # lo' = (1 + a1) * (lo + 0.5) + a0 - 0.5 (RPC space keeps the centre-at-0 convention)
    out = {name: getattr(model, name) for name in _NORM_FIELDS}
    out["line_scale"] = (1.0 + a1) * model.line_scale
    out["line_off"] = (1.0 + a1) * (model.line_off + 0.5) + a0 - 0.5
    out["samp_scale"] = (1.0 + b2) * model.samp_scale
    out["samp_off"] = (1.0 + b2) * (model.samp_off + 0.5) + b0 - 0.5
    for name in _COEF_FIELDS:
        out[name] = np.array(getattr(model, name))
    return out


def _rpc_txt_text(model: RpcModel) -> str:
    f = _folded(model)
    lines = [
        f"{keys[0]}: {float(f[name])!r} {_UNITS_TXT[name]}"
        for name, keys in _NORM_FIELDS.items()
    ]
    for name, keys in _COEF_FIELDS.items():
        lines += [f"{keys[0]}_{i + 1}: {float(x)!r}" for i, x in enumerate(f[name])]
    errors = [
        f"{key}: {value!r} meters"
        for key, value in (("ERR_BIAS", model.err_bias), ("ERR_RAND", model.err_rand))
        if value is not None
    ]
    return "\n".join(errors + lines) + "\n"


def _rpb_text(model: RpcModel) -> str:
    f = _folded(model)
    out = ['satId = "UNKNOWN";', 'bandId = "P";', 'SpecId = "RPC00B";', "BEGIN_GROUP = IMAGE"]
    eb = -1.0 if model.err_bias is None else model.err_bias
    er = -1.0 if model.err_rand is None else model.err_rand
    out += [f"\terrBias = {eb!r};", f"\terrRand = {er!r};"]
    out += [f"\t{keys[2]} = {float(f[name])!r};" for name, keys in _NORM_FIELDS.items()]
    for name, keys in _COEF_FIELDS.items():
        vals = ",\n".join(f"\t\t\t{float(x)!r}" for x in f[name])
        out.append(f"\t{keys[2]} = (\n{vals});")
    out += ["END_GROUP = IMAGE", "END;"]
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------------------------------------
# Strict field parsing and the readers and writer of each format
# ---------------------------------------------------------------------------------------------
def _to_float(text, source, field) -> float:
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise RpcError(f"not a number: {text!r}", path=source, field=field) from None
    if not math.isfinite(v):
        raise RpcError(f"not a finite number: {text!r}", path=source, field=field)
    return v


def _number(table, key, source, *, first_token=False) -> float:
    if key not in table:
        raise RpcError("missing", path=source, field=key)
    text = str(table[key]).strip()
    if first_token:
        parts = text.split()
        text = parts[0] if parts else ""
    return _to_float(text, source, key)


def _read_text(path: Path) -> str:
    from sensor_models.files.documents import MAX_DOCUMENT_BYTES, read_text

    # bytes that are not UTF-8 become U+FFFD: every value used is then checked as a number
    return read_text(path, error=RpcError, max_bytes=MAX_DOCUMENT_BYTES, kind="RPC", errors="replace")


def _read_ossim_geom(path: Path) -> RpcModel:
    """OSSIM keyword list: ``key: value`` per line (projection-less RPC, polynomial_format B)."""
    source = str(path)
    table = {}
    for line in _read_text(path).splitlines():
        key, sep, value = line.partition(":")
        if sep:
            table[key.strip()] = value.strip()
    fmt = table.get("polynomial_format")
    if fmt is None:
        raise RpcError("missing (expected 'B', RPC00B term order)", path=source,
                       field="polynomial_format")  # fmt: skip
    if fmt.strip().upper() != "B":
        raise RpcError(
            f"unsupported polynomial format {fmt!r}: only 'B' (RPC00B term order) is read",
            path=source, field="polynomial_format",
        )  # fmt: skip
    # OSSIM adjustments (in-track/cross-track offsets and scales, rotation) would modify the
    # model; they are zero in vendor files. Refuse non-zero ones rather than ignore them.
    for key, value in table.items():
        if re.fullmatch(r"adjustment_\d+\.adj_param_\d+\.parameter", key):
            if _to_float(value, source, key) != 0.0:
                raise RpcError("non-zero OSSIM adjustment parameters are not supported; "
                               "remove the adjustment or apply it as a bias", path=source,
                               field=key)  # fmt: skip
    kw = {name: _number(table, keys[1], source) for name, keys in _NORM_FIELDS.items()}
    for name, keys in _COEF_FIELDS.items():
        kw[name] = [_number(table, f"{keys[1]}_{i:02d}", source) for i in range(20)]
    shape = None
    if "number_lines" in table or "number_samples" in table:
        n_lines = _number(table, "number_lines", source)
        n_samps = _number(table, "number_samples", source)
        if n_lines < 1 or n_samps < 1 or n_lines != int(n_lines) or n_samps != int(n_samps):
            raise RpcError(f"image size must be positive integers, got {n_lines} x {n_samps}",
                           path=source, field="number_lines")  # fmt: skip
        shape = (int(n_lines), int(n_samps))
    return RpcModel(**kw, image_shape=shape, source=source)


def _read_rpc_txt(path: Path) -> RpcModel:
    """``*_RPC.TXT``: ``KEY: value [units]`` per line, coefficients ``LINE_NUM_COEFF_1..20``."""
    source = str(path)
    table = {}
    for line in _read_text(path).splitlines():
        key, sep, value = line.partition(":")
        if sep:
            table[key.strip().upper()] = value.strip()
    md = {keys[0]: table.get(keys[0]) for keys in _NORM_FIELDS.values()}
    md = {k: v for k, v in md.items() if v is not None}
    for keys in _COEF_FIELDS.values():
        vals = []
        for i in range(1, 21):
            key = f"{keys[0]}_{i}"
            vals.append(repr(_number(table, key, source, first_token=True)))
        md[keys[0]] = " ".join(vals)
    for key in ("ERR_BIAS", "ERR_RAND"):
        if key in table:
            md[key] = table[key]
    return rpc_from_gdal_metadata(md, source=source)


_RPB_ASSIGN = re.compile(r"(\w+)\s*=\s*(\([^)]*\)|[^;\n]*);")


def _read_rpb(path: Path) -> RpcModel:
    """DigitalGlobe-style ``*.RPB``: ``name = value;`` and ``name = (v, ..., v);`` in a group."""
    source = str(path)
    text = "\n".join(
        line for line in _read_text(path).splitlines()
        if not line.strip().upper().startswith(("BEGIN_GROUP", "END_GROUP", "END;"))
    )  # fmt: skip
    table = {m.group(1): m.group(2).strip() for m in _RPB_ASSIGN.finditer(text)}
    kw = {name: _number(table, keys[2], source) for name, keys in _NORM_FIELDS.items()}
    for name, keys in _COEF_FIELDS.items():
        if keys[2] not in table:
            raise RpcError("missing", path=source, field=keys[2])
        body = table[keys[2]].strip()
        if not (body.startswith("(") and body.endswith(")")):
            raise RpcError("expected '(c1, ..., c20)'", path=source, field=keys[2])
        tokens = [t.strip() for t in body[1:-1].split(",")]
        if len(tokens) != 20:
            raise RpcError(f"needs 20 coefficients, got {len(tokens)}", path=source,
                           field=keys[2])  # fmt: skip
        kw[name] = [_to_float(t, source, f"{keys[2]}[{i}]") for i, t in enumerate(tokens)]
    err = {}
    for key, arg in (("errBias", "err_bias"), ("errRand", "err_rand")):
        if key in table:
            err[arg] = _number(table, key, source)
    return RpcModel(**kw, **err, source=source)


def _read_raster(path: Path) -> RpcModel:
    import rasterio
    from rasterio.errors import RasterioError

    source = str(path)
    try:
        with rasterio.open(path) as src:
            md = src.tags(ns="RPC")
            shape = (src.height, src.width)
    except (RasterioError, OSError) as err:
        raise RpcError(f"cannot open as a raster: {err}", path=source) from None
    if not md:
        raise RpcError(
            "no RPC found (no GeoTIFF RPC tag and no side-car .RPB or _RPC.TXT); pass the "
            "RPC file itself (.geom, .RPB, _RPC.TXT)", path=source,
        )  # fmt: skip
    return rpc_from_gdal_metadata(md, image_shape=shape, source=source)


def _write_geotiff(model: RpcModel, path: Path, template) -> None:
    import rasterio
    import rasterio.shutil
    from rasterio.errors import RasterioError

    rpcs = rpc_to_rasterio(model)
    try:
        with atomic_file(path, ".tif") as tmp, rasterio.Env(GDAL_PAM_ENABLED="NO"):
            if template is None:
                n_rows, n_cols = model.image_shape
                with rasterio.open(
                    tmp, "w", driver="GTiff", width=n_cols, height=n_rows, count=1,
                    dtype="uint8", tiled=True, sparse_ok=True, compress="deflate", rpcs=rpcs,
                ):  # fmt: skip
                    pass
            else:
                rasterio.shutil.copy(str(template), str(tmp), driver="GTiff")
                with rasterio.open(tmp, "r+") as dst:
                    dst.rpcs = rpcs
    except RasterioError as err:
        raise RpcError(f"GDAL could not write the GeoTIFF: {err}", path=str(path)) from None
