"""A throwaway PostgreSQL server for the tests (imported as ``pg_cluster``).

:meth:`PgCluster.start` runs ``initdb`` into a new temporary folder and starts the server from
Debian's ``postgresql`` package (``/usr/lib/postgresql/<version>/bin``, or ``initdb`` and
``pg_ctl`` on ``PATH``, or the folder ``HPTVSIM_PG_BINDIR`` names). The server never runs as root:
as root, every command runs as the ``postgres`` user (``runuser -u postgres --``), who owns the
folder. It listens on 127.0.0.1 on a free port, puts its unix socket in its own folder, and lets
in one superuser with a random password. :meth:`PgCluster.stop` stops it (``pg_ctl stop -m
immediate``) and deletes the folder; :meth:`PgCluster.pause` and :meth:`PgCluster.resume` stop
and start it again with its data (a database server that goes away for a while). Each
pytest-xdist worker may start one: folders come from ``mkdtemp`` and ports from the kernel, so
they never collide.

The server is tuned for throwaway data (no fsync); it is not a place to keep anything.
"""

from __future__ import annotations

import atexit
import contextlib
import glob
import os
import pwd
import secrets
import shutil
import socket
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

INSTALL_HINT = (
    "the PostgreSQL tests need the PostgreSQL server programs (initdb, pg_ctl): install Debian's "
    "`postgresql` package (`sudo apt-get install postgresql`, or `make system-deps`), or set "
    "HPTVSIM_PG_BINDIR to the folder holding them"
)
REQUIRE_VARIABLE = "HPTVSIM_REQUIRE_POSTGRES"
"""Set to ``1`` (``make unit`` does) to fail, rather than skip, when PostgreSQL is missing."""
SUPERUSER = "hptvsim"
RUN_AS = "postgres"
"""The account the server runs under when the tests run as root."""


class PgUnavailable(RuntimeError):
    """No PostgreSQL server programs on this machine (the message says what to install)."""


