"""The counterparts the fleet's tests run against, each a separate process
on this machine started from the command line: an S3-compatible server
(``moto_server``, with the credentials and endpoint in the environment of
the test and of the cluster's processes), and a Dask scheduler with two
workers (``cms.fleet.procs``)."""

import os
import re
import subprocess
import urllib.error
import urllib.request

import pytest

from cms.fleet import procs

S3_ENV = {"AWS_ACCESS_KEY_ID": "cms-fleet-test", "AWS_SECRET_ACCESS_KEY": "cms-fleet-test", "AWS_DEFAULT_REGION": "us-east-1"}


def _answers(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=2):
            return True
    except urllib.error.HTTPError:
        return True  # an HTTP answer, whatever its status: the server is up
    except OSError:
        return False


@pytest.fixture(scope="session")
def s3(tmp_path_factory):
    """``moto_server`` on a port the system picks; its endpoint, set in
    this process's environment (and so in the cluster's) with the
    credentials, for fsspec's ``s3://`` URLs."""
    d = tmp_path_factory.mktemp("s3")
    log = str(d / "moto.log")
    with open(log, "wb") as f:
        p = subprocess.Popen(
            [procs.console_script("moto_server"), "-H", "127.0.0.1", "-p", "0"], stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
        )
    try:
        port = []

        def listening() -> bool:
            with open(log, errors="replace") as f:
                m = re.search(r"Running on http://127\.0\.0\.1:(\d+)", f.read())
            if m:
                port[:] = [m.group(1)]
            return bool(m) and _answers(f"http://127.0.0.1:{port[0]}/")

        procs.wait_until(listening, "moto_server", p, log, 60)
        endpoint = f"http://127.0.0.1:{port[0]}"
        saved = {k: os.environ.get(k) for k in [*S3_ENV, "AWS_ENDPOINT_URL"]}
        os.environ.update(S3_ENV, AWS_ENDPOINT_URL=endpoint)
        yield endpoint
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    finally:
        p.terminate()
        p.wait(timeout=15)


@pytest.fixture(scope="session")
def cluster(s3, tmp_path_factory):
    """A scheduler and two workers, each a process started from the
    command line, reaching the S3 server; the scheduler's address."""
    with procs.DaskProcesses(str(tmp_path_factory.mktemp("dask")), workers=2) as c:
        yield c.address


def bucket(name: str):
    """A new bucket on the S3 server; its fsspec filesystem."""
    import fsspec

    fs = fsspec.filesystem("s3")
    fs.invalidate_cache()
    import boto3

    boto3.client("s3").create_bucket(Bucket=name)
    return fs
