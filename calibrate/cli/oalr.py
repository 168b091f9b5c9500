"""``gcpcal oalr``: camera changes from autocollimation cross marks (seed 004)."""

from __future__ import annotations

import click

from calibrate.actions.oalr import oalr_from_csv
from calibrate.cli.options import echo_json, json_option, out_dir_option

__all__ = ["command"]


@click.command("oalr")
@click.argument("marks", metavar="MARKS.csv", type=click.Path(dir_okay=False))
@out_dir_option()
@click.option("--reference", type=int, default=0, show_default=True, help="Data row (0-based) of the nominal marks.")
@click.option("--focal-mm", type=float, default=6550.0, show_default=True, help="Effective focal length f.")
@click.option("--baseline-mm", type=float, default=669.0, show_default=True, help="Distance L between the SMCCDs.")
@click.option("--pixel-um", type=float, default=None,
              help="SMCCD pixel pitch (default: the pitch subtending 1 arcsec at f, 31.755 um at 6550 mm).")
@click.option("--sigma-k-px", type=float, default=0.144, show_default=True,
              help="Error of each mark displacement coordinate (seed 004: 0.430 lab, 0.144 flight).")
@click.option("--beta-deg", type=float, default=0.0, show_default=True, help="SMCCD angle off axis in YOZ.")
@click.option("--alpha-deg", type=float, default=0.0, show_default=True, help="SMCCD angle off axis in XOZ.")
@click.option("--ccd-size-px", type=float, default=None, help="SMCCD size; positions beyond it are errors.")
@click.option("--reproduce-table3", "table3", is_flag=True, help="Add seed 004 table 3, ours beside the paper's.")
@json_option
def command(marks, out_dir, reference, focal_mm, baseline_mm, pixel_um, sigma_k_px, beta_deg, alpha_deg,
            ccd_size_px, table3, as_json):
    """Focal-length change and camera rotations from OALR cross marks in MARKS.csv (seed 004).

    MARKS.csv has the columns time,ccd1_x_px,ccd1_y_px,ccd2_x_px,ccd2_y_px (x = column, y = row,
    pixels), or time,ccd1_frame,ccd2_frame (SMCCD frames, paths relative to the CSV). Writes
    OUT/oalr.json. Format, frames and units: docs/oalr_marks.md; example:
    fixtures/oalr_marks/marks.csv.
    """
    if pixel_um is None:
        from calibrate.schemes.autocollimation import ARCSEC

        pixel_um = focal_mm * ARCSEC * 1000.0
    doc = oalr_from_csv(marks, out_dir, reference=reference, focal_mm=focal_mm, baseline_mm=baseline_mm,
                        pixel_um=pixel_um, sigma_k_px=sigma_k_px, beta_deg=beta_deg, alpha_deg=alpha_deg,
                        ccd_size_px=ccd_size_px, table3=table3)
    last = doc["epochs"][-1]
    summary = {"n_epochs": len(doc["epochs"]), "last": {k: last[k] for k in
               ("time", "delta_f_mm", "rot_x_arcsec", "rot_y_arcsec", "rot_z_arcsec")}, "sigmas": doc["sigmas"]}
    if as_json:
        echo_json(summary)
    else:
        s = doc["sigmas"]
        click.echo(f"{out_dir}/oalr.json: {summary['n_epochs']} epochs; last: df {last['delta_f_mm']:+.4f} mm "
                   f"(+/- {s['sigma_f_mm']:.4f}), rot x {last['rot_x_arcsec']:+.3f}\" y {last['rot_y_arcsec']:+.3f}\" "
                   f"z {last['rot_z_arcsec']:+.2f}\" (+/- {s['sigma_rot_x_arcsec']:.3f}, "
                   f"{s['sigma_rot_y_arcsec']:.3f}, {s['sigma_rot_z_arcsec']:.2f})")
        if table3:
            for line in doc["table3"]["discrepancies"]:
                click.echo(f"table 3: {line}")
