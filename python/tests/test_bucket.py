"""The fleet job against a bucket: recordings read from, and the dataset
written to, an S3-compatible server (``moto_server``, a process of its
own) by a scheduler and two workers started from the command line; every
good recording's blocks those of ``cms-host analyze --json``, a bad file
carried in ``runs`` with the command line's error, the swap into place
published by the manifest."""

import os

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
