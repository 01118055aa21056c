"""``python -m cms.fleet.job INPUT OUTPUT [--workers N | --scheduler ADDRESS]``

Every recording (``*.cmsrec``) under INPUT — a folder, or any fsspec URL
such as ``s3://bucket/surveys`` with its filesystem package installed — is
analysed on its own, as ``cms-host analyze RECORDING`` would, on a Dask
cluster: a LocalCluster of N single-threaded worker processes on this
machine, or the scheduler at ADDRESS (the same code on a cluster; its
workers need the ``cms`` package and must reach INPUT). The blocks, the
zones and one row per recording (``runs``) go into OUTPUT as a
hive-partitioned Parquet dataset ``TABLE/line=…/track=…/year=…/``.

Then the trend of every site: the analysed recordings grouped by the
``line`` and ``track`` of their survey blocks, and each group holding
surveys of at least two dates followed as ``cms-host trend`` follows them
(``cms.trend``, on a worker): one row per block and band in
``trend/line=…/track=…/``, and one row per group in ``trends`` (its
surveys, or why it has no trend).

OUTPUT is a local folder (on a cluster: one the client writes). It is
written whole into a sibling temporary folder and then renamed into
place: OUTPUT holds the old dataset or the new one, never a mix. An
existing OUTPUT is replaced only when it is a dataset of this job.

A recording that cannot be analysed is not dropped silently: its ``runs``
row carries the error (the line ``cms-host analyze`` prints), the other
recordings are written, and the job exits with status 1 naming it.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import sys
import tempfile
import time
from typing import Optional

import pyarrow as pa
import pyarrow.dataset as ds

import cms

#: The file that marks OUTPUT as this job's dataset (and says how it was made).
MARKER = "_cms_fleet.json"
#: The tables of the dataset, each a folder of OUTPUT.
TABLES = ("blocks", "zones", "runs", "trend", "trends")
#: The partition keys, in order.
PARTITIONS = ("line", "track", "year")
#: The partition keys of the trend's tables: a site's surveys span years.
SITE_KEYS = ("line", "track")
#: The options of ``cms.trend`` the job passes on (the others are ``cms.trend``'s defaults).
TREND_OPTIONS = ("edition", "block_m")
#: The analysis options the job passes on (the keywords of ``cms.analyze``).
OPTIONS = ("edition", "block_m", "dx_mm", "segment_mm")


def list_recordings(source: str) -> list[str]:
    """The recordings under ``source`` (a folder, or an fsspec URL), sorted;
    an error naming ``source`` when it holds none. A folder's are paths
    under it as given (the ``source`` column then names each file as
    ``cms-host analyze`` run here would); a URL's are URLs."""
    if "://" not in source:
        if not os.path.isdir(source):
            raise cms.Error(f"{source}: not a folder")
        found = sorted(
            os.path.join(d, f) for d, _, files in os.walk(source) for f in files if f.endswith(".cmsrec")
        )
    else:
        import fsspec

        fs, root = fsspec.core.url_to_fs(source)
        if not fs.isdir(root):
            raise cms.Error(f"{source}: not a folder")
        found = sorted(fs.unstrip_protocol(p) for p in fs.find(root) if p.endswith(".cmsrec"))
    if not found:
        raise cms.Error(f"{source}: no recordings (*.cmsrec)")
    return found


def _local_copy(url: str, tmp: str) -> str:
    import fsspec

    fs, path = fsspec.core.url_to_fs(url)
    local = os.path.join(tmp, os.path.basename(path))
    fs.get(path, local)
    return local


def _with_keys(t: pa.Table, keys: dict, source: str) -> pa.Table:
    """``t`` with ``source`` set to the recording's name and the partition
    keys as columns."""
    n = t.num_rows
    if "source" in t.column_names:
        t = t.set_column(t.column_names.index("source"), pa.field("source", pa.string(), False), pa.array([source] * n, pa.string()))
    for k in PARTITIONS:
        typ = pa.int32() if k == "year" else pa.string()
        t = t.append_column(pa.field(k, typ), pa.array([keys[k]] * n, typ))
    return t


