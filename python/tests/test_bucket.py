"""The fleet job against a bucket: recordings read from, and the dataset
written to, an S3-compatible server (``moto_server``, a process of its
own) by a scheduler and two workers started from the command line; every
good recording's blocks those of ``cms-host analyze --json``, a bad file
carried in ``runs`` with the command line's error, the swap into place
published by the manifest."""

import os
import signal
import subprocess
import sys
import time

import pytest
from conftest import bucket
from test_fleet import BLOCK_M, blocks_of, cli, cli_json, pick

from cms.fleet import job, queries, store, synth

CMS_HOST = os.environ["CMS_HOST"]
#: 3 lines × 2 tracks × 2 years.
COUNT = 12


@pytest.fixture(scope="module")
def fleet_in_bucket(s3, tmp_path_factory):
    """The fleet's recordings (and one bad file) written here, then put in
    the bucket ``fleet`` under ``in/``: their local paths by URL."""
    d = tmp_path_factory.mktemp("bucket-fleet")
    paths = synth.write_fleet(str(d / "in"), COUNT, 150, 120, CMS_HOST)
    bad = d / "in" / "bad.cmsrec"
    bad.write_bytes(b"CMSREC\x00\x01garbage")
    fs = bucket("fleet")
    fs.put(str(d / "in") + "/", "fleet/in/", recursive=True)
    local = {f"s3://fleet/in/{os.path.basename(p)}": p for p in [*paths, str(bad)]}
    fs.invalidate_cache()
    assert sorted(fs.unstrip_protocol(p) for p in fs.find("fleet/in")) == sorted(local)
    return fs, local


def test_the_job_reads_and_writes_a_bucket_on_a_command_line_cluster(fleet_in_bucket, cluster):
    fs, local = fleet_in_bucket
    out = "s3://fleet/datasets/all"
    assert job.main(["s3://fleet/in", out, "--scheduler", cluster, "--block-m", str(BLOCK_M)]) == 1
    manifest = store.read_manifest(out)
    assert manifest["recordings"] == COUNT + 1 and manifest["failed"] == 1 and manifest["workers"] == 2
    # The data is under the run's own prefix, each file the manifest names there.
    version = manifest["data"]
    assert version.startswith("v-")
    fs.invalidate_cache()
    stored = {p for p in fs.find(f"fleet/datasets/all/{version}")}
    named = {f"fleet/datasets/all/{version}/{rel}" for files in manifest["files"].values() for rel, _ in files}
    assert named == stored and named
    blocks = store.open_table(out, "blocks").to_table().to_pylist()
    runs = store.open_table(out, "runs").to_table().to_pylist()
    assert sum(n for _, n in manifest["files"]["blocks"]) == len(blocks) == manifest["rows"]["blocks"]
    assert sorted(r["source"] for r in runs) == sorted(local)
    by: dict = {}
    for r in blocks:
        by.setdefault(r["source"], []).append(r)
    for url, path in local.items():
        [run] = [r for r in runs if r["source"] == url]
        if path.endswith("bad.cmsrec"):
            r = cli("analyze", path)
            assert r.returncode == 2 and r.stderr.strip() == "error: " + run["error"].replace(url, path)
            assert url not in by
            continue
        v = cli_json(path)
        want = blocks_of(v)
        got = sorted(by[url], key=lambda b: b["start_chainage_mm"])
        assert pick(got, want[0].keys()) == want, url
        sv = v["survey"]
        assert run["error"] is None and run["reprofile_mm"] == v["verdict"]["reprofile_mm"]
        for b in got + [run]:
            assert (b["line"], b["track"], str(b["year"])) == (sv["line"], sv["track"], sv["date"][:4]), url
    # The queries read the bucket through the manifest too.
    res = queries.run(out)
    (cols, rows) = res["reprofiling length per line (EN 13231-3 verdict of each run, summed)"]
    assert sum(r[cols.index("runs")] for r in rows) == COUNT


