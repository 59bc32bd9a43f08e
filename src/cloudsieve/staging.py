"""Temporary places of outputs on object stores: a report folder written locally then uploaded
(:func:`staged_folder`), and what an interrupted write left beside a URL destination
(:func:`remove_stale_scratch`). Built on :mod:`cloudsieve.storage`."""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator

from .storage import filesystem, is_url, name, parent, protocol, remote_errors, remove, upload

__all__ = ["staged_folder", "remove_stale_scratch"]


@contextlib.contextmanager
def staged_folder(folder: str) -> Iterator[str]:
    """A folder to write a report into: *folder* when local; for a URL, a local temporary folder uploaded
    under *folder* when the block ends without error, and removed either way."""
    import shutil
    import tempfile

    if not is_url(folder):
        yield folder
        return
    tmp = tempfile.mkdtemp(prefix=".cloudsieve-report-")
    try:
        yield tmp
        base = folder.rstrip("/")
        for root, _, names in os.walk(tmp):
            for n in names:
                full = os.path.join(root, n)
                if n.endswith((".json", ".md", ".html")):
                    with open(full, encoding="utf-8") as fh:
                        text = fh.read()
                    with open(full, "w", encoding="utf-8") as fh:
                        fh.write(text.replace(tmp, base))
                upload(full, base + "/" + os.path.relpath(full, tmp).replace(os.sep, "/"))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def remove_stale_scratch(dst: str, sources: list[str]) -> None:
    """Remove what an interrupted write to the URL *dst* left beside it (``.<name>.parts-<id>``,
    ``.<name>.scratch-<id>`` prefixes, write probes: cloudsieve's own names, ``<id>`` 12 hex digits); never
    one that is or holds one of *sources*. A local *dst* has none."""
    from .paths import holds

    if not is_url(dst):
        return
    base = f"{parent(dst)}/.{_glob_escape(name(dst))}"
    for kind in ("parts", "scratch", "cloudsieve-probe"):
        fs, p = filesystem(f"{base}.{kind}-{'[0-9a-f]' * 12}")
        with remote_errors(dst):
            found = fs.glob(p)
        for key in found:
            url = f"{protocol(dst)}://{key}"
            if not any(holds(url, s) for s in sources):
                remove(url, recursive=True)


def _glob_escape(text: str) -> str:
    """*text* with the glob's special characters taken literally."""
    return re.sub(r"([*?\[\]])", r"[\1]", text)