def analyse_one(url: str, options: dict) -> dict:
    """One recording analysed: its blocks, zones and runs row (Arrow IPC
    bytes, cheap to send back), or its error in the runs row."""
    t0 = time.perf_counter()
    keys = {"line": None, "track": None, "year": None}
    row = {"source": url, "error": None}
    out = {}
    try:
        with tempfile.TemporaryDirectory(prefix="cms-fleet-") as tmp:
            path = url if "://" not in url else _local_copy(url, tmp)
            survey = cms.read_survey(path) or {}
            keys = {k: survey.get(k) for k in PARTITIONS}
            a = cms.analyze(path, profile=False, **options)
        v = a.summary["verdict"]
        limits = {(b["lo_mm"], b["hi_mm"]): b["limit_mm"] for b in v["bands"]}
        zones = a.zones.append_column(
            pa.field("limit_mm", pa.float64(), False),
            pa.array([limits[(lo, hi)] for lo, hi in zip(a.zones["band_lo_mm"].to_pylist(), a.zones["band_hi_mm"].to_pylist())], pa.float64()),
        )
        out["blocks"] = _with_keys(a.blocks, keys, url)
        out["zones"] = _with_keys(zones, keys, url)
        row.update(
            date=survey.get("date"),
            rail=survey.get("rail"),
            start_chainage=survey.get("start_chainage"),
            edition=v["edition"],
            measured_mm=v["measured_mm"],
            reprofile_mm=v["reprofile_mm"],
            blocks=a.blocks.num_rows,
            zones=a.zones.num_rows,
        )
    except cms.Error as e:
        row["error"] = str(e)
    row.update(keys)
    row["seconds"] = time.perf_counter() - t0
    out["runs"] = pa.Table.from_pylist([row], schema=RUNS_SCHEMA)
    return {k: _ipc(t) for k, t in out.items()}


RUNS_SCHEMA = pa.schema(
    [
        pa.field("source", pa.string(), False),
        pa.field("error", pa.string()),
        pa.field("date", pa.string()),
        pa.field("rail", pa.string()),
        pa.field("start_chainage", pa.string()),
        pa.field("edition", pa.string()),
        pa.field("measured_mm", pa.float64()),
        pa.field("reprofile_mm", pa.float64()),
        pa.field("blocks", pa.int64()),
        pa.field("zones", pa.int64()),
        pa.field("line", pa.string()),
        pa.field("track", pa.string()),
        pa.field("year", pa.int32()),
        pa.field("seconds", pa.float64()),
    ]
)


def _ipc(t: pa.Table) -> bytes:
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, t.schema) as w:
        w.write_table(t)
    return sink.getvalue().to_pybytes()


def _table(b: bytes) -> pa.Table:
    return pa.ipc.open_stream(b).read_all()


def run(urls: list[str], client, options: dict) -> dict:
    """Analyses ``urls`` on the Dask ``client``: each table concatenated
    over the recordings, in the order of ``urls``."""
    futures = client.map(analyse_one, urls, options=options, pure=False)
    results = client.gather(futures)
    tables = {}
    for name in TABLES:
        parts = [_table(r[name]) for r in results if name in r]
        tables[name] = pa.concat_tables(parts, promote_options="default") if parts else None
    return tables


TRENDS_SCHEMA = pa.schema(
    [
        pa.field("line", pa.string(), False),
        pa.field("track", pa.string(), False),
        pa.field("surveys", pa.int32(), False),
        pa.field("sources", pa.list_(pa.string()), False),
        pa.field("dates", pa.list_(pa.date32()), False),
        pa.field("error", pa.string()),
        pa.field("blocks", pa.int64()),
        pa.field("seconds", pa.float64()),
    ]
)


def sites(runs: pa.Table) -> list[tuple[str, str, list[str], list[str]]]:
    """The analysed recordings grouped by the ``line`` and ``track`` of
    their survey blocks: (line, track, sources, dates), the sources in
    date order (then by name). A recording without a line, track or date
    belongs to no site."""
    groups: dict = {}
    for r in runs.to_pylist():
        if r["error"] is None and r["line"] is not None and r["track"] is not None and r["date"] is not None:
            groups.setdefault((r["line"], r["track"]), []).append((r["date"], r["source"]))
    out = []
    for (line, track), surveys in sorted(groups.items()):
        surveys.sort()
        out.append((line, track, [s for _, s in surveys], [d for d, _ in surveys]))
    return out