def test_a_bucket_dataset_is_replaced_by_its_manifest(fleet_in_bucket, cluster):
    fs, local = fleet_in_bucket
    good = sorted(u for u in local if not u.endswith("bad.cmsrec"))[:3]
    out = "s3://fleet/datasets/grown"
    firsts = []
    for n in (2, 3):
        for u in good[:n]:
            fs.copy(store._fs(u)[1], "fleet/grown/" + os.path.basename(u))
        assert job.main(["s3://fleet/grown", out, "--scheduler", cluster, "--block-m", str(BLOCK_M)]) == 0
        m = store.read_manifest(out)
        assert m["recordings"] == n and m["data"] not in firsts
        firsts.append(m["data"])
    runs = store.open_table(out, "runs").to_table()
    assert sorted(runs["source"].to_pylist()) == [f"s3://fleet/grown/{os.path.basename(u)}" for u in good]
    # The replaced run's files are gone: the bucket holds the manifest and the new run's prefix.
    fs.invalidate_cache()
    assert sorted(fs.ls("fleet/datasets/grown")) == [f"fleet/datasets/grown/{store.MANIFEST}", f"fleet/datasets/grown/{m['data']}"]


def test_a_bucket_prefix_not_the_jobs_is_refused(fleet_in_bucket, cluster):
    fs, _ = fleet_in_bucket
    fs.pipe("fleet/mine/keep.txt", b"mine")
    assert job.main(["s3://fleet/in", "s3://fleet/mine", "--scheduler", cluster]) == 2
    fs.invalidate_cache()
    assert fs.ls("fleet/mine") == ["fleet/mine/keep.txt"] and fs.cat("fleet/mine/keep.txt") == b"mine"
    with pytest.raises(store.NotADataset):
        store.read_manifest("s3://fleet/mine")


