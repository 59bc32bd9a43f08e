"""The object store's retries, counted in each process: what a run's summary reports as ``storage.retries``.

A leaf. botocore's standard retry mode (:mod:`cloudsieve.storage`) resends a request after a timeout,
throttling or a 5xx; a ``request-created`` handler for S3 counts each attempt after the first. It joins
botocore's built-in handlers at the process's first remote filesystem (:func:`watch`), so every client made
later counts (s3fs's, zarr's, renewed ones). :func:`counts` is this process's tally; the task runner sums
the workers' and the summary adds the driver's.
"""

from __future__ import annotations

import threading

__all__ = ["watch", "counts"]

_lock = threading.Lock()
_uses = 0  # remote filesystems asked for in this process (any protocol but file://)
_retries = 0  # S3 attempts after a request's first, in this process
_registered = False


def _on_request(request=None, **kwargs) -> None:
    """botocore's ``request-created.s3`` handler: count an attempt after the first."""
    global _retries
    retry = getattr(request, "context", None) or {}
    if retry.get("retries", {}).get("attempt", 1) > 1:
        with _lock:
            _retries += 1


def watch(protocol: str) -> None:
    """Note that this process uses a remote filesystem of *protocol*; for S3, count botocore's retries from
    now on (once per process)."""
    global _uses, _registered
    if protocol in ("file", "local"):
        return
    _uses += 1
    if _registered or protocol not in ("s3", "s3a"):
        return
    with _lock:
        if not _registered:
            from botocore import handlers

            handlers.BUILTIN_HANDLERS.append(("request-created.s3", _on_request))
            _registered = True


def counts() -> tuple[int, int]:
    """``(remote filesystems asked for, S3 retries)`` in this process so far."""
    return _uses, _retries
