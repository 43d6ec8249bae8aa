"""A throw-away PostgreSQL server on loopback for tests (initdb + pg_ctl in a temporary directory).

The server binaries come from the Debian ``postgresql`` package (``.ci/run`` installs it). They
are looked up on ``PATH``, then through ``pg_config --bindir``, then in Debian's versioned layout.
PostgreSQL refuses to run as root: when the tests run as root, the server runs as the
``postgres`` system user (created by the Debian package) through ``runuser``.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

_SERVER_USER = "postgres"


class PostgresUnavailable(RuntimeError):
    """The PostgreSQL server binaries (or the user to run them as) are missing."""


def find_server_bindir() -> Path:
    """
    Directory holding ``initdb``, ``pg_ctl`` and ``postgres``.

    :raises PostgresUnavailable: when no such directory exists
    """
    candidates: list[Path] = []
    initdb = shutil.which("initdb")
    if initdb is not None:
        candidates.append(Path(initdb).resolve().parent)
    pg_config = shutil.which("pg_config")
    if pg_config is not None:
        result = subprocess.run([pg_config, "--bindir"], capture_output=True, text=True, check=False)
        if result.returncode == 0:
            candidates.append(Path(result.stdout.strip()))
    # Debian/Ubuntu layout: /usr/lib/postgresql/<major>/bin, newest first.
    versions = glob.glob("/usr/lib/postgresql/*/bin")
    candidates += [Path(p) for p in sorted(versions, key=lambda p: int(Path(p).parent.name), reverse=True)]
    for bindir in candidates:
        if all((bindir / tool).is_file() for tool in ("initdb", "pg_ctl", "postgres")):
            return bindir
    raise PostgresUnavailable(
        "PostgreSQL server binaries (initdb, pg_ctl, postgres) not found on PATH, via pg_config or in "
        "/usr/lib/postgresql/*/bin; install the Debian package: apt-get install -y postgresql"
    )


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class PostgresServer:
    """
    A PostgreSQL cluster in a temporary directory, listening on 127.0.0.1 only, trust authentication.

    Use as a context manager; ``url(database)`` gives an SQLAlchemy/Optuna storage URL.

    :param start_timeout: seconds to wait for the server to accept connections
    """

    def __init__(self, start_timeout: float = 60.0) -> None:
        self.bindir = find_server_bindir()
        self.start_timeout = start_timeout
        self.run_as: str | None = None
        if os.geteuid() == 0:
            try:
                pwd.getpwnam(_SERVER_USER)
            except KeyError:
                raise PostgresUnavailable(
                    f"running as root and there is no {_SERVER_USER!r} user to run the server as "
                    "(the Debian postgresql package creates it)"
                ) from None
            if shutil.which("runuser") is None:
                raise PostgresUnavailable("running as root and `runuser` is missing (util-linux)")
            self.run_as = _SERVER_USER
        self.port = 0
        self.root: Path | None = None

    @property
    def datadir(self) -> Path:
        assert self.root is not None, "server not started"
        return self.root / "data"

    def _run(self, *command: str, timeout: float) -> subprocess.CompletedProcess:
        argv = [str(self.bindir / command[0]), *command[1:]]
        if self.run_as is not None:
            argv = ["runuser", "-u", self.run_as, "--", *argv]
        result = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, check=False)
        if result.returncode != 0:
            raise RuntimeError(
                f"{' '.join(argv)} failed ({result.returncode}):\n{result.stdout}\n{result.stderr}"
            )
        return result

    def start(self) -> PostgresServer:
        self.root = Path(tempfile.mkdtemp(prefix="ua2c-pg-"))
        if self.run_as is not None:
            entry = pwd.getpwnam(self.run_as)
            os.chown(self.root, entry.pw_uid, entry.pw_gid)
        initdb = ("initdb", "-D", str(self.datadir), "-U", "postgres", "-A", "trust", "-E", "UTF8",
                  "--no-locale", "--no-sync")  # fmt: skip
        self._run(*initdb, timeout=120)
        for attempt in range(3):  # the free port may be taken between probing and binding
            self.port = _free_port()
            options = (
                f"-c listen_addresses=127.0.0.1 -c port={self.port} -c unix_socket_directories={self.root} "
                "-c fsync=off -c synchronous_commit=off -c full_page_writes=off -c max_connections=50"
            )
            pg_ctl = ("pg_ctl", "-D", str(self.datadir), "-l", str(self.root / "server.log"), "-o", options,
                      "-w", "-t", str(int(self.start_timeout)), "start")  # fmt: skip
            try:
                self._run(*pg_ctl, timeout=self.start_timeout + 10)
                break
            except RuntimeError:
                if attempt == 2:
                    log = self.root / "server.log"
                    raise RuntimeError(
                        f"PostgreSQL did not start:\n{log.read_text() if log.exists() else ''}"
                    ) from None
        return self

    def create_database(self, name: str) -> str:
        """
        Create database ``name`` and return its URL.

        :param name: a plain identifier
        """
        import psycopg2

        if not name.isidentifier():
            raise ValueError(f"database name must be a plain identifier, got {name!r}")
        deadline = time.monotonic() + self.start_timeout
        while True:
            try:
                connection = psycopg2.connect(
                    host="127.0.0.1", port=self.port, user="postgres", dbname="postgres"
                )
                break
            except psycopg2.OperationalError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        connection.autocommit = True
        with connection.cursor() as cursor:
            cursor.execute(f"CREATE DATABASE {name}")
        connection.close()
        return self.url(name)

    def url(self, database: str) -> str:
        return f"postgresql+psycopg2://postgres@127.0.0.1:{self.port}/{database}"

    def stop(self) -> None:
        if self.root is None:
            return
        try:
            if (self.datadir / "postmaster.pid").exists():
                # A throw-away cluster: no shutdown checkpoint needed.
                self._run("pg_ctl", "-D", str(self.datadir), "-m", "immediate", "-w", "stop", timeout=60)
        finally:
            shutil.rmtree(self.root, ignore_errors=True)
            self.root = None

    def __enter__(self) -> PostgresServer:
        try:
            return self.start()
        except BaseException:
            self.stop()
            raise

    def __exit__(self, *exc_info: object) -> None:
        self.stop()