def _job_process(src: str, out: str) -> subprocess.Popen:
    """The job as a command, in a process group of its own (the client and
    its LocalCluster's worker): its stderr piped."""
    return subprocess.Popen(
        [sys.executable, "-m", "cms.fleet.job", src, out, "--workers", "1", "--block-m", str(BLOCK_M)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def _staged(fs, out_path: str) -> dict:
    """The objects under OUTPUT's staging prefixes, by prefix (the lease
    among them)."""
    fs.invalidate_cache()
    if not fs.exists(out_path):
        return {}
    found: dict = {}
    for p in fs.find(out_path):
        rel = p[len(out_path) + 1 :]
        top = rel.split("/", 1)[0]
        if store.STAGING.match(top):
            found.setdefault(top, []).append(rel)
    return found


def _until_data_staged(fs, out_path: str, proc: subprocess.Popen) -> str:
    """Waits until the job has staged a data file (not only its lease);
    its staging prefix. Fails if the job ends or publishes first."""
    deadline = time.monotonic() + 120
    while True:
        for prefix, objects in _staged(fs, out_path).items():
            if any(o.endswith(".parquet") for o in objects):
                assert not fs.exists(f"{out_path}/{store.MANIFEST}"), "the job published before it could be stopped"
                return prefix
        assert proc.poll() is None, f"the job ended before staging anything: {proc.stderr.read()}"
        assert time.monotonic() < deadline, "no staged data within 120 s"
        time.sleep(0.02)


def _whole(fs, out: str, out_path: str, sources: list) -> None:
    """The dataset at ``out`` holds every recording of ``sources`` and the
    bucket holds its manifest and its data prefix only, every file there
    named by the manifest."""
    m = store.read_manifest(out)
    runs = store.open_table(out, "runs").to_table()
    assert sorted(runs["source"].to_pylist()) == sorted(sources) and m["failed"] == 0
    fs.invalidate_cache()
    assert sorted(fs.ls(out_path)) == [f"{out_path}/{store.MANIFEST}", f"{out_path}/{m['data']}"]
    stored = set(fs.find(f"{out_path}/{m['data']}"))
    named = {f"{out_path}/{m['data']}/{rel}" for files in m["files"].values() for rel, _ in files}
    assert stored == named and named


@pytest.fixture(scope="module")
def four(fleet_in_bucket):
    """Four good recordings of the fleet under a prefix of their own: its
    URL and theirs."""
    fs, local = fleet_in_bucket
    good = sorted(u for u in local if not u.endswith("bad.cmsrec"))[:4]
    for u in good:
        fs.copy(store._fs(u)[1], "fleet/four/" + os.path.basename(u))
    return "s3://fleet/four", [f"s3://fleet/four/{os.path.basename(u)}" for u in good]


def test_a_killed_jobs_staging_is_removed_by_the_next_run(fleet_in_bucket, four, cluster, capsys):
    fs, _ = fleet_in_bucket
    src, sources = four
    out, out_path = "s3://fleet/datasets/killed", "fleet/datasets/killed"
    p = _job_process(src, out)
    prefix = _until_data_staged(fs, out_path, p)
    # The client and its cluster killed outright, mid-run.
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    left = _staged(fs, out_path)[prefix]
    assert store.LEASE in [o.split("/", 1)[1] for o in left] and len(left) >= 2
    # The next run on the same output removes it, and says so.
    assert job.main([src, out, "--scheduler", cluster, "--block-m", str(BLOCK_M)]) == 0
    err = capsys.readouterr().err
    line = f"note: removed s3://{out_path}/{prefix}/, {len(left)} objects staged by a run that did not finish: its client, pid {p.pid} on "
    assert line in err and err.count("note: removed") == 1, err
    _whole(fs, out, out_path, sources)


def test_a_running_jobs_staging_is_left_to_it(fleet_in_bucket, four, cluster, capsys):
    fs, _ = fleet_in_bucket
    src, sources = four
    out, out_path = "s3://fleet/datasets/shared", "fleet/datasets/shared"
    p = _job_process(src, out)
    prefix = _until_data_staged(fs, out_path, p)
    # Paused (the client and its cluster): alive, its lease young.
    os.killpg(p.pid, signal.SIGSTOP)
    try:
        staged = sorted(_staged(fs, out_path)[prefix])
        assert job.main([src, out, "--scheduler", cluster, "--block-m", str(BLOCK_M)]) == 0
        err = capsys.readouterr().err
        assert f"note: s3://{out_path}/{prefix}/: {len(staged)} objects of another run left in place: its client, pid {p.pid} on " in err, err
        assert "is running" in err and "note: removed" not in err, err
        assert sorted(_staged(fs, out_path)[prefix]) == staged
        first = store.read_manifest(out)["data"]
    finally:
        os.killpg(p.pid, signal.SIGCONT)
    # Resumed, it publishes in turn (the last to publish wins) and removes the one it replaced.
    _, err = p.communicate(timeout=300)
    assert p.returncode == 0, err
    m = store.read_manifest(out)
    assert m["data"] == prefix and m["data"] != first
    _whole(fs, out, out_path, sources)


def test_staging_is_judged_by_its_lease(tmp_path):
    import datetime

    t0 = datetime.datetime(2026, 1, 1, tzinfo=datetime.timezone.utc)
    later = lambda s: t0 + datetime.timedelta(seconds=s)  # noqa: E731
    here = store.identity()
    assert here is not None and here["pid"] == os.getpid()
    # A process of this machine: running, or gone (started, then reaped).
    me = {"host": "here", "pid": os.getpid(), "identity": here}
    assert store.judge(me, t0, later(10_000), here) == (False, f"its client, pid {os.getpid()} on here, is running")
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    gone_pid = int(done.stdout)
    gone = {"host": "here", "pid": gone_pid, "identity": {**here, "pid": gone_pid}}
    assert store.judge(gone, t0, later(1), here) == (True, f"its client, pid {gone_pid} on here, is gone")
    # The same pid reused by another process: another start time.
    reused = {"host": "here", "pid": os.getpid(), "identity": {**here, "start": here["start"] + 1}}
    assert store.judge(reused, t0, later(1), here)[0]
    # Another machine (or pid namespace): the lease's age, by the store's clock.
    there = {"host": "there", "pid": 7, "identity": {**here, "boot_id": "another"}}
    assert store.judge(there, t0, later(599), here, 600) == (
        False,
        "its client, pid 7 on there, renewed its lease 599 s ago (removed once not renewed for 600 s)",
    )
    assert store.judge(there, t0, later(601), here, 600)[0]
    assert store.judge({"host": "there", "pid": 7, "identity": None}, t0, later(601), here, 600)[0]
    # No lease: its newest object's age.
    assert not store.judge(None, t0, later(599), here, 600)[0] and store.judge(None, t0, later(601), here, 600)[0]
