"""``hptvsim serve``: start the digital-twin service (API, dashboard, live view) and print its URLs.

Settings come from the environment (:mod:`hptvsim.service.settings`); the options here override
them. With nothing configured it runs on localhost with SQLite in ``hptvsim-out/service``, the
shipped scenarios and policies, and local worker processes. ``make run``, the Docker image and
``python -m hptvsim.service`` all start it through :func:`serve`.
"""

from __future__ import annotations

import logging
import os
import socket
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import click

from hptvsim.service.settings import Settings, SettingsError

if TYPE_CHECKING:
    from fastapi import FastAPI

__all__ = ["register", "serve"]


def _port_free(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError:
            return False
    return True


@click.group(invoke_without_command=True, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--host", default=None, help="Interface to bind (HPTVSIM_HOST; default 127.0.0.1).")
@click.option(
    "--port", type=int, default=None, help="API port (HPTVSIM_PORT; default 8000; 0 picks a free one)."
)
@click.option(
    "--viser-port", type=int, default=None, help="Live view port (HPTVSIM_VISER_PORT; default 8080)."
)
@click.option("--no-viser", is_flag=True, help="Do not start the viser live view.")
@click.option("--workers", type=int, default=None, help="Worker processes (HPTVSIM_WORKERS).")
@click.option(
    "--data-dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Recordings, trajectories and the SQLite file (HPTVSIM_DATA_DIR).",
)
@click.option("--log-level", default="info", type=click.Choice(["debug", "info", "warning", "error"]))
@click.pass_context
def serve(
    ctx: click.Context,
    host: str | None,
    port: int | None,
    viser_port: int | None,
    no_viser: bool,
    workers: int | None,
    data_dir: Path | None,
    log_level: str,
) -> None:
    """Start the hptvsim service: REST API, dashboard and viser live view (and print their URLs).

    ``hptvsim serve view --api URL`` runs the live view alone, following a service's episodes.
    """
    if ctx.invoked_subcommand is not None:
        return
    import uvicorn

    os.environ.setdefault("OMP_NUM_THREADS", "1")  # worker processes inherit it
    try:
        settings = Settings.from_env()
        changes: dict[str, object] = {}
        if host is not None:
            changes["host"] = host
        if port is not None:
            changes["port"] = port
        if viser_port is not None:
            changes["viser_port"] = viser_port
        if no_viser:
            changes["viser"] = False
        if workers is not None:
            changes["workers"] = workers
        if data_dir is not None:
            changes["data_dir"] = data_dir
        if settings.port == 0 or changes.get("port") == 0:
            with socket.socket() as sock:
                sock.bind((str(changes.get("host", settings.host)), 0))
                changes["port"] = sock.getsockname()[1]
        settings = settings.replace(**changes)
    except SettingsError as exc:
        raise click.ClickException(str(exc)) from None
    from hptvsim.service.service import check_writable

    try:
        check_writable(settings.episodes_dir)
    except RuntimeError as exc:
        raise click.ClickException(str(exc)) from None
    if not _port_free(settings.host, settings.port):
        raise click.ClickException(
            f"port {settings.port} on {settings.host} is in use; pick another with --port or HPTVSIM_PORT"
        )
    if settings.viser and settings.viser_port and not _port_free(settings.host, settings.viser_port):
        raise click.ClickException(
            f"the live view's port {settings.viser_port} is in use; "
            "pick another with --viser-port, or --no-viser"
        )
    logging.basicConfig(level=log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from hptvsim.service.app import create_app

    shown = "localhost" if settings.host in ("127.0.0.1", "0.0.0.0", "::") else settings.host
    base = f"http://{shown}:{settings.port}"

    def ready(app: FastAPI) -> None:
        lines = [
            "hptvsim service",
            f"  dashboard:  {base}/",
            f"  API docs:   {base}/docs",
            f"  API:        {base}/api/v1",
            f"  health:     {base}/healthz",
        ]
        viser_url = getattr(app.state, "viser_url", None)
        if viser_url:
            lines.append(f"  live view:  {viser_url}")
        lines.append(f"  database:   {settings.db_url}")
        lines.append(f"  data:       {settings.data_dir.resolve()}")
        click.echo("\n".join(lines))
        sys.stdout.flush()

    app = create_app(settings, on_ready=ready)
    uvicorn.run(
        app,
        host=settings.host,
        port=settings.port,
        log_level=log_level,
        lifespan="on",
        ws_max_size=settings.max_body_bytes,  # WebSocket messages obey the body limit too
        timeout_graceful_shutdown=5,  # event streams never end by themselves
    )


@serve.command("view")
@click.option(
    "--api", "api_url", default="http://127.0.0.1:8000", show_default=True, help="The service to follow."
)
@click.option("--host", default="127.0.0.1", show_default=True, help="Interface the live view binds.")
@click.option(
    "--port", type=click.IntRange(0, 65535), default=8080, show_default=True, help="Live view port."
)
@click.option(
    "--api-key", envvar="HPTVSIM_API_KEY", default=None, help="The service's API key (HPTVSIM_API_KEY)."
)
@click.option(
    "--allowed-hosts",
    envvar="HPTVSIM_VIEW_ALLOWED_HOSTS",
    default=None,
    help="Comma-separated Host names the view answers (HPTVSIM_VIEW_ALLOWED_HOSTS; default: "
    "derived from --host, loopback names for a loopback bind).",
)
def viser_command(api_url: str, host: str, port: int, api_key: str | None, allowed_hosts: str | None) -> None:
    """Run the viser live view on its own, showing the episodes a service runs (its event stream)."""
    import time

    import httpx

    from hptvsim.client import Client, ServiceError
    from hptvsim.viz.viser_view import start_live_view

    hosts = tuple(h.strip() for h in (allowed_hosts or "").split(",") if h.strip())
    try:
        settings = Settings(host=host, api_key=api_key or None, allowed_hosts=hosts)  # the service's rules
    except SettingsError as exc:
        raise click.ClickException(str(exc)) from None
    client = Client(api_url, api_key=api_key or None)

    def launcher(scenario: str, policies: dict[str, str], seed: int) -> str:
        try:
            episode = client.create_episode(
                scenario, policies=policies, seed=seed, label="from the live view"
            )
        except ServiceError as exc:
            raise ValueError(exc.detail) from None
        return str(episode["id"])

    view = start_live_view(
        host=host,
        port=port,
        launcher=launcher,
        api_key=api_key or None,
        allowed_hosts=settings.hosts_allowed,
    )
    click.echo(f"hptvsim live view: {view.url} (following {api_url})")
    sys.stdout.flush()
    try:
        while True:
            try:
                for event in client.events(None, frames=True, static=True):
                    data = dict(event["data"])
                    episode = data.pop("episode", None)
                    view.on_event({"type": event["event"], "episode": episode, "data": data})
            except (httpx.HTTPError, ServiceError) as exc:
                click.echo(f"the service's event stream is unavailable ({exc}); retrying", err=True)
                time.sleep(2.0)
    except KeyboardInterrupt:
        pass
    finally:
        client.close()
        view.stop()


def register(main: click.Group, bench: click.Group) -> None:
    """Add ``hptvsim serve`` to ``main`` and the service benchmark to ``bench``."""
    main.add_command(serve)

    @bench.command("service")
    @click.option("--quick", is_flag=True, help="Seconds instead of a minute.")
    @click.option("--url", default=None, help="Measure a running service (default: start one).")
    @click.option(
        "--workers",
        type=click.IntRange(min=1),
        default=2,
        show_default=True,
        help="Workers of the service it starts.",
    )
    @click.option("--json", "as_json", is_flag=True, help="Print JSON instead of tables.")
    @click.option(
        "--only",
        type=click.Choice(["steps", "episodes", "create", "fanout", "interactive"]),
        multiple=True,
        help="Run only this benchmark (repeatable; default: all). fanout: /healthz under 200 subscribers; "
        "interactive: light steps beside a heavy interactive creation.",
    )
    def bench_command(
        quick: bool, url: str | None, workers: int, as_json: bool, only: tuple[str, ...]
    ) -> None:
        """What the service costs: RemoteEnv steps, API episode runs, creations, event fan-out."""
        import json

        import httpx

        from hptvsim.service.bench import bench_service

        if url is not None:
            try:
                httpx.get(f"{url.rstrip('/')}/healthz", timeout=10.0).raise_for_status()
            except (httpx.HTTPError, httpx.InvalidURL) as exc:
                raise click.BadParameter(
                    f"no hptvsim service answers at {url} ({exc})", param_hint="--url"
                ) from None
        results = bench_service(url=url, quick=quick, workers=workers, only=list(only) or None)
        if as_json:
            click.echo(json.dumps([r.as_dict() for r in results], indent=2))
        else:
            click.echo("\n\n".join(r.table() for r in results))