def find_bindir() -> Path:
    """The folder of ``initdb`` and ``pg_ctl``, newest PostgreSQL first.

    Raises:
        PgUnavailable: No such folder.
    """
    candidates: list[Path] = []
    if os.environ.get("HPTVSIM_PG_BINDIR"):
        candidates.append(Path(os.environ["HPTVSIM_PG_BINDIR"]))

    def version(path: str) -> tuple[int, ...]:
        name = Path(path).parent.name
        return tuple(int(p) for p in name.split(".") if p.isdigit())

    debian = sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=version, reverse=True)
    candidates += [Path(p) for p in debian]
    on_path = shutil.which("initdb")
    if on_path:
        candidates.append(Path(on_path).parent)
    for c in candidates:
        if (c / "initdb").is_file() and (c / "pg_ctl").is_file() and (c / "postgres").is_file():
            return c
    raise PgUnavailable(INSTALL_HINT)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class PgCluster:
    """A running throwaway PostgreSQL server.

    Attributes:
        root: Its temporary folder (data in ``data/``, the socket in ``socket/``, ``server.log``).
        port: Its TCP port on 127.0.0.1.
        password: The superuser's password.
        bindir: The folder of the server programs.
        user: The account the server runs as (None: the current one).
    """

    root: Path
    port: int
    password: str
    bindir: Path
    user: str | None
    _databases: int = field(default=0, repr=False)

    @classmethod
    def start(cls, attempts: int = 3) -> PgCluster:
        """``initdb`` a new cluster in a temporary folder and start its server.

        Args:
            attempts: Ports to try (another process may take a free port before the server does).

        Raises:
            PgUnavailable: No PostgreSQL server programs, or no account to run them under.
            RuntimeError: initdb or the server failed (the message holds their output).
        """
        bindir = find_bindir()
        user: str | None = None
        if os.geteuid() == 0:
            try:
                pwd.getpwnam(RUN_AS)
            except KeyError:
                raise PgUnavailable(
                    f"the tests run as root, and PostgreSQL refuses to: the user {RUN_AS!r} that "
                    f"Debian's `postgresql` package creates is missing; {INSTALL_HINT}"
                ) from None
            if shutil.which("runuser") is None:
                raise PgUnavailable(
                    "the tests run as root and need `runuser` (util-linux) to drop to postgres"
                )
            user = RUN_AS
        # /tmp itself, not pytest's folders: those are private to the user running the tests
        root = Path(tempfile.mkdtemp(prefix="hptvsim-pg-", dir="/tmp"))
        cluster = cls(root=root, port=0, password=secrets.token_hex(16), bindir=bindir, user=user)
        try:
            cluster._initdb()
            for attempt in range(attempts):
                cluster.port = _free_port()
                try:
                    cluster._run([str(bindir / "pg_ctl"), *cluster._start_args()], timeout=60)
                    break
                except RuntimeError:
                    if attempt == attempts - 1:
                        raise
            atexit.register(cluster.stop)
            return cluster
        except BaseException:
            cluster.stop()
            raise

    def _run(self, args: list[str], timeout: float = 120) -> str:
        if self.user is not None:
            args = ["runuser", "-u", self.user, "--", *args]
        # cwd: the server's account may not be allowed into the current folder
        proc = subprocess.run(
            args, cwd=self.root, capture_output=True, text=True, timeout=timeout, check=False
        )
        if proc.returncode != 0:
            log = self.root / "server.log"
            tail = log.read_text(errors="replace")[-3000:] if log.exists() else ""
            raise RuntimeError(
                f"{' '.join(args)} exited with {proc.returncode}:\n{proc.stdout}{proc.stderr}{tail}"
            )
        return proc.stdout

    def _initdb(self) -> None:
        (self.root / "socket").mkdir()
        pwfile = self.root / "pwfile"
        pwfile.write_text(self.password + "\n")
        pwfile.chmod(0o600)
        if self.user is not None:
            account = pwd.getpwnam(self.user)
            for path in (self.root, self.root / "socket", pwfile):
                os.chown(path, account.pw_uid, account.pw_gid)
        self.root.chmod(0o700)
        try:
            self._run(
                [
                    str(self.bindir / "initdb"),
                    "--pgdata",
                    str(self.root / "data"),
                    "--username",
                    SUPERUSER,
                    "--pwfile",
                    str(pwfile),
                    "--auth",
                    "scram-sha-256",
                    "--encoding",
                    "UTF8",
                    "--locale",
                    "C",
                    "--no-sync",
                ]
            )
        finally:
            pwfile.unlink(missing_ok=True)

    def _start_args(self) -> list[str]:
        options = " ".join(
            [
                "-c listen_addresses=127.0.0.1",
                f"-c port={self.port}",
                f"-c unix_socket_directories={self.root / 'socket'}",
                "-c max_connections=200",
                "-c shared_buffers=32MB",
                # throwaway data: durability traded for speed
                "-c fsync=off",
                "-c synchronous_commit=off",
                "-c full_page_writes=off",
            ]
        )
        return [
            "start",
            "--pgdata",
            str(self.root / "data"),
            "--log",
            str(self.root / "server.log"),
            "--options",
            options,
            "--wait",
            "--timeout",
            "60",
        ]

    def url(self, database: str = "postgres") -> str:
        """The SQLAlchemy URL of one database of this server (psycopg 3 driver)."""
        return f"postgresql+psycopg://{SUPERUSER}:{self.password}@127.0.0.1:{self.port}/{database}"

    def create_database(self, prefix: str = "t") -> str:
        """Create a new empty database; returns its SQLAlchemy URL."""
        import psycopg

        self._databases += 1
        name = f"{prefix}_{self._databases}"  # one server per test process: names are its own
        with psycopg.connect(
            host="127.0.0.1",
            port=self.port,
            user=SUPERUSER,
            password=self.password,
            dbname="postgres",
            autocommit=True,
        ) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        return self.url(name)

    def pause(self) -> None:
        """Stop the server at once (``-m immediate``, as a crash would), keeping its data."""
        self._run(
            [str(self.bindir / "pg_ctl"), "stop", "--pgdata", str(self.root / "data"), "-m", "immediate"],
            timeout=60,
        )

    def resume(self) -> None:
        """Start the server again after :meth:`pause`, on the same port with the same data."""
        self._run([str(self.bindir / "pg_ctl"), *self._start_args()], timeout=60)

    def stop(self) -> None:
        """Stop the server at once (``-m immediate``) and delete its folder; safe to call twice."""
        if not self.root.exists():
            return
        if (self.root / "data" / "postmaster.pid").exists():
            with contextlib.suppress(RuntimeError, subprocess.TimeoutExpired):
                self._run(
                    [
                        str(self.bindir / "pg_ctl"),
                        "stop",
                        "--pgdata",
                        str(self.root / "data"),
                        "-m",
                        "immediate",
                    ],
                    timeout=60,
                )
        shutil.rmtree(self.root, ignore_errors=True)
        with contextlib.suppress(Exception):
            atexit.unregister(self.stop)
