"""The object store's error answers, against a real S3 server (SeaweedFS, tests/s3server.py) behind a proxy that
answers some requests itself (tests/faultproxy.py): 503 SlowDown and 500 InternalError now and then are retried,
counted in the summary, and give the bytes of a run with no fault; an answer that keeps failing (503, 500) or
refuses (403) ends the run with one line naming the URL and the problem, exit 2, no secret, nothing under the
final name, no scratch left beside it, the input untouched."""

from __future__ import annotations

import hashlib
import json
import os
import random
import subprocess
import sys
import threading

import pytest

from conftest import shared_file
from faultproxy import FaultProxy, Rule

#: two attempts a request (4 by default): a request that keeps failing fails sooner
FEW_ATTEMPTS = {"config_kwargs": {"retries": {"total_max_attempts": 2, "mode": "standard"}}}
SLOW_DOWN = "503 SlowDown (Please reduce your request rate.)"
INTERNAL = "500 InternalError (We encountered an internal error. Please try again.)"


@pytest.fixture
def cloud(bucket, s3):
    """autzen_trim.laz (110,000 points) as the object bucket/in/a.laz."""
    s3.filesystem().put_file(str(shared_file("autzen_trim.laz")), f"{bucket[5:]}/in/a.laz")
    return f"{bucket}/in/a.laz"


@pytest.fixture
def proxy(s3):
    """``proxy(*rules)``: a FaultProxy before the session's server; every one made is closed after the test,
    and leaves no thread behind."""
    made: list[FaultProxy] = []

    def make(*rules: Rule) -> FaultProxy:
        made.append(FaultProxy(s3.endpoint_url, list(rules)))
        return made[-1]

    yield make
    for p in made:
        p.close()
    assert not [t.name for t in threading.enumerate() if t.name == "faultproxy" or "process_request" in t.name]


def _simplify(s3, through: FaultProxy, *args: str, options: dict | None = None) -> subprocess.CompletedProcess:
    """``cloudsieve simplify ARGS --ratio 0.5``, the AWS_* chain pointing at the proxy."""
    env = {**os.environ, **s3.env(), "AWS_ENDPOINT_URL": through.url, "AWS_ENDPOINT_URL_S3": through.url}
    extra = ["--storage-options", json.dumps(options)] if options else []
    return subprocess.run([sys.executable, "-m", "cloudsieve", "simplify", *args, "--ratio", "0.5", *extra],
                          capture_output=True, text=True, env=env, timeout=300)


def _sha(s3, url: str) -> str:
    return hashlib.sha256(s3.filesystem().cat_file(url.split("://", 1)[1])).hexdigest()


def _under(s3, prefix: str) -> list[str]:
    """The objects under the URL *prefix*, as names relative to it (a folder marker SeaweedFS keeps once its
    objects are gone is none)."""
    key = prefix.split("://", 1)[1]
    return sorted(k[len(key) + 1:] for k in s3.filesystem().find(key) if k.rstrip("/") != key)


