"""Command line of the SITL vehicle: ``hptvsim vehicle sitl`` (:mod:`hptvsim.twin.sitl`)."""

from __future__ import annotations

import math

import click

__all__ = ["register"]


def register(main: click.Group) -> None:
    """Add ``hptvsim vehicle sitl`` (the ``vehicle`` group made when not there)."""
    group = main.commands.get("vehicle")
    if not isinstance(group, click.Group):

        @main.group("vehicle")
        def vehicle_group() -> None:
            """Vehicle types: calibrate one from a log, fly one over MAVLink."""

        group = vehicle_group

    @group.command("sitl")
    @click.option(
        "--vehicle", default=None, help="A built-in type or a vehicle file (TOML; a fitted one too)."
    )
    @click.option("--mavlink", "url", required=True, help="Where to speak MAVLink: udpout:HOST:PORT.")
    @click.option(
        "--sysid", type=click.IntRange(1, 254), default=1, show_default=True, help="MAVLink system id."
    )
    @click.option(
        "--speedup",
        type=click.FloatRange(min=0.01, max=1000.0),
        default=1.0,
        show_default=True,
        help="Its clock runs this many times faster than real time.",
    )
    @click.option("--scenario", default=None, help="A scenario (name or file): start pose, currents, seabed.")
    @click.option("--agent", default=None, help="The scenario's agent this vehicle is (default: the first).")
    @click.option(
        "--dof", type=click.Choice(["3", "6"]), default=None, help="Model (default: the scenario's game; 6)."
    )
    @click.option(
        "--seed", type=click.IntRange(0, 2**31 - 1), default=0, show_default=True, help="Start pose seed."
    )
    def vehicle_sitl(
        vehicle: str | None,
        url: str,
        sysid: int,
        speedup: float,
        scenario: str | None,
        agent: str | None,
        dof: str | None,
        seed: int,
    ) -> None:
        """A simulated vehicle that speaks ArduSub's MAVLink (until Ctrl-C or SIGTERM)."""
        from hptvsim.twin.sitl import SitlError, build_vehicle, connect, serve

        try:
            conn = connect(url, sysid)
            try:
                v = build_vehicle(
                    vehicle,
                    dof=int(dof) if dof else None,
                    scenario=scenario,
                    agent=agent,
                    seed=seed,
                    connection=conn,
                )
            except BaseException:
                conn.close()
                raise
        except SitlError as exc:
            raise click.UsageError(str(exc)) from None
        pos, eul = v.model.pose()
        click.echo(
            f"SITL {v.model.name} ({v.model.dof}-DOF), system {sysid}, on {url}, x{speedup:g}; "
            f"at ({pos[0]:.1f}, {pos[1]:.1f}, {pos[2]:.1f}) m, heading {math.degrees(eul[2]):.0f} deg; "
            "disarmed, MANUAL",
            err=True,
        )
        serve(v, speedup=speedup)
        click.echo("SITL stopped", err=True)
