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
TREND_QUERY = "the blocks that will cross their EN 13231-3 limit soonest (trend of each site)"


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
def dataset(fleet, cluster):
    """The fleet's dataset, made on a scheduler and two workers started
    from the command line (conftest.py), the workers writing into a
    folder they share with the client."""
    d, _ = fleet
    out = str(d / "dataset")
    assert job.main([str(d / "in"), out, "--scheduler", cluster, "--block-m", str(BLOCK_M)]) == 0
    return out


ISO_CLASSES = ("within_mm", "exceeded_mm", "not_judged_mm")


def iso3095_of(o, suffix):
    """A spectrum's ISO 3095 verdict and third octaves in the JSON as the table's columns."""
    row = {f"iso3095_verdict{suffix}": None if o is None else o["verdict"]}
    for c in ISO_CLASSES:
        row[f"iso3095_{c}{suffix}"] = None if o is None else [float(w) for w in o[c]]
    return row


def blocks_of(v):
    """The CLI's blocks as the table's rows: the energy average's ISO 3095
    verdict and each line's (``_K``, null where the line has no spectrum)."""
    lasers = sorted({l["laser"] for l in v["lasers"]})
    rows = []
    for b in v["verdict"]["blocks"]:
        row = {"start_chainage_mm": b["start_mm"], "end_chainage_mm": b["end_mm"]}
        for k, r in zip(BANDS, b["rms_mm"]):
            row[f"rms_um_{k}"] = None if r is None else r * 1000.0
        row |= iso3095_of(b["iso3095"], "")
        lines = {l["laser"]: l["iso3095"] for l in b["lines"]}
        for k in lasers:
            row |= iso3095_of(lines.get(k), f"_{k}")
        rows.append(row)
    return rows


def third_octaves_of(v):
    """The CLI's blocks' ISO 3095 third octaves as ``third_octaves``' rows:
    per block the energy average (``laser`` null), then each line."""
    rows = []
    for b in v["verdict"]["blocks"]:
        spectra = [(None, b["iso3095"])] + [(l["laser"], l["iso3095"]) for l in b["lines"]]
        for laser, o in spectra:
            for t in [] if o is None else o["bands"]:
                d = t["decision"]
                if d is not None:
                    rows.append(
                        {
                            "start_chainage_mm": b["start_mm"],
                            "laser": laser,
                            "wavelength_mm": t["nominal_wavelength_mm"],
                            "level_db": t["level_db"],
                            "floor_db": t["floor_db"],
                            "rail_db": d["rail_db"],
                            "rail_lo_db": d["rail_lo_db"],
                            "verdict": d["verdict"],
                        }
                    )
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
    zones = octaves = 0
    verdicts = set()
    for p in paths[:5]:
        v = cli_json(p)
        a = cms.analyze(p, block_m=BLOCK_M)
        assert a.summary == v
        want = blocks_of(v)
        assert pick(a.blocks.to_pylist(), want[0].keys()) == want
        verdicts.update(r["iso3095_verdict"] for r in want)
        assert a.blocks["source"].to_pylist() == [p] * len(want)
        wz = zones_of(v)
        zones += len(wz)
        assert pick(a.zones.to_pylist(), ZONE_KEYS) == wz
        assert a.profile.num_rows > 1000 and a.profile["coverage"].null_count == 0
        wt = third_octaves_of(v)
        octaves += len(wt)
        assert wt and pick(a.third_octaves.to_pylist(), wt[0].keys()) == wt
    assert zones > 0 and octaves > 0
    assert verdicts - {None}, verdicts

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
    # Without the profile (as the fleet job asks): the same figures, no profile.
    b = cms.analyze(p, block_m=BLOCK_M, profile=False)
    assert b.profile is None and b.blocks.equals(a.blocks) and b.zones.equals(a.zones)
    assert b.summary == a.summary