def trend_one(line: str, track: str, urls: list[str], dates: list[str], options: dict) -> dict:
    """One site's trend: its rows (Arrow IPC bytes) and its ``trends`` row,
    or the row with the error (the line ``cms-host trend`` prints, or why
    the site has no trend)."""
    import datetime

    t0 = time.perf_counter()
    row = {
        "line": line,
        "track": track,
        "surveys": len(urls),
        "sources": urls,
        "dates": [datetime.date.fromisoformat(d) for d in dates],
        "error": None,
        "blocks": None,
    }
    out = {}
    copies = {}
    try:
        if len(set(dates)) < 2:
            raise cms.Error(f"{len(urls)} survey(s) all of {dates[0]}: a trend needs surveys of at least two dates")
        with tempfile.TemporaryDirectory(prefix="cms-fleet-") as tmp:
            paths = [u if "://" not in u else _local_copy_as(u, tmp, i) for i, u in enumerate(urls)]
            copies = {p: u for p, u in zip(paths, urls) if p != u}
            # The survey blocks' dates, as grouped here: the trend follows the same surveys.
            tr = cms.trend(paths, dates=dates, **options)
        t = tr.table
        n = t.num_rows
        for k in SITE_KEYS:
            t = t.append_column(pa.field(k, pa.string(), False), pa.array([row[k]] * n, pa.string()))
        out["trend"] = t
        row["blocks"] = len({(s, e) for s, e in zip(t["start_chainage_mm"].to_pylist(), t["end_chainage_mm"].to_pylist())})
    except cms.Error as e:
        # A copy's path in the message named as the job names the recording: its URL.
        msg = str(e)
        for p, u in copies.items():
            msg = msg.replace(p, u)
        row["error"] = msg
    row["seconds"] = time.perf_counter() - t0
    out["trends"] = pa.Table.from_pylist([row], schema=TRENDS_SCHEMA)
    return {k: _ipc(t) for k, t in out.items()}


def _local_copy_as(url: str, tmp: str, i: int) -> str:
    """A URL's recording copied to its own folder of ``tmp`` (two surveys
    of a site may share a file name)."""
    d = os.path.join(tmp, str(i))
    os.makedirs(d)
    return _local_copy(url, d)


def run_trends(runs: pa.Table, client, options: dict) -> dict:
    """The trend of every site of ``runs`` on the Dask ``client``: the
    ``trend`` and ``trends`` tables (``None``: no site)."""
    topts = {k: options[k] for k in TREND_OPTIONS}
    futures = [client.submit(trend_one, line, track, urls, dates, topts, pure=False) for line, track, urls, dates in sites(runs)]
    results = client.gather(futures)
    tables = {}
    for name in ("trend", "trends"):
        parts = [_table(r[name]) for r in results if name in r]
        tables[name] = pa.concat_tables(parts, promote_options="default") if parts else None
    return tables


def _is_dataset(path: str) -> bool:
    return os.path.isfile(os.path.join(path, MARKER))


def write(output: str, tables: dict, about: dict) -> None:
    """Writes the dataset into ``output`` atomically (a sibling temporary
    folder renamed into place)."""
    output = os.path.abspath(output)
    if os.path.lexists(output) and not (os.path.isdir(output) and _is_dataset(output)):
        raise cms.Error(f"{output}: exists and is not a dataset of cms.fleet.job; give a new folder")
    parent = os.path.dirname(output)
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=".cms-fleet-", dir=parent)
    try:
        keys = {"line": pa.string(), "track": pa.string(), "year": pa.int32()}
        for name in TABLES:
            by = SITE_KEYS if name in ("trend", "trends") else PARTITIONS
            part = ds.partitioning(pa.schema([pa.field(k, keys[k]) for k in by]), flavor="hive")
            t = tables.get(name)
            if t is None or t.num_rows == 0:
                os.makedirs(os.path.join(tmp, name))
                continue
            ds.write_dataset(
                t,
                os.path.join(tmp, name),
                format="parquet",
                partitioning=part,
                basename_template=name + "-{i}.parquet",
                existing_data_behavior="error",
            )
        with open(os.path.join(tmp, MARKER), "w") as f:
            json.dump(about, f, indent=1)
        old = None
        if os.path.lexists(output):
            old = tempfile.mkdtemp(prefix=".cms-fleet-old-", dir=parent)
            os.rename(output, os.path.join(old, "d"))
        os.rename(tmp, output)
        tmp = None
        if old:
            shutil.rmtree(old)
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)


