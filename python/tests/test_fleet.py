"""The Python side against the command line: the package's tables and the
fleet job's dataset give, for every recording, the figures of
``cms-host analyze --json`` of that recording; the queries run; errors
are the command line's. ``CMS_HOST`` names the release binary."""

import json
import math
import os
import subprocess

import duckdb
import pyarrow as pa
import pyarrow.dataset as ds
import pytest

import cms
from cms.fleet import job, queries, synth

CMS_HOST = os.environ["CMS_HOST"]
COUNT = int(os.environ.get("CMS_FLEET_COUNT", "100"))
BLOCK_M = 1.0
BANDS = ("10_30", "30_100", "100_300", "300_1000")


def cli(*args):
    r = subprocess.run([CMS_HOST, *args], capture_output=True, text=True)
    return r


def cli_json(path):
    r = cli("analyze", path, "--block-m", str(BLOCK_M), "--json")
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@pytest.fixture(scope="session")
def fleet(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    paths = synth.write_fleet(str(d / "in"), COUNT, 150, 120, CMS_HOST)
    assert len(paths) == COUNT
    return d, paths


@pytest.fixture(scope="session")
def dataset(fleet):
    d, _ = fleet
    out = str(d / "dataset")
    assert job.main([str(d / "in"), out, "--workers", "2", "--block-m", str(BLOCK_M)]) == 0
    return out


def blocks_of(v):
    """The CLI's blocks as the table's rows."""
    rows = []
    for b in v["verdict"]["blocks"]:
        e = b["iso3095_exceeded_mm"]
        row = {"start_chainage_mm": b["start_mm"], "end_chainage_mm": b["end_mm"]}
        for k, r in zip(BANDS, b["rms_mm"]):
            row[f"rms_um_{k}"] = None if r is None else r * 1000.0
        row["iso3095_pass"] = None if e is None else not e
        row["iso3095_exceeded_mm"] = None if e is None else [float(w) for w in e]
        rows.append(row)
    return rows


ZONE_KEYS = ("band_lo_mm", "band_hi_mm", "start_chainage_mm", "end_chainage_mm", "exceeding_mm", "worst_pp_mm")


def zones_of(v):
    return [
        {
            "band_lo_mm": z["lo_mm"],
            "band_hi_mm": z["hi_mm"],
            "start_chainage_mm": z["start_mm"],
            "end_chainage_mm": z["end_mm"],
            "exceeding_mm": z["exceeding_mm"],
            "worst_pp_mm": z["worst_pp_mm"],
        }
        for z in v["verdict"]["zones"]
    ]


def pick(rows, keys):
    return [{k: r[k] for k in keys} for r in rows]


def test_the_package_gives_the_figures_of_the_cli(fleet):
    _, paths = fleet
    zones = 0
    for p in paths[:5]:
        v = cli_json(p)
        a = cms.analyze(p, block_m=BLOCK_M)
        assert a.summary == v
        want = blocks_of(v)
        assert pick(a.blocks.to_pylist(), want[0].keys()) == want
        assert a.blocks["source"].to_pylist() == [p] * len(want)
        wz = zones_of(v)
        zones += len(wz)
        assert pick(a.zones.to_pylist(), ZONE_KEYS) == wz
        assert a.profile.num_rows > 1000 and a.profile["coverage"].null_count == 0
    assert zones > 0

def test_the_tables_equal_the_cli_parquet_exports(fleet, tmp_path):
    import pyarrow.parquet as pq

    _, paths = fleet
    p = paths[3]
    r = cli("analyze", p, "--block-m", str(BLOCK_M), "--parquet", str(tmp_path / "pq"))
    assert r.returncode == 0, r.stderr
    a = cms.analyze(p, block_m=BLOCK_M)
    for name, t in a.tables.items():
        f = pq.read_table(tmp_path / "pq" / f"{name}.parquet")
        assert t.column_names == f.column_names, name
        # The profile's source is a dictionary here (one string, not one per sample).
        assert t.cast(f.schema).equals(f.cast(f.schema)), name


def test_the_dataset_holds_every_recording_with_the_cli_figures(fleet, dataset):
    _, paths = fleet
    zones_seen = 0
    part = ds.partitioning(flavor="hive")
    blocks = ds.dataset(os.path.join(dataset, "blocks"), format="parquet", partitioning=part).to_table()
    zones = ds.dataset(os.path.join(dataset, "zones"), format="parquet", partitioning=part).to_table()
    runs = ds.dataset(os.path.join(dataset, "runs"), format="parquet", partitioning=part).to_table()
    assert sorted(runs["source"].to_pylist()) == sorted(paths)
    assert runs["error"].null_count == COUNT
    by = lambda t: {s: [] for s in paths} | _group(t)
    b_by, z_by, r_by = by(blocks), by(zones), by(runs)
    for p in paths:
        v = cli_json(p)
        sv = v["survey"]
        want = blocks_of(v)
        got = sorted(b_by[p], key=lambda r: r["start_chainage_mm"])
        assert pick(got, want[0].keys()) == want, p
        wz = zones_of(v)
        gz = sorted(z_by[p], key=lambda r: (r["band_lo_mm"], r["start_chainage_mm"]))
        assert pick(gz, ZONE_KEYS) == sorted(wz, key=lambda r: (r["band_lo_mm"], r["start_chainage_mm"])), p
        zones_seen += len(wz)
        [run] = r_by[p]
        assert run["reprofile_mm"] == v["verdict"]["reprofile_mm"] and run["measured_mm"] == v["verdict"]["measured_mm"]
        for r in got + gz + [run]:
            assert (r["line"], r["track"], str(r["year"])) == (sv["line"], sv["track"], sv["date"][:4]), p
    assert zones_seen > COUNT // 2


def _group(t):
    out = {}
    for r in t.to_pylist():
        out.setdefault(r["source"], []).append(r)
    return out


def test_the_queries_run_and_agree_with_the_dataset(dataset):
    res = queries.run(dataset)
    assert len(res) == 3
    for title, (cols, rows) in res.items():
        assert rows, title
    (cols, rows) = res["reprofiling length per line (EN 13231-3 verdict of each run, summed)"]
    assert sum(r[cols.index("runs")] for r in rows) == COUNT
    con = duckdb.connect()
    total = con.execute(f"SELECT sum(reprofile_mm) FROM read_parquet('{dataset}/runs/**/*.parquet')").fetchone()[0]
    assert math.isclose(sum(r[cols.index("reprofile_m")] for r in rows), total / 1000, abs_tol=0.05 * len(rows))


def test_the_job_replaces_only_its_own_dataset(fleet, tmp_path):
    d, _ = fleet
    other = tmp_path / "other"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    assert job.main([str(d / "in"), str(other), "--workers", "1"]) == 2
    assert (other / "keep.txt").read_text() == "mine"
    assert job.main([str(d / "in"), str(d / "in" / "out")]) == 2


def test_a_bad_recording_is_named_not_dropped(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    synth.write_fleet(str(src), 2, 150, 120, CMS_HOST)
    (src / "bad.cmsrec").write_bytes(b"CMSREC\x00\x01garbage")
    out = str(tmp_path / "ds")
    assert job.main([str(src), out, "--workers", "1", "--block-m", "1"]) == 1
    runs = ds.dataset(os.path.join(out, "runs"), format="parquet", partitioning="hive").to_table().to_pylist()
    [bad] = [r for r in runs if r["source"].endswith("bad.cmsrec")]
    r = cli("analyze", str(src / "bad.cmsrec"))
    assert r.returncode == 2 and r.stderr.strip() == f"error: {bad['error']}"


def test_errors_are_the_cli_lines(tmp_path):
    missing = str(tmp_path / "nope.cmsrec")
    for kwargs, args in [({}, []), ({"block_m": 0}, ["--block-m", "0"]), ({"edition": "1999"}, ["--edition", "1999"])]:
        with pytest.raises(cms.Error) as e:
            cms.analyze(missing, **kwargs)
        r = cli("analyze", missing, *args)
        assert r.returncode == 2
        # clap lists an enum's values on a line of their own.
        assert f"error: {e.value}".startswith(r.stderr.splitlines()[0]), (kwargs, r.stderr)


def test_read_survey(fleet):
    _, paths = fleet
    s = cms.read_survey(paths[0])
    want = synth.spec(0, 150)
    assert (s["line"], s["track"], s["date"], s["year"]) == (want["line"], want["track"], want["date"], int(want["date"][:4]))
