"""A QGIS style stored inside the residual GeoPackage: each point an arrow along its residual.

QGIS reads the default style of a GeoPackage layer from the ``layer_styles`` table (the table
QGIS itself writes with "Save as default"), so a residual layer dropped on a QGIS map draws each
point as an arrow rotated to the residual's azimuth (``resid_azimuth_deg``, clockwise from north,
as QGIS rotates markers), sized by its length in pixels (``resid_planar_px``, 1.5 to 8 mm over
the layer's range) and coloured by kind (GCP blue, check point orange, outlier red).
:func:`add_residual_style` writes that table into an existing GeoPackage with SQLite.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

__all__ = ["STYLE_NAME", "add_residual_style", "residual_style_qml"]

#: Name of the stored style (QGIS lists it under Layer Properties, Style).
STYLE_NAME = "gcpcal residual arrows"

_KINDS = (("gcp", "GCP", "31,95,168,255"), ("check", "check point", "230,126,34,255"),
          ("outlier", "outlier", "192,57,43,255"))


def _symbol(index: int, color: str) -> str:
    size = 'scale_linear("resid_planar_px", 0, maximum("resid_planar_px"), 1.5, 8)'
    return f"""      <symbol type="marker" name="{index}" alpha="1" clip_to_extent="1" force_rhr="0">
        <layer class="SimpleMarker" pass="0" enabled="1" locked="0">
          <Option type="Map">
            <Option name="name" value="arrow" type="QString"/>
            <Option name="color" value="{color}" type="QString"/>
            <Option name="outline_color" value="35,35,35,255" type="QString"/>
            <Option name="outline_width" value="0.1" type="QString"/>
            <Option name="size" value="4" type="QString"/>
            <Option name="size_unit" value="MM" type="QString"/>
            <Option name="angle" value="0" type="QString"/>
            <Option name="vertical_anchor_point" value="2" type="QString"/>
          </Option>
          <data_defined_properties>
            <Option type="Map">
              <Option name="name" value="" type="QString"/>
              <Option name="properties" type="Map">
                <Option name="angle" type="Map">
                  <Option name="active" value="true" type="bool"/>
                  <Option name="field" value="resid_azimuth_deg" type="QString"/>
                  <Option name="type" value="2" type="int"/>
                </Option>
                <Option name="size" type="Map">
                  <Option name="active" value="true" type="bool"/>
                  <Option name="expression" value="{size.replace('"', '&quot;')}" type="QString"/>
                  <Option name="type" value="3" type="int"/>
                </Option>
              </Option>
              <Option name="type" value="collection" type="QString"/>
            </Option>
          </data_defined_properties>
        </layer>
      </symbol>
"""


def residual_style_qml() -> str:
    """The QGIS style (QML) of a residual layer (module docstring).

    Returns
    -------
    str
        A QML document: categorized by ``kind``, one arrow marker per category.
    """
    categories = "".join(f'      <category value="{k}" symbol="{i}" label="{label}" render="true"/>\n'
                         for i, (k, label, _) in enumerate(_KINDS))
    symbols = "".join(_symbol(i, color) for i, (_, _, color) in enumerate(_KINDS))
    return ("<!DOCTYPE qgis PUBLIC 'http://mrcc.com/qgis.dtd' 'SYSTEM'>\n"
            '<qgis version="3.22.0" styleCategories="Symbology">\n'
            '  <renderer-v2 type="categorizedSymbol" attr="kind" forceraster="0" symbollevels="0" '
            'enableorderby="0">\n'
            f"    <categories>\n{categories}    </categories>\n"
            f"    <symbols>\n{symbols}    </symbols>\n"
            "  </renderer-v2>\n"
            "</qgis>\n")


def add_residual_style(path, layer: str) -> None:
    """Store :func:`residual_style_qml` as the default QGIS style of ``layer`` in the GeoPackage.

    Parameters
    ----------
    path : str or Path
        A GeoPackage holding ``layer`` (written by gcpcal, not yet in place: the caller renames it).
    layer : str
        The layer's name.
    """
    con = sqlite3.connect(str(Path(path)))
    try:
        with con:
            con.execute("""CREATE TABLE IF NOT EXISTS layer_styles (
                id INTEGER PRIMARY KEY AUTOINCREMENT, f_table_catalog TEXT(256), f_table_schema TEXT(256),
                f_table_name TEXT(256), f_geometry_column TEXT(256), styleName TEXT(30), styleQML TEXT,
                styleSLD TEXT, useAsDefault BOOLEAN, description TEXT, owner TEXT(30), ui TEXT(30),
                update_time DATETIME DEFAULT CURRENT_TIMESTAMP)""")
            con.execute("DELETE FROM layer_styles WHERE f_table_name = ?", (layer,))
            con.execute("INSERT INTO layer_styles (f_table_catalog, f_table_schema, f_table_name, f_geometry_column, "
                        "styleName, styleQML, styleSLD, useAsDefault, description, owner, ui) "
                        "VALUES ('', '', ?, 'geom', ?, ?, '', 1, ?, '', '')",
                        (layer, STYLE_NAME, residual_style_qml(),
                         "arrows along each residual (azimuth, length in px), coloured by kind"))
    finally:
        con.close()