def _inside(a: str, b: str) -> bool:
    a, b = os.path.realpath(a), os.path.realpath(b)
    return a == b or a.startswith(b + os.sep)


def client_for(workers: Optional[int], scheduler: Optional[str]):
    """A Dask client: of the scheduler at ``scheduler``, else of a
    LocalCluster of ``workers`` single-threaded processes."""
    from dask.distributed import Client, LocalCluster

    # The cluster's own lines (workers starting, closing) are not the job's output.
    logging.getLogger("distributed").setLevel(logging.WARNING)
    if scheduler:
        return Client(scheduler)
    cluster = LocalCluster(
        n_workers=workers or os.cpu_count() or 1,
        threads_per_worker=1,
        processes=True,
        dashboard_address=":0",
        silence_logs=logging.WARNING,
    )
    return Client(cluster)


def main(argv: Optional[list[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="python -m cms.fleet.job", description=__doc__.split("\n\n")[1])
    p.add_argument("input", metavar="INPUT", help="a folder or fsspec URL holding *.cmsrec recordings")
    p.add_argument("output", metavar="OUTPUT", help="the dataset folder to write (replaced whole)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, help="LocalCluster worker processes (default: one per CPU)")
    g.add_argument("--scheduler", metavar="ADDRESS", help="a Dask scheduler (tcp://host:8786) instead of a LocalCluster")
    p.add_argument("--edition", default="2006", choices=["2006", "2012"])
    p.add_argument("--block-m", type=float, default=50.0)
    p.add_argument("--dx-mm", type=float)
    p.add_argument("--segment-mm", type=float, default=1000.0)
    a = p.parse_args(argv)
    if a.workers is not None and a.workers < 1:
        p.error(f"--workers {a.workers}: at least 1")
    options = {"edition": a.edition, "block_m": a.block_m, "dx_mm": a.dx_mm, "segment_mm": a.segment_mm}
    try:
        if "://" not in a.input and (_inside(a.output, a.input) or _inside(a.input, a.output)):
            raise cms.Error(f"{a.output}: inside the input {a.input} (or holding it); write the dataset elsewhere")
        urls = list_recordings(a.input)
        t0 = time.perf_counter()
        with client_for(a.workers, a.scheduler) as client:
            workers = len(client.scheduler_info()["workers"])
            t1 = time.perf_counter()
            tables = run(urls, client, options)
            t2 = time.perf_counter()
            tables.update(run_trends(tables["runs"], client, options))
            t3 = time.perf_counter()
        runs = tables["runs"]
        failed = [(s, e) for s, e in zip(runs["source"].to_pylist(), runs["error"].to_pylist()) if e]
        trends = tables["trends"]
        untrended = [] if trends is None else [r for r in trends.to_pylist() if r["error"]]
        about = {
            "schema": cms.SCHEMA_VERSION,
            "input": a.input,
            "recordings": len(urls),
            "failed": len(failed),
            "options": options,
            "workers": workers,
            "analysis_s": round(t2 - t1, 3),
            "sites": 0 if trends is None else trends.num_rows,
            "trends_failed": len(untrended),
            "trend_s": round(t3 - t2, 3),
        }
        write(a.output, tables, about)
    except cms.Error as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for s, e in failed:
        print(f"error: {e}", file=sys.stderr)
    # A site without a trend is data, not a failure of the job: named, and in `trends`.
    for r in untrended:
        print(f"note: no trend for {r['line']} / {r['track']}: {r['error']}", file=sys.stderr)
    print(
        f"{a.output}: {len(urls)} recordings ({len(failed)} failed) on {workers} workers in {t2 - t1:.2f} s "
        f"({len(urls) / (t2 - t1):.1f} recordings/s; cluster start {t1 - t0:.1f} s); "
        f"{about['sites']} sites, {about['sites'] - len(untrended)} with a trend, in {t3 - t2:.2f} s"
    )
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
