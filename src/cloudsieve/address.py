"""A dask scheduler address parsed: :func:`host_port` (a leaf: read by :mod:`cloudsieve.params` and
:mod:`cloudsieve.scheduler`, which connects)."""

from __future__ import annotations

from urllib.parse import urlparse

from .errors import InvalidParameterError

__all__ = ["TCP_SCHEMES", "host_port"]

#: address schemes that run over TCP (a socket connect tells whether they answer)
TCP_SCHEMES = ("tcp", "tls", "ws", "wss")


def host_port(address: str) -> tuple[str, int] | None:
    """The (host, port) of a TCP scheduler *address*; None for a non-TCP scheme (left to dask).
    InvalidParameterError for a ``tcp://`` (``tls://``, ``ws://``, ``wss://``) address without host or port."""
    url = urlparse(address)
    if url.scheme not in TCP_SCHEMES:
        return None
    try:
        host, port = url.hostname, url.port
    except ValueError:
        host, port = None, None
    if not host or port is None:
        raise InvalidParameterError(f"scheduler address {address!r} needs a host and a port: tcp://host:port")
    return host, port
