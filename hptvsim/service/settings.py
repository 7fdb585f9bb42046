"""Service settings: one frozen dataclass, read from ``HPTVSIM_*`` environment variables.

Every setting has an embedded default, so ``hptvsim serve`` runs with nothing configured
(SQLite in the data folder, the shipped scenarios and policies, a local worker pool). A bad value
is an error naming the variable and what would be valid.

=============================  ===========================================================
variable                       meaning (default)
=============================  ===========================================================
``HPTVSIM_HOST``               interface the API binds (``127.0.0.1``)
``HPTVSIM_PORT``               API port (``8000``)
``HPTVSIM_DATA_DIR``           recordings, trajectories, the SQLite file (``hptvsim-out/service``)
``DATABASE_URL``               SQLAlchemy URL, e.g. ``postgresql+psycopg://...``
                               (``sqlite:///<data dir>/hptvsim.db``)
``HPTVSIM_API_KEY``            when set, every ``/api/v1`` request and the live view need it
                               (required when ``HPTVSIM_HOST`` is not a loopback address)
``HPTVSIM_CORS_ORIGINS``       comma-separated origins of other sites' pages allowed to call the
                               API (none: the dashboard is served by the API itself; ``*`` only
                               with an API key)
``HPTVSIM_INSECURE_OPEN``      ``1``: allow a non-loopback ``HPTVSIM_HOST`` without an API key
                               (a network of your own only; off)
``HPTVSIM_EXECUTOR``           ``local`` (worker processes) or ``ray`` (``local``)
``RAY_ADDRESS``                Ray cluster address for ``HPTVSIM_EXECUTOR=ray`` (a local Ray)
``HPTVSIM_WORKERS``            worker processes of the local executor (CPU count, at most 4)
``HPTVSIM_HOSTS``              spare interactive host processes kept started; each interactive
                               episode runs in a host of its own, taken from the spares (``2``:
                               two creations in a row open at once; a third waits for a host to
                               start, several seconds)
``HPTVSIM_MAX_STEPS``          largest ``max_steps`` a request may ask for (``20000``)
``HPTVSIM_MAX_AGENTS``         most vehicles in a scenario (``16``)
``HPTVSIM_MAX_BODY_BYTES``     largest request body (``1048576``)
``HPTVSIM_MAX_JOBS``           episodes queued or running at once (``256``)
``HPTVSIM_MAX_INTERACTIVE``    interactive episodes open at once, each a process of its own of
                               about 250 MB before its episode (``16``)
``HPTVSIM_MAX_GRID_CELLS``     largest terrain grid of an inline scenario (``4000000``)
``HPTVSIM_IDLE_TIMEOUT_S``     an interactive episode idle this long is cancelled (``600``)
``HPTVSIM_JOB_TIMEOUT_S``      a run longer than this (wall clock) is cancelled (``3600``)
``HPTVSIM_EVENT_HZ``           progress/frame events per second per episode (``10``)
``HPTVSIM_EVENT_STREAM_S``     longest life of one event stream; clients reconnect (``3600``)
``HPTVSIM_PREP_WORKERS``       processes that build clients' scenarios and maps (``1``)
``HPTVSIM_PREP_TIMEOUT_S``     time limit of building one client's scenario (``30``)
``HPTVSIM_VISER``              start the viser live view (``1``; ``0`` to skip)
``HPTVSIM_VISER_PORT``         viser port (``8080``)
``HPTVSIM_VISER_URL``          address of a live view run as its own service (none)
``HPTVSIM_ALLOWED_HOSTS``      comma-separated ``Host`` names the service answers (derived from
                               the bind address: loopback names for a loopback bind; ``*``: any)
``HPTVSIM_EPISODE_MEMORY_MB``  largest estimated memory of one episode, refused at admission (``2048``)
``HPTVSIM_EPISODE_DISK_MB``    largest estimated disk use of one episode, refused at admission (``1024``)
``HPTVSIM_EPISODE_CPU_S``      largest estimated CPU time of one episode, refused at admission,
                               and the CPU-time limit a simulating process enforces (``3600``)
``HPTVSIM_PROCESS_MEMORY_MB``  hard limit on the private writable memory (``RLIMIT_DATA``) of every
                               simulating process: workers, interactive hosts, preparation (``4096``)
``HPTVSIM_DISK_QUOTA_MB``      most disk the stored episodes may use; new episodes are refused
                               beyond it (``10240``)
``HPTVSIM_RETENTION_DAYS``     ended episodes older than this are deleted (``30``)
``HPTVSIM_MAX_SUBSCRIBERS``    event streams and WebSockets open at once, in total (``256``)
``HPTVSIM_MAX_SUBSCRIBERS_PER_EPISODE``
                               event streams and WebSockets open at once on one episode, or on
                               all episodes' stream (``64``)
``HPTVSIM_HOST_CALL_TIMEOUT_S`` longest wait for one interactive call (open, step) (``120``)
``HPTVSIM_HOST_START_TIMEOUT_S``
                               longest wait for a new interactive host process to start, before
                               its first call (``120``)
``HPTVSIM_MAX_DOWNLOADS``      trajectory downloads (json, jsonl, csv) streamed at once; more are
                               answered 503 with ``Retry-After`` (``8``; parquet and recordings
                               are sent from disk and not counted)
``HPTVSIM_SUBSCRIBER_BACKLOG``
                               events one subscriber may have waiting; beyond it the oldest
                               progress or frame is skipped (``8``)
``HPTVSIM_SUBSCRIBER_LAG_LIMIT``
                               events one subscriber may skip in a row, taking none, before it
                               is dropped (``128``)
``HPTVSIM_SEND_TIMEOUT_S``     longest wait for one send to an event subscriber's socket before
                               it is dropped (``10``)
``HPTVSIM_EVENT_BYTES_PER_S``  frames sent to all event subscribers together, at most, in bytes
                               per second (``50000000``)
``HPTVSIM_WEB_DIR``            dashboard files (the checkout's ``web/``)
``HPTVSIM_TWIN_LISTEN``        follow a live MAVLink stream on ``udp:HOST:PORT`` as a running
                               ``twin`` episode (``1``: ``udp:127.0.0.1:14550``; none)
``HPTVSIM_TWIN_IDLE_S``        a twin stream silent this long has ended and is stored (``5``)
``HPTVSIM_TWIN_MAX_MESSAGES``  MAVLink messages one twin episode keeps; a stream that sends more
                               is stored there and goes on as a new episode (``1000000``, about
                               11 h of an ArduSub stream at ~25 messages/s, ~200 MB in memory)
=============================  ===========================================================
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from hptvsim._paths import shipped_dir

__all__ = ["LIMITS", "Settings", "SettingsError"]


LIMITS: tuple[tuple[str, str, type[int] | type[float]], ...] = (
    ("HPTVSIM_WORKERS", "workers", int),
    ("HPTVSIM_HOSTS", "hosts", int),
    ("HPTVSIM_MAX_STEPS", "max_steps", int),
    ("HPTVSIM_MAX_AGENTS", "max_agents", int),
    ("HPTVSIM_MAX_BODY_BYTES", "max_body_bytes", int),
    ("HPTVSIM_MAX_JOBS", "max_jobs", int),
    ("HPTVSIM_MAX_INTERACTIVE", "max_interactive", int),
    ("HPTVSIM_MAX_GRID_CELLS", "max_grid_cells", int),
    ("HPTVSIM_IDLE_TIMEOUT_S", "idle_timeout_s", float),
    ("HPTVSIM_JOB_TIMEOUT_S", "job_timeout_s", float),
    ("HPTVSIM_EVENT_HZ", "event_hz", float),
    ("HPTVSIM_EVENT_STREAM_S", "event_stream_s", float),
    ("HPTVSIM_PREP_WORKERS", "prep_workers", int),
    ("HPTVSIM_PREP_TIMEOUT_S", "prep_timeout_s", float),
    ("HPTVSIM_EPISODE_MEMORY_MB", "episode_memory_mb", int),
    ("HPTVSIM_EPISODE_DISK_MB", "episode_disk_mb", int),
    ("HPTVSIM_EPISODE_CPU_S", "episode_cpu_s", float),
    ("HPTVSIM_PROCESS_MEMORY_MB", "process_memory_mb", int),
    ("HPTVSIM_DISK_QUOTA_MB", "disk_quota_mb", int),
    ("HPTVSIM_RETENTION_DAYS", "retention_days", float),
    ("HPTVSIM_MAX_SUBSCRIBERS", "max_subscribers", int),
    ("HPTVSIM_MAX_SUBSCRIBERS_PER_EPISODE", "max_subscribers_per_episode", int),
    ("HPTVSIM_HOST_CALL_TIMEOUT_S", "host_call_timeout_s", float),
    ("HPTVSIM_HOST_START_TIMEOUT_S", "host_start_timeout_s", float),
    ("HPTVSIM_MAX_DOWNLOADS", "max_downloads", int),
    ("HPTVSIM_SUBSCRIBER_BACKLOG", "subscriber_backlog", int),
    ("HPTVSIM_SUBSCRIBER_LAG_LIMIT", "subscriber_lag_limit", int),
    ("HPTVSIM_SEND_TIMEOUT_S", "send_timeout_s", float),
    ("HPTVSIM_EVENT_BYTES_PER_S", "event_bytes_per_s", float),
    ("HPTVSIM_TWIN_MAX_MESSAGES", "twin_max_messages", int),
)
"""Every setting that bounds a resource: its variable, its field and its type. Each is a finite
number > 0 (checked however the settings are made: ``inf`` would switch a limit off, and ``nan``
compares false with every bound); an integer one from the environment must be written as one."""


class SettingsError(ValueError):
    """An environment variable holds an invalid value (the message names it)."""


def _default_workers() -> int:
    return max(1, min(4, os.cpu_count() or 1))


def _default_web_dir() -> Path:
    return shipped_dir("web", env="HPTVSIM_WEB_DIR")


@dataclass(frozen=True, kw_only=True)
class Settings:
    """Everything the service is configured by (see the module docstring for the variables).

    Attributes:
        host: Interface the API binds.
        port: API port.
        data_dir: Folder of recordings, trajectories and the default SQLite database.
        database_url: SQLAlchemy URL (``None``: SQLite in ``data_dir``).
        api_key: Required ``X-API-Key`` header value (``None``: no authentication).
        cors_origins: Origins allowed by CORS (none by default).
        insecure_open: Allow a non-loopback ``host`` without an API key.
        executor: ``"local"`` worker processes or ``"ray"`` tasks.
        ray_address: Ray cluster address (``None``: start or join a local Ray).
        workers: Worker processes of the local executor.
        hosts: Spare interactive host processes kept started (one per interactive episode).
        max_steps: Largest ``max_steps`` of an episode.
        max_agents: Most vehicles in an episode's scenario.
        max_body_bytes: Largest request body [bytes].
        max_jobs: Most episodes queued or running at once.
        max_interactive: Most interactive episodes open at once.
        max_grid_cells: Largest terrain grid (cells) of a client's inline scenario.
        idle_timeout_s: Interactive episodes idle this long are cancelled [s].
        job_timeout_s: Runs longer than this (wall clock) are cancelled [s].
        event_hz: Progress and frame events per second per episode [1/s].
        event_stream_s: Longest life of one server-sent event stream [s] (EventSource reconnects).
        prep_workers: Processes that build clients' scenarios and draw maps.
        prep_timeout_s: Time limit of one such preparation [s].
        viser: Whether to start the viser live view beside the API.
        viser_port: Port of the viser live view.
        viser_url: Public address of a live view that runs as its own service (shown by the dashboard).
        web_dir: Folder of the dashboard's static files.
        allowed_hosts: ``Host`` header names answered (empty: derived from ``host``; ``"*"``: any).
        episode_memory_mb: Largest estimated memory of one episode [MiB] (admission).
        episode_disk_mb: Largest estimated disk use of one episode [MiB] (admission).
        episode_cpu_s: Largest estimated CPU time of one episode [s] (admission), also enforced.
        process_memory_mb: Limit on the private writable memory (``RLIMIT_DATA``) of every
            simulating process [MiB].
        disk_quota_mb: Most disk the stored episodes may use [MiB].
        retention_days: Ended episodes older than this are deleted [days].
        max_subscribers: Event streams and WebSockets open at once, in total.
        max_subscribers_per_episode: Event streams and WebSockets open at once per episode
            (and on the all-episodes stream).
        host_call_timeout_s: Longest wait for one interactive call [s].
        host_start_timeout_s: Longest wait for a new interactive host process to start [s].
        max_downloads: Trajectory downloads (json, jsonl, csv) streamed at once.
        subscriber_backlog: Events one subscriber may have waiting (the oldest skippable one
            is skipped beyond it).
        subscriber_lag_limit: Events one subscriber may skip in a row before it is dropped.
        send_timeout_s: Longest wait for one send to an event subscriber [s].
        event_bytes_per_s: Frames sent to all event subscribers together, at most [bytes/s].
        twin_listen: ``udp:HOST:PORT`` of a live MAVLink stream the service follows as a running
            ``twin`` episode (:mod:`hptvsim.service.twin`), or None.
        twin_idle_s: A twin stream silent this long has ended and is stored [s].
        twin_max_messages: MAVLink messages one twin episode keeps (then it is stored and the
            stream goes on as a new one): what any sender to the port can make the API hold.
    """

    host: str = "127.0.0.1"
    port: int = 8000
    data_dir: Path = field(default_factory=lambda: Path("hptvsim-out") / "service")
    database_url: str | None = None
    api_key: str | None = None
    cors_origins: tuple[str, ...] = ()
    insecure_open: bool = False
    executor: Literal["local", "ray"] = "local"
    ray_address: str | None = None
    workers: int = field(default_factory=_default_workers)
    hosts: int = 2
    max_steps: int = 20000
    max_agents: int = 16
    max_body_bytes: int = 1 << 20
    max_jobs: int = 256
    max_interactive: int = 16
    max_grid_cells: int = 4_000_000
    idle_timeout_s: float = 600.0
    job_timeout_s: float = 3600.0
    event_hz: float = 10.0
    event_stream_s: float = 3600.0
    prep_workers: int = 1
    prep_timeout_s: float = 30.0
    viser: bool = True
    viser_port: int = 8080
    viser_url: str | None = None
    web_dir: Path = field(default_factory=_default_web_dir)
    allowed_hosts: tuple[str, ...] = ()
    episode_memory_mb: int = 2048
    episode_disk_mb: int = 1024
    episode_cpu_s: float = 3600.0
    process_memory_mb: int = 4096
    disk_quota_mb: int = 10240
    retention_days: float = 30.0
    max_subscribers: int = 256
    max_subscribers_per_episode: int = 64
    host_call_timeout_s: float = 120.0
    host_start_timeout_s: float = 120.0
    max_downloads: int = 8
    subscriber_backlog: int = 8
    subscriber_lag_limit: int = 128
    send_timeout_s: float = 10.0
    event_bytes_per_s: float = 50e6
    twin_listen: str | None = None
    twin_idle_s: float = 5.0
    twin_max_messages: int = 1_000_000

    def __post_init__(self) -> None:
        for _, name, kind in LIMITS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise SettingsError(f"{name} = {value!r} is invalid; valid: a number")
            if not (math.isfinite(value) and value > 0):  # inf would switch a limit off
                raise SettingsError(f"{name} = {value!r} is invalid; valid: a finite number > 0")
            if kind is int and value != int(value):
                raise SettingsError(f"{name} = {value!r} is invalid; valid: an integer > 0")
        for name in ("port", "viser_port"):
            if not 0 <= getattr(self, name) <= 65535:
                raise SettingsError(f"{name} = {getattr(self, name)!r} is invalid; valid: 0..65535")
        if self.executor not in ("local", "ray"):
            raise SettingsError(f"executor = {self.executor!r} is invalid; valid: 'local', 'ray'")
        if self.api_key is not None and len(self.api_key) < 8:
            raise SettingsError("api_key is too short; valid: at least 8 characters")
        if "*" in self.cors_origins and self.api_key is None:
            raise SettingsError(
                "cors_origins = '*' without an API key would let any web page run and delete episodes; "
                "list the origins, or set an API key"
            )
        if not (math.isfinite(self.twin_idle_s) and self.twin_idle_s > 0):
            raise SettingsError(f"twin_idle_s = {self.twin_idle_s!r} is invalid; valid: a finite number > 0")
        if self.twin_listen is not None:
            self._check_twin_listen()
        if not self.loopback and self.api_key is None and not self.insecure_open:
            raise SettingsError(
                f"host = {self.host!r} is reachable from the network, and without an API key anyone "
                "there could run episodes; set HPTVSIM_API_KEY (or HPTVSIM_INSECURE_OPEN=1 on a "
                "network of your own)"
            )

    def _check_twin_listen(self) -> None:
        """``twin_listen`` is ``udp:HOST:PORT``; off this machine only with an API key (or on purpose)."""
        import ipaddress

        from hptvsim.twin.listen import parse_address

        assert self.twin_listen is not None
        try:
            host, _ = parse_address(self.twin_listen)
        except ValueError as exc:
            raise SettingsError(f"twin_listen: {exc}") from None
        try:
            local = host == "localhost" or ipaddress.ip_address(host).is_loopback
        except ValueError:
            local = False
        if not local and not self.insecure_open:
            # the API key guards the API, not the telemetry port: MAVLink packets carry no key, and
            # the listener does not verify MAVLink 2 signatures yet (issue 49)
            raise SettingsError(
                f"twin_listen = {self.twin_listen!r} takes unauthenticated telemetry from the network, "
                "where anyone could send a vehicle of their own (an API key does not protect that port); "
                "listen on 127.0.0.1 and forward the vehicle's stream there, or set HPTVSIM_INSECURE_OPEN=1 "
                "on a network of your own"
            )

    @property
    def loopback(self) -> bool:
        """Whether the service binds a loopback address only (reachable from this machine alone)."""
        import ipaddress

        if self.host == "localhost":
            return True
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            return False

    @property
    def hosts_allowed(self) -> frozenset[str]:
        """The ``Host`` names (without port) the service answers; ``{"*"}`` means any.

        ``allowed_hosts`` when set; otherwise derived from the bind address
        (:func:`hptvsim.viz.gateway.hosts_for_bind`, the live view's gateway applies the same):
        a loopback bind answers ``localhost``, ``127.0.0.1`` and ``::1`` only, so a page whose
        own name was pointed at 127.0.0.1 (DNS rebinding) is refused.
        """
        if self.allowed_hosts:
            return frozenset(h.strip().lower().strip("[]") for h in self.allowed_hosts)
        from hptvsim.viz.gateway import hosts_for_bind

        return hosts_for_bind(self.host)

    @property
    def db_url(self) -> str:
        """The database URL in use (``database_url`` or SQLite in ``data_dir``)."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'hptvsim.db').resolve()}"

    @property
    def episodes_dir(self) -> Path:
        """Folder holding one sub-folder of files per episode."""
        return self.data_dir / "episodes"

    def replace(self, **changes: object) -> Settings:
        """A copy with some settings changed."""
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]  # checked in __post_init__

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> Settings:
        """Read the settings from environment variables (``env``, default ``os.environ``).

        Raises:
            SettingsError: A variable holds an invalid value (named in the message).
        """
        e = os.environ if env is None else env
        kw: dict[str, object] = {}

        def integer(var: str, name: str) -> None:
            if var in e:
                try:
                    kw[name] = int(e[var])
                except ValueError:
                    raise SettingsError(f"{var} = {e[var]!r} is invalid; valid: an integer") from None

        def number(var: str, name: str) -> None:
            if var in e:
                try:
                    value = float(e[var])
                except ValueError:
                    raise SettingsError(f"{var} = {e[var]!r} is invalid; valid: a number") from None
                if not math.isfinite(value):  # inf would switch a limit off, nan compares false
                    raise SettingsError(f"{var} = {e[var]!r} is invalid; valid: a finite number")
                kw[name] = value

        def text(var: str, name: str) -> None:
            if e.get(var):
                kw[name] = e[var]

        for var, name, kind in LIMITS:
            (integer if kind is int else number)(var, name)
            if name in kw and not kw[name] > 0:  # type: ignore[operator]  # a number, read above
                valid = "an integer > 0" if kind is int else "a finite number > 0"
                raise SettingsError(f"{var} = {e[var]!r} is invalid; valid: {valid}")
        text("HPTVSIM_HOST", "host")
        integer("HPTVSIM_PORT", "port")
        if e.get("HPTVSIM_DATA_DIR"):
            kw["data_dir"] = Path(e["HPTVSIM_DATA_DIR"])
        text("DATABASE_URL", "database_url")
        text("HPTVSIM_API_KEY", "api_key")
        if e.get("HPTVSIM_CORS_ORIGINS"):
            kw["cors_origins"] = tuple(o.strip() for o in e["HPTVSIM_CORS_ORIGINS"].split(",") if o.strip())
        if e.get("HPTVSIM_EXECUTOR"):
            value = e["HPTVSIM_EXECUTOR"].strip().lower()
            if value not in ("local", "ray"):
                raise SettingsError(f"HPTVSIM_EXECUTOR = {value!r} is invalid; valid: local, ray")
            kw["executor"] = value
        text("RAY_ADDRESS", "ray_address")

        def flag(var: str, name: str) -> None:
            if var in e:
                value = e[var].strip().lower()
                if value not in ("0", "1", "true", "false", "yes", "no", "on", "off"):
                    raise SettingsError(f"{var} = {value!r} is invalid; valid: 0 or 1")
                kw[name] = value in ("1", "true", "yes", "on")

        flag("HPTVSIM_VISER", "viser")
        flag("HPTVSIM_INSECURE_OPEN", "insecure_open")
        integer("HPTVSIM_VISER_PORT", "viser_port")
        text("HPTVSIM_VISER_URL", "viser_url")
        if e.get("HPTVSIM_WEB_DIR"):
            kw["web_dir"] = Path(e["HPTVSIM_WEB_DIR"])
        if e.get("HPTVSIM_ALLOWED_HOSTS"):
            kw["allowed_hosts"] = tuple(h.strip() for h in e["HPTVSIM_ALLOWED_HOSTS"].split(",") if h.strip())
        if e.get("HPTVSIM_TWIN_LISTEN"):
            value = e["HPTVSIM_TWIN_LISTEN"].strip()
            kw["twin_listen"] = (
                "udp:127.0.0.1:14550" if value.lower() in ("1", "true", "yes", "on") else value
            )
        number("HPTVSIM_TWIN_IDLE_S", "twin_idle_s")
        if "twin_idle_s" in kw and not kw["twin_idle_s"] > 0:  # type: ignore[operator]  # a number
            raise SettingsError(
                f"HPTVSIM_TWIN_IDLE_S = {e['HPTVSIM_TWIN_IDLE_S']!r} is invalid; valid: a number > 0"
            )
        try:
            return cls(**kw)  # type: ignore[arg-type]  # values were converted above
        except SettingsError as exc:
            raise SettingsError(f"{exc} (from the environment)") from None
