"""Commands of the twin layer: ``hptvsim twin replay`` and ``hptvsim twin listen``.

A log that cannot be read ends the command with one line, ``Error: ...`` (exit code 2), and no
output file; a truncated log is read up to its last whole message, with one warning line.
``--store`` needs the service layer above this one: the command line passes its function in
(:func:`register`'s ``store``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

__all__ = ["TwinError", "register"]

LISTEN_MAX_MESSAGES = 1_000_000
"""``twin listen``'s message cap (the service's ``HPTVSIM_TWIN_MAX_MESSAGES`` default)."""

StoreEpisode = Callable[..., str]
"""``store(episode, data_dir, *, label) -> episode id`` (:func:`hptvsim.service.twin.store_twin_episode`)."""


class TwinError(click.ClickException):
    """A log or stream that cannot be used: one line, exit code 2."""

    exit_code = 2


def _report(log: Any, frames: int) -> None:
    armed = log.armed_fraction
    click.echo(
        f"{log.source}: {log.duration:.1f} s, {frames} frames of {log.dt:g} s, "
        f"armed {100 * armed:.1f} % of the time, {len(log.events)} events"
    )


def _outputs(
    episode: Any, record: Path | None, csv: Path | None, store_dir: Path | None, store: StoreEpisode | None
) -> None:
    """Write what was asked (each file whole or not at all)."""
    from hptvsim.twin.replay import write_recording

    if csv is not None:
        episode.log.to_csv(csv)
        click.echo(f"calibration CSV: {csv.resolve()}")
    if record is not None:
        write_recording(episode, record)
        click.echo(f"recording: {record.resolve()}  (open it with `hptvsim replay {record}`)")
    if store_dir is not None:
        assert store is not None
        label = f"twin: {episode.log.source}"
        try:
            episode_id = store(episode, store_dir, label=label)
        except ValueError as exc:  # over the service's disk quota
            raise TwinError(str(exc)) from None
        click.echo(
            f"stored episode {episode_id} ({label}) in {store_dir.resolve()}; `hptvsim serve` lists it"
        )


def register(main: click.Group, *, store: StoreEpisode | None = None) -> click.Group:
    """Add the ``twin`` group to ``main``.

    Args:
        main: The ``hptvsim`` group.
        store: Stores an episode in a service's data folder (enables ``--store``).
    """

    @main.group()
    def twin() -> None:
        """A twin of a real vehicle: its MAVLink logs and live telemetry as episodes."""

    @twin.command("replay")
    @click.argument("log_file", metavar="LOG", type=click.Path(path_type=Path))
    @click.option(
        "--record", type=click.Path(dir_okay=False, path_type=Path), help="Write a rerun recording (.rrd)."
    )
    @click.option(
        "--csv", "csv", type=click.Path(dir_okay=False, path_type=Path), help="Write the calibration CSV."
    )
    @click.option(
        "--store",
        "store_dir",
        type=click.Path(file_okay=False, path_type=Path),
        help="Add the episode to a service's data folder (HPTVSIM_DATA_DIR) and its database.",
    )
    @click.option(
        "--dt",
        type=click.FloatRange(min=0.0, min_open=True, max=10.0),
        default=0.1,
        show_default=True,
        help="Step of the time grid [s].",
    )
    def replay(
        log_file: Path, record: Path | None, csv: Path | None, store_dir: Path | None, dt: float
    ) -> None:
        """Map a MAVLink .tlog or dataflash .BIN log into an episode: recording, CSV, stored episode."""
        from hptvsim._output import progress_bar
        from hptvsim.twin.mavlink import TwinLogError, read_log
        from hptvsim.twin.replay import episode_of

        if store_dir is not None and store is None:
            raise click.UsageError("--store needs the service (install hptvsim[service])")
        size = log_file.stat().st_size if log_file.is_file() else 0
        big = size > 4_000_000  # bytes: a bar for long logs only (a short one is read in a second)
        with progress_bar(
            total=size,
            desc=f"reading {log_file.name}",
            unit="B",
            unit_scale=True,
            leave=False,
            disable=not big,
        ) as bar:

            def advance(done: int, total: int) -> None:
                bar.update(done - bar.n)

            try:
                log = read_log(log_file, dt=dt, progress=advance if big else None)
            except TwinLogError as exc:
                raise TwinError(str(exc)) from None
        for w in log.warnings:
            click.echo(f"Warning: {w}", err=True)
        try:
            episode = episode_of(log)
        except ValueError as exc:
            raise TwinError(str(exc)) from None
        _report(log, len(episode.frames))
        _outputs(episode, record, csv, store_dir, store)

    @twin.command("listen")
    @click.argument("address", metavar="udp:HOST:PORT")
    @click.option(
        "--record",
        type=click.Path(dir_okay=False, path_type=Path),
        help="Write a rerun recording (.rrd) at the end.",
    )
    @click.option(
        "--csv",
        "csv",
        type=click.Path(dir_okay=False, path_type=Path),
        help="Write the calibration CSV at the end.",
    )
    @click.option(
        "--store",
        "store_dir",
        type=click.Path(file_okay=False, path_type=Path),
        help="Add the episode to a service's data folder at the end.",
    )
    @click.option("--viser", is_flag=True, help="Show the vehicle live in a viser view.")
    @click.option(
        "--viser-port", type=click.IntRange(0, 65535), default=8080, show_default=True, help="viser's port."
    )
    @click.option(
        "--idle-timeout",
        type=click.FloatRange(min=0.0, min_open=True),
        default=5.0,
        show_default=True,
        help="The stream has ended after this many seconds without a message.",
    )
    @click.option(
        "--dt", type=click.FloatRange(min=0.0, min_open=True, max=10.0), default=0.1, show_default=True
    )
    @click.option(
        "--max-messages",
        type=click.IntRange(min=1),
        default=LISTEN_MAX_MESSAGES,
        show_default=True,
        help="The stream has ended after this many MAVLink messages (what it can hold in memory is "
        "bounded, as the service's HPTVSIM_TWIN_MAX_MESSAGES).",
    )
    def listen(
        address: str,
        record: Path | None,
        csv: Path | None,
        store_dir: Path | None,
        viser: bool,
        viser_port: int,
        idle_timeout: float,
        dt: float,
        max_messages: int,
    ) -> None:
        """Follow a live MAVLink stream (as QGroundControl does) until it stops; then record it."""
        from hptvsim.twin.listen import Listener, parse_address, viser_sink
        from hptvsim.twin.mavlink import TwinLogError
        from hptvsim.twin.replay import episode_of

        if store_dir is not None and store is None:
            raise click.UsageError("--store needs the service (install hptvsim[service])")
        try:
            parse_address(address)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="udp:HOST:PORT") from None
        view = None
        on_static = on_frame = None
        if viser:
            from hptvsim.viz.viser_view import LiveView

            view = LiveView(port=viser_port, autoplay=False, loop=False).start()
            on_static, on_frame = viser_sink(view, f"twin {address}")
            click.echo(f"viser view: {view.url}")
        listener = Listener(
            address,
            dt=dt,
            idle_timeout_s=idle_timeout,
            on_static=on_static,
            on_frame=on_frame,
            max_messages=max_messages,
        )
        try:
            listener.open()
            click.echo(f"listening on {address} (Ctrl-C or {idle_timeout:g} s of silence ends it)")
            log = listener.run()  # Ctrl-C ends the listening; what arrived is kept
        except TwinLogError as exc:
            raise TwinError(str(exc)) from None
        finally:
            if view is not None:
                view.stop()
        episode = episode_of(log)
        click.echo(f"{listener.state.messages} messages, {listener.state.frames} live frames")
        if listener.state.messages >= max_messages:
            click.echo(f"Warning: stopped at --max-messages {max_messages}; the stream may go on", err=True)
        _report(log, len(episode.frames))
        _outputs(episode, record, csv, store_dir, store)

    return twin
