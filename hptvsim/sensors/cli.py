"""Sensor commands: ``hptvsim sonar ...``."""

from __future__ import annotations

from pathlib import Path

import click

__all__ = ["register"]


@click.group("sonar")
def sonar_group() -> None:
    """Sonar: the matched filter's and the periodogram's behaviour against SNR."""


@sonar_group.command("snr-plot")
@click.option(
    "--out",
    "out_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=Path("hptvsim-out/sonar-snr.png"),
    show_default=True,
    help="PNG to write.",
)
@click.option("--snr-min", type=float, default=-30.0, show_default=True, help="Lowest echo SNR [dB].")
@click.option("--snr-max", type=float, default=20.0, show_default=True, help="Highest echo SNR [dB].")
@click.option("--snr-step", type=float, default=2.5, show_default=True, help="SNR spacing [dB].")
@click.option(
    "--trials", type=click.IntRange(min=10), default=400, show_default=True, help="Records per SNR."
)
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (same seed, same plot).")
@click.option(
    "--pulse", type=click.Choice(["lfm", "cw"]), default="lfm", show_default=True, help="Pulse kind."
)
def snr_plot(
    out_path: Path, snr_min: float, snr_max: float, snr_step: float, trials: int, seed: int, pulse: str
) -> None:
    """Monte Carlo of the matched filter (Eq. 1): RMS range error and outlier rate against SNR."""
    import numpy as np

    from hptvsim.sensors.signal import plot_snr_sweep, snr_sweep
    from hptvsim.world.sensor_config import SonarConfig

    if snr_step <= 0.0 or snr_max < snr_min:
        raise click.BadParameter("need --snr-step > 0 and --snr-max >= --snr-min", param_hint="--snr-step")
    snrs = np.arange(snr_min, snr_max + 0.5 * snr_step, snr_step)
    config = SonarConfig(pulse="lfm" if pulse == "lfm" else "cw")
    sweep = snr_sweep(config, snrs, trials=trials, seed=seed, progress=True)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    plot_snr_sweep(sweep, str(out_path))
    for snr, rms, out in zip(sweep.snr_db, sweep.rms_error, sweep.outlier_rate, strict=True):
        click.echo(f"  SNR {snr:6.1f} dB: RMS error {rms:9.4f} m, outliers {out:6.1%}")
    click.echo(f"matched-filter error plot: {out_path.resolve()}")


def register(main: click.Group) -> None:
    """Add ``hptvsim sonar``."""
    main.add_command(sonar_group)