def test_the_dataset_holds_every_recording_with_the_cli_figures(fleet, dataset):
    _, paths = fleet
    zones_seen = 0
    part = ds.partitioning(flavor="hive")
    blocks = ds.dataset(os.path.join(dataset, "blocks"), format="parquet", partitioning=part).to_table()
    zones = ds.dataset(os.path.join(dataset, "zones"), format="parquet", partitioning=part).to_table()
    runs = ds.dataset(os.path.join(dataset, "runs"), format="parquet", partitioning=part).to_table()
    octaves = ds.dataset(os.path.join(dataset, "third_octaves"), format="parquet", partitioning=part).to_table()
    assert sorted(runs["source"].to_pylist()) == sorted(paths)
    assert runs["error"].null_count == COUNT
    by = lambda t: {s: [] for s in paths} | _group(t)
    b_by, z_by, r_by, o_by = by(blocks), by(zones), by(runs), by(octaves)
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
        keys = ("start_chainage_mm", "laser", "wavelength_mm", "verdict")
        order = lambda r: (r["start_chainage_mm"], -1 if r["laser"] is None else r["laser"], -r["wavelength_mm"])
        assert pick(sorted(o_by[p], key=order), keys) == pick(sorted(third_octaves_of(v), key=order), keys), p
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
    assert len(res) == 5
    # The fleet's sites are surveyed at other chainages each time: no trend (test_the_trend_… has one).
    assert res.pop(TREND_QUERY) == ([], [])
    for title, (cols, rows) in res.items():
        assert rows, title
    trends = ds.dataset(os.path.join(dataset, "trends"), format="parquet", partitioning="hive").to_table().to_pylist()
    runs = ds.dataset(os.path.join(dataset, "runs"), format="parquet", partitioning="hive").to_table().to_pylist()
    assert sorted((r["line"], r["track"]) for r in trends) == sorted({(r["line"], r["track"]) for r in runs})
    assert sum(r["surveys"] for r in trends) == COUNT
    assert all(r["error"] for r in trends), [r for r in trends if not r["error"]]
    # Every block with a spectrum counted once, by its verdict.
    (cols, rows) = res[queries.ISO3095_QUERY]
    blocks = duckdb.connect().execute(
        f"SELECT iso3095_verdict, count(*) FROM read_parquet('{dataset}/blocks/**/*.parquet', union_by_name = true) GROUP BY ALL"
    ).fetchall()
    by_verdict = dict(blocks)
    for word, column in [("EXCEEDS", "blocks_exceeding"), ("not judged", "blocks_not_judged"), ("within", "blocks_within")]:
        assert sum(r[cols.index(column)] for r in rows) == by_verdict.get(word, 0), (word, blocks)
    assert sum(by_verdict.get(w, 0) for w in ("EXCEEDS", "not judged", "within")) > 0, blocks
    # Every energy average's third octave counted once, by its verdict.
    (cols, rows) = res[queries.THIRD_OCTAVE_QUERY]
    octaves = dict(
        duckdb.connect()
        .execute(f"SELECT verdict, count(*) FROM read_parquet('{dataset}/third_octaves/**/*.parquet') WHERE laser IS NULL GROUP BY ALL")
        .fetchall()
    )
    for word, column in [("EXCEEDS", "exceeding"), ("not judged", "not_judged"), ("within", "within")]:
        assert sum(r[cols.index(column)] for r in rows) == octaves.get(word, 0), (word, octaves)
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


# One site surveyed three times a year apart, its 10–20 m corrugated at
# 4 → 6 → 8 µm (peak to peak 8 → 12 → 16 µm, the 30–100 mm band's limit
# 20 µm): 30 m of rail in blocks of 10 m, so the grown block is 10–20 m.
SITE = {"line": "LN 9 Test", "track": "up main", "start_chainage": "0+000", "chainage": "up"}
SITE_DATES = ["2024-05-02", "2025-05-02", "2026-05-02"]
SITE_FRAMES = 1765
SITE_BLOCK_M = 10.0


@pytest.fixture(scope="session")
def site(tmp_path_factory):
    """The site's three surveys, and a second site (the other track)
    surveyed twice at chainages 5 km apart: a trend that cannot be."""
    d = tmp_path_factory.mktemp("site")
    up = synth.write_site(str(d / "in" / "up"), CMS_HOST, SITE, SITE_DATES, [4.0, 6.0, 8.0], SITE_FRAMES, 120, (10.0, 20.0))
    down = {**SITE, "track": "down main"}
    # 400 frames, 6.8 m: over half a block, so the first survey has a figure of its block.
    apart = synth.write_site(str(d / "in" / "down-a"), CMS_HOST, down, SITE_DATES[:1], [0.0], 400, 120, (1.0, 2.0))
    apart += synth.write_site(
        str(d / "in" / "down-b"), CMS_HOST, {**down, "start_chainage": "5+000"}, SITE_DATES[1:2], [0.0], 400, 120, (1.0, 2.0)
    )
    return d, up, apart