def _failed(proc: subprocess.CompletedProcess, s3) -> str:
    """The one error line of a run that failed as it should (exit 2, no traceback, no key of the test's)."""
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    for secret in (s3.admin.key, s3.admin.secret):
        assert secret not in proc.stderr + proc.stdout
    errors = [line for line in proc.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1, proc.stderr
    return errors[0]


def test_503s_and_500s_now_and_then_are_retried_counted_and_give_the_bytes_of_a_run_without_fault(
        cloud, bucket, s3, proxy):
    """All on S3 (input, work store, parts, output), two worker processes: 503 SlowDown on GETs of the input and
    on PUTs of the work store, 500 InternalError on a part's PUT and on the output's: the run succeeds, its
    summary counts at least the faults, its file is the one of a run through the proxy with no fault (its
    work store local, in one process), and no part is left."""
    clean = proxy()
    base = _simplify(s3, clean, cloud, f"{bucket}/out/whole.laz", "--chunk-size", "20000")
    assert base.returncode == 0, base.stderr
    assert clean.injected == 0 and clean.forwarded > 0
    rules = [Rule("GET", r"/in/a\.laz$", first=2, last=3),
             Rule("PUT", r"/w1\.zarr/xyz/c/", first=1, last=2),
             Rule("PUT", r"/out/\.o\.laz\.parts-[0-9a-f]{12}/part-\d+\.laz$", first=1, last=1, status=500,
                  code="InternalError"),
             Rule("PUT", r"/out/o\.laz$", first=1, last=1, status=500, code="InternalError")]
    faulty = proxy(*rules)
    run = _simplify(s3, faulty, cloud, f"{bucket}/out/o.laz", "--chunk-size", "20000", "--workers", "2",
                    "--store", f"{bucket}/w1.zarr", "--json")
    assert run.returncode == 0, run.stderr
    assert [r.injected for r in rules] == [2, 2, 1, 1]
    assert faulty.injected == 6
    assert json.loads(run.stdout)["storage"]["retries"] >= faulty.injected
    assert _sha(s3, f"{bucket}/out/o.laz") == _sha(s3, f"{bucket}/out/whole.laz")
    assert _under(s3, f"{bucket}/out") == ["o.laz", "whole.laz"]


def test_a_multipart_upload_s_failed_part_and_completion_are_retried(bucket, s3, proxy):
    """An output of more than one write block (cloudsieve.storage.open_output, as the one-LAZ and COPC writers
    use it) is a multipart upload: a 500 on its second part's PUT and on its completion are sent again; the
    object is the bytes written, and the retries are counted."""
    from cloudsieve import storage, storage_retries

    rules = [Rule("PUT", r"/big\.bin$", query=r"partNumber=2", first=1, last=1, status=500, code="InternalError"),
             Rule("POST", r"/big\.bin$", query=r"uploadId=", first=1, last=1, status=500, code="InternalError")]
    faulty = proxy(*rules)
    data = random.Random(7).randbytes(storage.WRITE_BLOCK + 2**20)
    with storage.using({**s3.storage_options(), "endpoint_url": faulty.url}):
        before = storage_retries.counts()[1]
        fh = storage.open_output(f"{bucket}/big.bin")
        for start in range(0, len(data), 2**20):  # as a writer writes: a part goes when a block is full
            fh.write(data[start:start + 2**20])
        fh.close()
        retried = storage_retries.counts()[1] - before
    assert [r.seen for r in rules] == [2, 2] and faulty.injected == 2
    assert [m for m, path, _ in faulty.log if "partNumber=" in path].count("PUT") == 3  # two parts, one again
    assert retried >= 2
    assert hashlib.sha256(s3.filesystem().cat_file(f"{bucket[5:]}/big.bin")).hexdigest() == \
        hashlib.sha256(data).hexdigest()


def test_a_write_answered_503_every_time_fails_with_one_line_and_leaves_nothing(cloud, bucket, s3, proxy):
    """Every PUT of the output answered 503 SlowDown: the run's parts are written, the output's upload is sent
    again and again, then the run stops: exit 2, the URL and the answer named, nothing under out/ (neither the
    file nor its parts nor a write probe). The same with every request to the key answered 503."""
    rule = Rule("PUT", r"/out/o\.laz$")
    faulty = proxy(rule)
    dst = f"{bucket}/out/o.laz"
    proc = _simplify(s3, faulty, cloud, dst, "--store", f"{bucket}/w.zarr", options=FEW_ATTEMPTS)
    line = _failed(proc, s3)
    assert line == (f"cloudsieve simplify: error: {dst}: the object store answered {SLOW_DOWN} to every attempt: "
                    "retries exhausted")
    assert rule.injected >= 2  # sent again before giving up
    assert any(".o.laz.parts-" in path for _, path, _ in faulty.log)  # there were parts to clean
    assert _under(s3, f"{bucket}/out") == []
    # every request to the key, the destination's check (a HEAD: an answer with no body) first
    proc = _simplify(s3, proxy(Rule(None, r"/out/o\.laz$")), cloud, dst, options=FEW_ATTEMPTS)
    assert _failed(proc, s3) == (f"cloudsieve simplify: error: {dst}: the object store answered 503 (Service "
                                 "Unavailable) to every attempt: retries exhausted")
    assert _under(s3, f"{bucket}/out") == []


def test_reads_of_the_input_or_the_work_store_answered_5xx_every_time_fail_with_one_line(cloud, bucket, s3, proxy):
    """Every GET of the input answered 500 (its header is read, then its chunks): the input's URL named; every
    PUT of one work-store chunk answered 503: the store's URL named. Exit 2, nothing under out/."""
    faulty = proxy(Rule("GET", r"/in/a\.laz$", status=500, code="InternalError"))
    proc = _simplify(s3, faulty, cloud, f"{bucket}/out/o.laz", options=FEW_ATTEMPTS)
    assert _failed(proc, s3) == (f"cloudsieve simplify: error: {cloud}: the object store answered {INTERNAL} to "
                                 "every attempt: retries exhausted")
    faulty = proxy(Rule("PUT", r"/w\.zarr/xyz/c/0/0$"))
    proc = _simplify(s3, faulty, cloud, f"{bucket}/out/o.laz", "--store", f"{bucket}/w.zarr", options=FEW_ATTEMPTS)
    assert _failed(proc, s3) == (f"cloudsieve simplify: error: {bucket}/w.zarr: the object store answered "
                                 f"{SLOW_DOWN} to every attempt: retries exhausted")
    assert _under(s3, f"{bucket}/out") == []


def test_a_write_refused_with_403_fails_with_one_line_and_leaves_the_input_as_it_was(cloud, bucket, s3, proxy):
    """The write probe passes, the output's PUT is refused (AccessDenied): exit 2, the URL and "access denied"
    named, sent once (a refusal is not retried), nothing under out/, the input's bytes and ETag unchanged."""
    before = s3.filesystem().info(cloud[5:])["ETag"], _sha(s3, cloud)
    rule = Rule("PUT", r"/out/o\.laz$", status=403, code="AccessDenied")
    faulty = proxy(rule)
    dst = f"{bucket}/out/o.laz"
    proc = _simplify(s3, faulty, cloud, dst)
    assert _failed(proc, s3) == (f"cloudsieve simplify: error: {dst}: access denied: cannot write it with these "
                                 "credentials (Access Denied.)")
    assert rule.injected == 1
    assert _under(s3, f"{bucket}/out") == []
    assert (s3.filesystem().info(cloud[5:])["ETag"], _sha(s3, cloud)) == before
