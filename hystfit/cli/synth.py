"""``hystfit synth``: write synthetic captures measured on the virtual actuator (parsing and printing
only; the numerics are in :mod:`hystfit.synth`). Results: the written paths on stdout, one a line."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from ..errors import ConfigError, OutputError
from .app import app, command
from .common import seed_callback, stderr

synth_app = typer.Typer(
    help="Write synthetic captures of a virtual piezo stage (PI hysteresis + switchable effects).",
    no_args_is_help=True,
)
app.add_typer(synth_app, name="synth")

_EFFECTS_HELP = (
    "Effects of the plant: 'default' (creep,dynamics,noise,quantization), 'none', 'all', or a comma "
    "list of asymmetry, creep, dynamics, delay, drift, noise, quantization."
)

Seed = Annotated[
    int,
    typer.Option(
        "--seed", callback=seed_callback,
        help="Seed (0 … 4294967295): the sensor noise uses it, random excitations seed+500; campaign file i uses "
             "seed*1000+i.",
    ),
]
EffectsOpt = Annotated[str, typer.Option("--effects", help=_EFFECTS_HELP)]
Strength = Annotated[
    float,
    typer.Option("--strength", help="Scale every chosen effect's default strength (dynamics: divides f_n)."),
]
Force = Annotated[
    bool,
    typer.Option("--force", help="Write even if the output exists (campaign: only its own files are replaced)."),
]


def _positive(option: str, value: float | None) -> None:
    if value is not None and not value > 0:
        raise ConfigError(f"{option} {value:g}: must be > 0.")


def _plant(effects: str, strength: float, noise_um: float | None = None):
    from .. import synth

    _positive("--strength", strength)
    eff = synth.Effects.parse(effects, strength)
    if eff.noise and noise_um is None and strength != 1.0:  # a blind test's floor 20× its intent
        stderr.print(f"note: --strength {strength:g} scales the sensor noise too (σ = {eff.noise_sigma_um:.3g} µm); "
                     "--noise SIGMA sets it apart", markup=False, highlight=False, soft_wrap=True)
    if noise_um is not None:
        if not noise_um >= 0:
            raise ConfigError(f"--noise {noise_um:g}: the noise σ must be >= 0 (µm).")
        eff = eff.with_noise(noise_um)
    return synth.Plant.default().with_effects(eff)


@command("campaign", on=synth_app)
def campaign(
    out: Annotated[Path, typer.Option("--out", help="Output folder (created if missing).", show_default=False)],
    seed: Seed = 0,
    effects: EffectsOpt = "default",
    strength: Strength = 1.0,
    force: Force = False,
) -> None:
    """Write paper 002's campaign (24 raised cosines + 2 broadband files) measured on the default plant.

    Raised cosine 0→A→0, A = 20/40/60 V × f = 10…80 Hz, 5 cycles at 10 kHz, as aNNV_fNNHz.csv;
    broadband/prbs_60V.csv and broadband/steps_60V.csv.
    """
    from .. import synth

    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {out}: exists and is not a folder.")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise OutputError(f"--out {out}: the folder is not empty; choose another or pass --force.")
    from ..io import check_writable_file

    check_writable_file(out / "a20V_f10Hz.csv")
    plant = _plant(effects, strength)
    for path in synth.make_campaign(out, plant, seed):
        typer.echo(str(path))


@command("capture", on=synth_app)
def capture(
    output: Annotated[Path, typer.Argument(help="File to write (.csv, or .parquet).", show_default=False)],
    amplitude: Annotated[
        float,
        typer.Option(
            "--amplitude", "-a",
            help="Volts: peak A (raised-cosine/triangle/prbs/multisine/steps span 0…A), sine ±A about --offset.",
            show_default=False,
        ),
    ],
    excitation: Annotated[
        str,
        typer.Option("--excitation", "-e", help="raised-cosine, sine, triangle, rising-sine, prbs, multisine or steps."),
    ] = "raised-cosine",
    frequency: Annotated[
        Optional[float],
        typer.Option(
            "--frequency", "-f",
            help="Hz: the period frequency; prbs bit clock (default 2500); multisine highest line (default 1000).",
        ),
    ] = None,
    cycles: Annotated[float, typer.Option("--cycles", help="Periods (periodic excitations).")] = 5,
    fs: Annotated[float, typer.Option("--fs", help="Sample rate (Hz).")] = 10_000.0,
    duration: Annotated[
        Optional[float],
        typer.Option("--duration", help="Seconds (prbs, multisine: default 3; steps: default 7.7)."),
    ] = None,
    offset: Annotated[float, typer.Option("--offset", help="Voltage offset (sine, triangle) (V).")] = 0.0,
    seed: Seed = 0,
    effects: EffectsOpt = "default",
    strength: Strength = 1.0,
    noise: Annotated[
        Optional[float], typer.Option("--noise", help="Sensor noise σ (µm), overriding --effects; 0 = off.")
    ] = None,
    force: Force = False,
) -> None:
    """One capture of the default plant under one excitation."""
    from .. import synth

    if output.exists() and not force:
        raise OutputError(f"{output}: exists; choose another name or pass --force.")
    if output.exists() and output.is_dir():
        raise OutputError(f"{output}: is a folder.")
    from ..io import check_writable_file

    check_writable_file(output)
    if not amplitude >= 0:
        raise ConfigError(f"--amplitude {amplitude:g}: must be >= 0 V.")
    for option, value in (("--frequency", frequency), ("--cycles", cycles), ("--fs", fs), ("--duration", duration)):
        _positive(option, value)
    plant = _plant(effects, strength, noise)
    t, u = synth.make_excitation(
        excitation, amplitude, frequency, cycles=cycles, fs_Hz=fs, duration_s=duration, seed=seed + 500,
        offset_V=offset,
    )
    y = synth.simulate_plant(plant, t, u, seed=seed)  # noise seed; random excitations use seed + 500
    typer.echo(str(synth.write_capture(output, t, u, y, plant.output_unit)))