def cli_trend(paths):
    r = cli("trend", *paths, "--block-m", str(SITE_BLOCK_M), "--json")
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def trend_rows_of(v):
    """The CLI's trend as the table's rows."""
    rows = []
    for b in v["blocks"]:
        figures = [f for f in b["figures"] if f is not None]
        c = b["crossing"]
        rows.append(
            {
                "start_chainage_mm": b["start_mm"],
                "end_chainage_mm": b["end_mm"],
                "band_lo_mm": b["lo_mm"],
                "band_hi_mm": b["hi_mm"],
                "limit_mm": b["limit_mm"],
                "surveys": len(figures),
                "last_figure_mm": figures[-1]["figure_mm"] if figures else None,
                "last_u_mm": figures[-1]["u_mm"] if figures else None,
                "growth_mm_per_year": b["growth_mm_per_year"],
                "u_growth_mm_per_year": b["u_growth_mm_per_year"],
                "chi2_reduced": b["chi2_reduced"],
                "crossing": c["kind"],
                "crossing_date": c.get("date"),
                "crossing_earliest_date": c.get("earliest"),
                "crossing_latest_date": c.get("latest"),
                "not_within_years": c.get("years"),
            }
        )
    return rows


def iso(rows):
    """The rows with their dates as ISO text (the JSON's)."""
    return [{k: v.isoformat() if hasattr(v, "isoformat") else v for k, v in r.items()} for r in rows]


def test_cms_trend_is_the_cli_trend(site):
    _, up, _ = site
    v = cli_trend(up)
    t = cms.trend(up, block_m=SITE_BLOCK_M)
    assert t.summary == v
    want = trend_rows_of(v)
    assert len(want) == t.table.num_rows > 0
    assert iso(pick(t.table.to_pylist(), want[0].keys())) == want
    assert t.table.schema.field("crossing_date").type == pa.date32()
    assert t.table["last_date"].to_pylist()[0].isoformat() == SITE_DATES[-1]
    # The grown block crosses 30–100 mm's limit; its growth that of 4 µm a year of amplitude (8 µm/yr peak to peak is the ceiling).
    [grown] = [r for r in t.table.to_pylist() if r["start_chainage_mm"] == 10_000.0 and r["band_lo_mm"] == 30.0]
    assert grown["crossing"] == "on" and 0.002 < grown["growth_mm_per_year"] < 0.006, grown


def test_trend_errors_are_the_cli_lines(site):
    _, up, apart = site
    for paths, kwargs, args in [
        (up[:1], {}, []),
        (apart, {}, []),
        (up, {"dates": ["2024-13-01"]}, ["--date", "2024-13-01"]),
        (up, {"block_m": 0.5}, ["--block-m", "0.5"]),
    ]:
        with pytest.raises(cms.Error) as e:
            cms.trend(paths, **kwargs)
        r = cli("trend", *paths, *args)
        assert r.returncode == 2
        assert f"error: {e.value}" == r.stderr.splitlines()[0], (kwargs, r.stderr)


