"""Reaching a dask.distributed scheduler by address, with a short timeout.

dask's connect waits 30 s for a missing scheduler, then raises a raw ``OSError``:
:func:`check_scheduler` tries a plain socket first, :func:`connect` maps dask's errors.
"""

from __future__ import annotations

import socket
from typing import Any
from .address import host_port
from .errors import SchedulerUnreachableError

__all__ = ["CONNECT_TIMEOUT", "host_port", "check_scheduler", "connect"]

#: seconds to wait for a scheduler's address to accept a connection
CONNECT_TIMEOUT = 5.0


def _reason(exc: BaseException) -> str:
    if isinstance(exc, (socket.timeout, TimeoutError)):
        return "no answer"
    return getattr(exc, "strerror", None) or str(exc) or type(exc).__name__


def check_scheduler(address: str, timeout: float = CONNECT_TIMEOUT) -> None:
    """Raise unless something accepts connections at the scheduler *address* within *timeout* seconds.
    *address* is ``tcp://host:port`` (also ``tls://``, ``ws://``, ``wss://``). Raises InvalidParameterError (no
    host or port) or SchedulerUnreachableError (refused, unknown host, timed out)."""
    where = host_port(address)
    if where is None:
        return
    try:
        with socket.create_connection(where, timeout=timeout):
            pass
    except OSError as exc:
        raise SchedulerUnreachableError(
            f"cannot reach the dask scheduler at {address}: {_reason(exc)} (connect timeout {timeout:g} s)"
        ) from None


def connect(address: str, timeout: float | None = None) -> Any:
    """A :class:`distributed.Client` of the scheduler at *address* (*timeout* default: dask's).
    Raises SchedulerUnreachableError when dask cannot connect (e.g. not a dask scheduler)."""
    from distributed import Client

    try:
        return Client(address) if timeout is None else Client(address, timeout=timeout)
    except (OSError, TimeoutError) as exc:
        raise SchedulerUnreachableError(f"cannot connect to the dask scheduler at {address}: {_reason(exc)}") from exc
