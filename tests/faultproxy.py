"""A fault-injecting HTTP reverse proxy for tests: the real S3 server behind it, answers of its own by rule.

:class:`FaultProxy` listens on 127.0.0.1 (a free port) and relays each request to the upstream endpoint
byte for byte (head as received, Host included, bodies by Content-Length or chunked framing, streamed in
blocks; keep-alive on both sides; interim 1xx answers of the upstream skipped). A client signs its requests
(SigV4) for the proxy's host:port, and the upstream checks them against the Host it receives, the same. A
:class:`Rule` turns the *first*..*last* requests matching a method, a path pattern and a query pattern into
an error answer of its own, an S3 ``<Error>`` document (``503 SlowDown``, ``500 InternalError``,
``403 AccessDenied``), after reading the request's body. ``forwarded`` and ``injected`` count what it did;
``log`` lists ``(method, path?query, status)``. What s3fs/aiobotocore send: bodies with a Content-Length (PUTs
with ``Expect: 100-continue``, answered here and not forwarded: SigV4 does not sign it), ranged GETs, path-style
keys; a chunked body is relayed as framed. Standard library only::

    with FaultProxy(s3.endpoint_url, [Rule("PUT", r"/out\\.laz$", first=1, last=2)]) as proxy:
        env = {**s3.env(), "AWS_ENDPOINT_URL": proxy.url, "AWS_ENDPOINT_URL_S3": proxy.url}
"""

from __future__ import annotations

import re
import socket
import threading
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import unquote, urlsplit

__all__ = ["FaultProxy", "Rule", "ERRORS"]

#: the S3 error codes a rule may answer with, and their messages
ERRORS = {"SlowDown": "Please reduce your request rate.",
          "InternalError": "We encountered an internal error. Please try again.",
          "ServiceUnavailable": "Please reduce your request rate.",
          "AccessDenied": "Access Denied."}
BLOCK = 1 << 16


@dataclass
class Rule:
    """Answer the *first*..*last* (1-based, inclusive; *last* None: every one from *first*) requests whose
    method is *method* (None: any), whose unquoted path matches *path* and whose query matches *query*
    (``re.search``), with *status* and the S3 error *code*."""

    method: str | None = None
    path: str = ""
    query: str = ""
    first: int = 1
    last: int | None = None
    status: int = 503
    code: str = "SlowDown"
    seen: int = 0
    injected: int = 0

    def applies(self, method: str, path: str, query: str) -> bool:
        if self.method not in (None, method) or not re.search(self.path, path) or not re.search(self.query, query):
            return False
        self.seen += 1
        return self.first <= self.seen and (self.last is None or self.seen <= self.last)


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"  # keep-alive; "Expect: 100-continue" answered here, dropped upstream
    server: "_Server"

    def log_message(self, *args) -> None:  # quiet
        pass

    def setup(self) -> None:
        super().setup()
        self.upstream = None
        with self.server.lock:
            self.server.clients.add(self.connection)

    def finish(self) -> None:
        with self.server.lock:
            self.server.clients.discard(self.connection)
        if self.upstream is not None:
            self.upstream.close()
        super().finish()

    def handle_one_request(self) -> None:
        try:
            self.raw_requestline = self.rfile.readline(65537)
            if not self.raw_requestline:
                self.close_connection = True
                return
            if not self.parse_request():
                return
            self._relay()
        except OSError:  # the client or the upstream went away (a time-out, the proxy closing)
            self.close_connection = True
            if self.upstream is not None:
                self.upstream.close()
                self.upstream = None

    def _relay(self) -> None:
        split = urlsplit(self.path)
        path = unquote(split.path)
        rule = self.server.proxy.match(self.command, path, split.query)
        if rule is not None:
            self._body(None)  # read and dropped: the connection stays usable
            return self._error(rule, path)
        if self.upstream is None:
            self.upstream = socket.create_connection(self.server.proxy.upstream, timeout=120)
            self.up_in = self.upstream.makefile("rb")
        head = [self.requestline] + [f"{k}: {v}" for k, v in self.headers.items() if k.lower() != "expect"]
        self.upstream.sendall(("\r\n".join(head) + "\r\n\r\n").encode("latin-1"))
        self._body(self.upstream)
        while True:  # the answer's head; 1xx heads are skipped
            status_line = self.up_in.readline(65537)
            if not status_line:  # the upstream closed the kept connection: the client's to send again
                raise ConnectionError("the upstream closed the connection")
            lines = [status_line]
            while lines[-1] not in (b"\r\n", b"\n", b""):
                lines.append(self.up_in.readline(65537))
            status = int(status_line.split()[1])
            if status >= 200:
                break
        self.wfile.write(b"".join(lines))
        headers = {ln.split(b":", 1)[0].strip().lower(): ln.split(b":", 1)[1].strip()
                   for ln in lines[1:-1] if b":" in ln}
        if self.command == "HEAD" or status in (204, 304):
            pass
        elif b"chunked" in headers.get(b"transfer-encoding", b"").lower():
            _copy_chunked(self.up_in, self.wfile)
        elif b"content-length" in headers:
            _copy(self.up_in, self.wfile, int(headers[b"content-length"]))
        else:  # to the end of the upstream's connection
            while block := self.up_in.read1(BLOCK):
                self.wfile.write(block)
            self.close_connection = True
        self.wfile.flush()
        if headers.get(b"connection", b"").lower() == b"close":
            self.close_connection = True
            self.upstream.close()
            self.upstream = None
        self.server.proxy.count(self.command, self.path, status, injected=False)

    def _body(self, out) -> None:
        """Copy (to the socket *out*) or drop (None) the request's body."""
        sink = out.makefile("wb") if out is not None else None
        if "chunked" in self.headers.get("Transfer-Encoding", "").lower():
            _copy_chunked(self.rfile, sink)
        else:
            _copy(self.rfile, sink, int(self.headers.get("Content-Length") or 0))
        if sink is not None:
            sink.flush()

    def _error(self, rule: Rule, path: str) -> None:
        body = (f'<?xml version="1.0" encoding="UTF-8"?>\n<Error><Code>{rule.code}</Code><Message>'
                f"{ERRORS.get(rule.code, rule.code)}</Message><Resource>{path}</Resource>"
                f"<RequestId>faultproxy</RequestId></Error>").encode()
        self.send_response(rule.status)
        self.send_header("Content-Type", "application/xml")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("x-amz-request-id", "faultproxy")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)
        self.wfile.flush()
        self.server.proxy.count(self.command, self.path, rule.status, injected=True)


