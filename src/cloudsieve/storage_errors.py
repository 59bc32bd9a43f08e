"""An object store's errors as cloudsieve's own: one line naming the URL (and the endpoint when it cannot be
reached), with no credential in it. A leaf (no other cloudsieve module but :mod:`cloudsieve.errors`);
:func:`cloudsieve.storage.remote_errors` hands it the run's endpoint and secrets."""

from __future__ import annotations

import contextlib
import re
from collections.abc import Iterator

from .errors import (CloudsieveError, DestinationNotWritableError, InputNotFoundError, InputNotReadableError,
                     InvalidParameterError)

__all__ = ["redact", "mapped"]

_SECRET = re.compile(r"(?i)(secret|token|password|key|signature|credential)[\"']?\s*[:=]\s*[\"']?[^\s\"',}&]+")


def redact(text: str, secrets: list[str] = ()) -> str:
    """*text* with anything that looks like a credential (``secret=...``, ``"key": "..."``) and each of
    *secrets* masked."""
    text = _SECRET.sub(lambda m: m.group(1) + "=***", text)
    for value in secrets:
        text = text.replace(value, "***")
    return text


def _reason(exc: BaseException, secrets: list[str]) -> str:
    text = str(exc).strip() or type(exc).__name__
    return redact(text.splitlines()[0], secrets)


def _answer(exc: BaseException) -> tuple[int, str, str] | None:
    """``(HTTP status, S3 error code, its message)`` of the store's answer behind *exc* (s3fs keeps botocore's
    error as the cause), or None for an error that is no answer; a code or message the answer lacks is ""."""
    for err in (exc, exc.__cause__, exc.__context__):
        meta = getattr(err, "response", None)
        if isinstance(meta, dict) and "ResponseMetadata" in meta:
            status = meta["ResponseMetadata"].get("HTTPStatusCode")
            error = meta.get("Error", {})
            code, message = str(error.get("Code") or ""), str(error.get("Message") or "")
            return (int(status), "" if code == str(status) else code, message) if status else None
    return None


#: the exceptions' names (botocore, aiohttp, requests) that say the store cannot be reached
_UNREACHABLE = ("EndpointConnectionError", "ConnectTimeoutError", "ConnectionError", "ClientConnectorError",
                "ConnectTimeout", "ReadTimeoutError")


@contextlib.contextmanager
def mapped(path: str, remote: bool, writing: bool, endpoint: str | None, secrets: list[str]) -> Iterator[None]:
    """The block's errors about *path* (a URL when *remote*; a local path's pass as they are) as cloudsieve's."""
    try:
        yield
    except CloudsieveError:
        raise
    except Exception as exc:  # noqa: BLE001 - the object store's own exceptions (botocore, aiohttp, ...)
        if not remote:
            raise
        failed = DestinationNotWritableError if writing else InputNotReadableError
        if isinstance(exc, FileNotFoundError):
            what = "no such bucket" if "bucket" in str(exc).lower() else "no such file"
            raise InputNotFoundError(f"{path}: {what}") from None
        if isinstance(exc, PermissionError):
            raise failed(f"{path}: access denied: cannot {'write' if writing else 'read'} it with these "
                         f"credentials ({_reason(exc, secrets)})") from None
        kind = type(exc).__name__
        if kind in ("ParamValidationError", "InvalidBucketName") or "Invalid bucket name" in str(exc):
            raise InvalidParameterError(f"{path}: invalid bucket name (S3 bucket names are 3 to 63 lower-case "
                                        "letters, digits, dots and hyphens)") from None
        if kind in _UNREACHABLE or "Could not connect" in str(exc):
            raise failed(f"{path}: cannot reach the object store at {endpoint or 'the default endpoint'} "
                         f"({_reason(exc, secrets)})") from None
        answer = _answer(exc)
        if answer is not None and (answer[0] >= 500 or answer[0] == 429):  # retried by the client, in vain
            status, code, message = answer
            said = f"{status} {code}".strip() + (f" ({redact(message, secrets)})" if message else "")
            raise failed(f"{path}: the object store answered {said} to every attempt: retries exhausted") from None
        if isinstance(exc, (OSError, ValueError)):
            raise failed(f"{path}: {_reason(exc, secrets)}") from None
        raise
