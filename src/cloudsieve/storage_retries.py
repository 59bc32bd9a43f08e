"""The object store's retries, counted in each process: what a run's summary reports as ``storage.retries``.

A leaf. S3 requests go through botocore, whose standard retry mode (set in :mod:`cloudsieve.storage`: 4
attempts, a bounded exponential backoff) sends a request again after a timeout, throttling or a 5xx answer.
Each such attempt after the first is counted here: a handler of botocore's ``request-created`` event for
S3, which sees the attempt's number in the request's retry context. It is added to botocore's built-in
handlers (:data:`botocore.handlers.BUILTIN_HANDLERS`) the first time this process makes a remote filesystem
(:func:`watch`, called by :func:`cloudsieve.storage.fs_options` and :func:`cloudsieve.storage.filesystem`),
so every client made after that counts: those of s3fs's synchronous filesystems, those zarr makes for a
remote work store in its own event loop, and those s3fs makes anew when it renews its connection.

:func:`counts` is this process's tally; the task runner sums the workers' (:mod:`cloudsieve.engine.runner`)
and the run's summary adds the driver's (:mod:`cloudsieve.engine.summary`). s3fs retries a call that still
fails after botocore's attempts (up to 5 calls, its own backoff): each of those calls is counted by its own
attempts after the first.
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