def _copy(src, dst, n: int) -> None:
    while n > 0:
        block = src.read(min(n, BLOCK))
        if not block:
            raise ConnectionError("the body ended early")
        if dst is not None:
            dst.write(block)
        n -= len(block)


def _copy_chunked(src, dst) -> None:
    """Copy a chunked body as it is framed: each chunk's size line and data, then the trailers."""
    while True:
        line = src.readline(65537)
        if dst is not None:
            dst.write(line)
        size = int(line.split(b";", 1)[0].strip() or b"0", 16)
        if size == 0:
            break
        _copy(src, dst, size + 2)  # the data and its CRLF
    while True:  # trailers, to the empty line
        line = src.readline(65537)
        if dst is not None:
            dst.write(line)
        if line in (b"\r\n", b"\n", b""):
            return


class _Server(ThreadingHTTPServer):
    daemon_threads = False  # server_close() joins every connection's thread
    block_on_close = True


class FaultProxy:
    """The proxy, serving from construction until :meth:`close` (a context manager)."""

    def __init__(self, upstream_url: str, rules: list[Rule] | None = None) -> None:
        split = urlsplit(upstream_url)
        self.upstream = (split.hostname, split.port or 80)
        self.rules = list(rules or [])
        self.forwarded = 0
        self.injected = 0
        self.log: list[tuple[str, str, int]] = []
        self._lock = threading.Lock()
        self._server = _Server(("127.0.0.1", 0), _Handler)
        self._server.proxy, self._server.lock, self._server.clients = self, threading.Lock(), set()
        self.url = f"http://127.0.0.1:{self._server.server_address[1]}"
        self._thread = threading.Thread(target=self._server.serve_forever, name="faultproxy", daemon=True)
        self._thread.start()

    def match(self, method: str, path: str, query: str) -> Rule | None:
        """The first rule that answers this request (each matching rule counts it), or None."""
        with self._lock:
            hits = [r for r in self.rules if r.applies(method, path, query)]
            if hits:
                hits[0].injected += 1
        return hits[0] if hits else None

    def count(self, method: str, path: str, status: int, injected: bool) -> None:
        with self._lock:
            self.log.append((method, path, status))
            if injected:
                self.injected += 1
            else:
                self.forwarded += 1

    def close(self) -> None:
        """Stop serving, end every open connection, and join every thread."""
        self._server.shutdown()
        with self._server.lock:
            for conn in list(self._server.clients):
                try:
                    conn.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
        self._server.server_close()
        self._thread.join()

    def __enter__(self) -> "FaultProxy":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