def test_the_dataset_holds_each_sites_trend(site):
    d, up, apart = site
    out = str(d / "dataset")
    assert job.main([str(d / "in"), out, "--workers", "2", "--block-m", str(SITE_BLOCK_M)]) == 0
    assert sorted(os.listdir(os.path.join(out, "trend"))) == ["line=LN%209%20Test"]
    assert os.listdir(os.path.join(out, "trend", "line=LN%209%20Test")) == ["track=up%20main"]
    t = ds.dataset(os.path.join(out, "trend"), format="parquet", partitioning="hive").to_table()
    rows = sorted(t.to_pylist(), key=lambda r: (r["start_chainage_mm"], r["band_lo_mm"]))
    v = cli_trend(up)
    want = sorted(trend_rows_of(v), key=lambda r: (r["start_chainage_mm"], r["band_lo_mm"]))
    assert iso(pick(rows, want[0].keys())) == want
    assert {(r["line"], r["track"]) for r in rows} == {("LN 9 Test", "up main")}
    trends = ds.dataset(os.path.join(out, "trends"), format="parquet", partitioning="hive").to_table().to_pylist()
    by = {r["track"]: r for r in trends}
    assert sorted(by) == ["down main", "up main"]
    assert by["up main"]["error"] is None and by["up main"]["sources"] == up
    assert by["up main"]["blocks"] == len({b["start_mm"] for b in v["blocks"]}) > 1
    assert [x.isoformat() for x in by["up main"]["dates"]] == SITE_DATES
    # The site that cannot be followed: its error is the command line's.
    r = cli("trend", *apart, "--block-m", str(SITE_BLOCK_M))
    assert r.returncode == 2 and r.stderr.strip() == f"error: {by['down main']['error']}"
    assert by["down main"]["error"].startswith(f"{apart[1]} does not overlap {apart[0]}"), by["down main"]
    cols, got = queries.run(out)[TREND_QUERY]
    assert got, "no block crossing"
    first = dict(zip(cols, got[0]))
    nearest = [b for b in v["blocks"] if b["crossing"]["kind"] in ("on", "already_over")]
    assert (first["line"], first["track"], first["from_m"], first["band_mm"]) == ("LN 9 Test", "up main", 10.0, "30.0-100.0")
    assert first["crossing_date"].isoformat() == min(
        (b for b in nearest if b["crossing"]["kind"] == "on"), key=lambda b: b["crossing"]["date"]
    )["crossing"]["date"]


def test_tasks_are_cut_by_count_and_bytes_in_order():
    small = [(f"r{i}", 1000) for i in range(10_000)]
    tasks = list(job.batches(small, 2))
    assert [u for t in tasks for u in t] == [u for u, _ in small]
    assert max(map(len, tasks)) == job.MAX_TASK_RECORDINGS and len(tasks) == 157
    # Few recordings: at least TASKS_IN_FLIGHT_PER_WORKER tasks per worker.
    assert [len(t) for t in job.batches(small[:20], 2)] == [3] * 6 + [2]
    big = [(f"b{i}", 40 << 20) for i in range(100)]
    assert [len(t) for t in job.batches(big, 2)] == [2] * 50


REGISTER = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", "examples", "track-register.csv"))


def test_the_job_places_runs_by_their_fixes(tmp_path, cluster):
    """``--track-register``: each recording's runs placed by their GNSS
    fixes (``runs.placed_by``), its blocks those of ``cms-host analyze
    --track-register --json``, the site followed at the fixes' chainage."""
    survey = {**SITE, "line": "LN 4 GNSS", "start_chainage": "41+100"}
    paths = synth.write_site(str(tmp_path / "in"), CMS_HOST, survey, SITE_DATES[:2], [4.0, 8.0], 600, 120, (2.0, 6.0), gnss=REGISTER)
    out = str(tmp_path / "dataset")
    assert job.main([str(tmp_path / "in"), out, "--scheduler", cluster, "--block-m", str(BLOCK_M), "--track-register", REGISTER]) == 0
    part = ds.partitioning(flavor="hive")
    runs = ds.dataset(os.path.join(out, "runs"), format="parquet", partitioning=part).to_table().to_pylist()
    assert sorted(r["source"] for r in runs) == paths and {r["placed_by"] for r in runs} == {"gnss"}, runs
    blocks = _group(ds.dataset(os.path.join(out, "blocks"), format="parquet", partitioning=part).to_table())
    for p in paths:
        r = cli("analyze", p, "--block-m", str(BLOCK_M), "--track-register", REGISTER, "--json")
        assert r.returncode == 0, r.stderr
        v = json.loads(r.stdout)
        assert v["gnss_placing"][0]["placed_by"] == "gnss"
        want = blocks_of(v)
        assert abs(want[0]["start_chainage_mm"] - 41_100_000.0) < 200.0, want[0]
        got = sorted(blocks[p], key=lambda r: r["start_chainage_mm"])
        assert pick(got, want[0].keys()) == want, p
    trends = ds.dataset(os.path.join(out, "trends"), format="parquet", partitioning=part).to_table().to_pylist()
    assert [t["error"] for t in trends] == [None], trends
    # A register that is not there: refused before any work, nothing written.
    assert job.main([str(tmp_path / "in"), str(tmp_path / "d2"), "--workers", "1", "--track-register", str(tmp_path / "no.csv")]) == 2
    assert not os.path.exists(tmp_path / "d2")
