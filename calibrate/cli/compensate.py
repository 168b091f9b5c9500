"""``gcpcal compensate``: seed 002's virtual-control-point compensation schemes, simulated."""

from __future__ import annotations

import click

from calibrate.actions.compensate import compensation_study
from calibrate.cli._errors import EXIT_FAILED
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import echo_json, exit_with_status, json_option, out_dir_option

__all__ = ["command"]

_JSON_KEYS = ("scheme", "success", "mean_x_px", "mean_y_px", "rms_x_px", "rms_y_px", "total_px", "max_px",
              "seed_total_px", "installation_arcsec")


def _num(value, spec: str) -> str:
    return format(float("nan") if value is None else value, spec)


def _print_table(out_dir, doc: dict) -> None:
    settings = doc["settings"]
    click.echo(f"{out_dir}: {settings['n_vcp']} virtual control points, "
               f"{settings['n_check']} check points; best {doc['best_scheme']}")
    click.echo(f"{'scheme':8s} {'X mean':>10s} {'Y mean':>10s} {'total':>11s} {'seed total':>10s}")
    for r in doc["rows"]:
        seed_total = "" if r["seed_total_px"] is None else f"{r['seed_total_px']:.3f}"
        click.echo(f"{r['scheme']:8s} {_num(r['mean_x_px'], '10.4f')} {_num(r['mean_y_px'], '10.4f')} "
                   f"{_num(r['total_px'], '11.3e')} {seed_total:>10s}")


@click.command("compensate")
@out_dir_option()
@click.option("--step", "step_px", type=click.FloatRange(min=1.0), default=100.0, show_default=True,
              help="Virtual control point grid step, pixels (seed 002: 100).")
@click.option("--start", "start_px", type=click.FloatRange(min=0.0), default=0.0, show_default=True,
              help="First grid pixel index.")
@click.option("--stop", "stop_px", type=click.FloatRange(min=0.0), default=10000.0, show_default=True,
              help="Last grid pixel index (seed 002: 10000).")
@click.option("--noise-px", type=click.FloatRange(min=0.0), default=0.0, show_default=True,
              help="Gaussian noise added to the virtual control points, pixels.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the noise.")
@click.option("--scheme", "schemes", multiple=True,
              type=click.Choice(["ICO", "ECO", "ECBIC", "ICBEC", "joint", "ICO-g"]),
              help="Schemes to run (repeatable; default all).")
@click.option("--no-figures", is_flag=True, help="Skip the PNG figures.")
@json_option
@click.pass_context
def command(ctx, out_dir, step_px, start_px, stop_px, noise_px, seed, schemes, no_figures, as_json):
    """Seed 002 simulation: ICO, ECO, ECBIC, ICBEC and joint compensation from virtual control points.

    Writes OUT/table.json, OUT/table.csv, OUT/summary.md and OUT/figures/*.png. Exit code 3 when
    a scheme fails.
    """
    with stage_progress(ctx, "gcpcal compensate", as_json):
        doc = compensation_study(out_dir, step_px=step_px, start_px=start_px, stop_px=stop_px, noise_px=noise_px,
                                 seed=seed, schemes=schemes, figures=not no_figures)
    if as_json:
        echo_json({"best_scheme": doc["best_scheme"], "rows": [{k: r.get(k) for k in _JSON_KEYS} for r in doc["rows"]]})
    else:
        _print_table(out_dir, doc)
    failed = [r["scheme"] for r in doc["rows"] if not r["success"]]
    if failed:
        exit_with_status(ctx, EXIT_FAILED, f"scheme(s) {', '.join(failed)} failed (see {out_dir}/table.json)")
