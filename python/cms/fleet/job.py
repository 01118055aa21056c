"""``python -m cms.fleet.job INPUT OUTPUT [--workers N | --scheduler ADDRESS]``

Every recording (``*.cmsrec``) under INPUT — a folder, or any fsspec URL
such as ``s3://bucket/surveys`` with its filesystem package installed — is
analysed on its own, as ``cms-host analyze RECORDING`` would, on a Dask
cluster: a LocalCluster of N single-threaded worker processes on this
machine, or the scheduler at ADDRESS (the same code on a cluster; its
workers need the ``cms`` package and must reach INPUT and OUTPUT). The blocks, the
zones, the blocks' ISO 3095 third octaves (``third_octaves``) and one row
per recording (``runs``) go into OUTPUT as a
hive-partitioned Parquet dataset ``TABLE/line=…/track=…/year=…/``.

Then the trend of every site: the analysed recordings grouped by the
``line`` and ``track`` of their survey blocks, and each group holding
surveys of at least two dates followed as ``cms-host trend`` follows them
(``cms.trend``, on a worker): one row per block and band in
``trend/line=…/track=…/``, and one row per group in ``trends`` (its
surveys, or why it has no trend).

OUTPUT is a folder (on a cluster: one the workers share at the same
path) or an fsspec URL of a bucket prefix. The workers write their own
partition files into a staging location and send the client only their
paths, row counts and the recordings' errors; the client publishes the
dataset whole (``cms.fleet.store``): OUTPUT holds the old dataset or the
new one, never a mix. An existing OUTPUT is replaced only when it is a
dataset of this job.

With ``--track-register REGISTER`` (a path or URL the workers can read)
each run with GNSS fixes is placed by them, as ``cms-host analyze
--track-register`` places it, and the trends follow the same placing;
``runs.placed_by`` says what placed each recording's runs.

A recording that cannot be analysed is not dropped silently: its ``runs``
row carries the error (the line ``cms-host analyze`` prints), the other
recordings are written, and the job exits with status 1 naming it.
"""


from __future__ import annotations

import argparse
import datetime
import logging
import math
import os
import sys
import tempfile
import time
from typing import Callable, Iterable, Iterator, Optional

import pyarrow as pa

import cms

from . import store

#: The file that marks OUTPUT as this job's dataset: its manifest.
MARKER = store.MANIFEST
#: The tables of the dataset, each a folder of OUTPUT.
TABLES = tuple(store.PARTITIONS)
#: The partition keys of the recordings' tables, in order.
PARTITIONS = store.PARTITIONS["blocks"]
#: The partition keys of the trend's tables: a site's surveys span years.
SITE_KEYS = store.PARTITIONS["trend"]
#: The options of ``cms.trend`` the job passes on (the others are ``cms.trend``'s defaults).
TREND_OPTIONS = ("edition", "block_m", "track_register")
#: The analysis options the job passes on (the keywords of ``cms.analyze``).
OPTIONS = ("edition", "block_m", "dx_mm", "segment_mm", "track_register")
#: A task's recordings: at most this many, and no more once they reach MAX_TASK_BYTES.
MAX_TASK_RECORDINGS = 64
MAX_TASK_BYTES = 64 << 20
#: Tasks in flight per worker: enough to keep every worker busy, few enough
#: that the client and the scheduler hold a bounded number of futures.
TASKS_IN_FLIGHT_PER_WORKER = 4


def list_recordings(source: str) -> list[tuple[str, int]]:
    """The recordings under ``source`` (a folder, or an fsspec URL) with
    their sizes in bytes, sorted; an error naming ``source`` when it holds
    none. A folder's are paths under it as given (the ``source`` column
    then names each file as ``cms-host analyze`` run here would); a URL's
    are URLs."""
    if "://" not in source:
        if not os.path.isdir(source):
            raise cms.Error(f"{source}: not a folder")
        found = sorted(
            (p, os.path.getsize(p))
            for p in (os.path.join(d, f) for d, _, files in os.walk(source) for f in files if f.endswith(".cmsrec"))
        )
    else:
        import fsspec

        try:
            fs, root = fsspec.core.url_to_fs(source)
            fs.invalidate_cache()
            if not fs.isdir(root):
                raise cms.Error(f"{source}: not a folder")
            found = sorted(
                (fs.unstrip_protocol(p), int(info.get("size") or 0))
                for p, info in fs.find(root, detail=True).items()
                if p.endswith(".cmsrec")
            )
        except (ImportError, ValueError, OSError) as e:
            raise cms.Error(f"{source}: {e}".replace("\n", " ")) from e
    if not found:
        raise cms.Error(f"{source}: no recordings (*.cmsrec)")
    return found


def batches(recordings: list[tuple[str, int]], workers: int) -> Iterator[list[str]]:
    """The recordings cut into tasks in order: at least
    ``TASKS_IN_FLIGHT_PER_WORKER`` tasks per worker while there are
    recordings enough, each of at most ``MAX_TASK_RECORDINGS`` recordings
    and closed once it holds ``MAX_TASK_BYTES``."""
    per = max(1, min(MAX_TASK_RECORDINGS, math.ceil(len(recordings) / (TASKS_IN_FLIGHT_PER_WORKER * max(1, workers)))))
    task: list[str] = []
    size = 0
    for url, n in recordings:
        task.append(url)
        size += n
        if len(task) == per or size >= MAX_TASK_BYTES:
            yield task
            task, size = [], 0
    if task:
        yield task


def _local_copy(url: str, tmp: str) -> str:
    import fsspec

    fs, path = fsspec.core.url_to_fs(url)
    local = os.path.join(tmp, os.path.basename(path))
    fs.get(path, local)
    return local


def _with_register(options: dict, tmp: str) -> dict:
    """``options`` with the track register's URL (when it is one) as a
    local copy in ``tmp``: each worker reads it where the job was told."""
    reg = options.get("track_register")
    if reg is None or "://" not in reg:
        return options
    return {**options, "track_register": _local_copy(reg, tmp)}


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
    """One recording analysed: its blocks, zones and runs row as tables
    (the runs row with its error when it cannot be analysed)."""
    t0 = time.perf_counter()
    keys = {"line": None, "track": None, "year": None}
    row = {"source": url, "error": None}
    out = {}
    path = url
    try:
        with tempfile.TemporaryDirectory(prefix="cms-fleet-") as tmp:
            if "://" in url:
                path = _local_copy(url, tmp)
            survey = cms.read_survey(path) or {}
            keys = {k: survey.get(k) for k in PARTITIONS}
            a = cms.analyze(path, profile=False, **_with_register(options, tmp))
        v = a.summary["verdict"]
        limits = {(b["lo_mm"], b["hi_mm"]): b["limit_mm"] for b in v["bands"]}
        zones = a.zones.append_column(
            pa.field("limit_mm", pa.float64(), False),
            pa.array([limits[(lo, hi)] for lo, hi in zip(a.zones["band_lo_mm"].to_pylist(), a.zones["band_hi_mm"].to_pylist())], pa.float64()),
        )
        out["blocks"] = _with_keys(a.blocks, keys, url)
        out["zones"] = _with_keys(zones, keys, url)
        out["third_octaves"] = _with_keys(a.third_octaves, keys, url)
        row.update(
            date=survey.get("date"),
            rail=survey.get("rail"),
            start_chainage=survey.get("start_chainage"),
            edition=v["edition"],
            measured_mm=v["measured_mm"],
            reprofile_mm=v["reprofile_mm"],
            placed_by=",".join(p["placed_by"] for p in a.summary["gnss_placing"]) if options.get("track_register") else None,
            blocks=a.blocks.num_rows,
            zones=a.zones.num_rows,
        )
    except (cms.Error, OSError) as e:
        # A copy's path in the message named as the job names the recording: its URL.
        msg = str(e).replace(path, url)
        row["error"] = msg if isinstance(e, cms.Error) else f"{url}: {msg}"
    row.update(keys)
    row["seconds"] = time.perf_counter() - t0
    out["runs"] = pa.Table.from_pylist([row], schema=RUNS_SCHEMA)
    return out


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
        pa.field("placed_by", pa.string()),
        pa.field("blocks", pa.int64()),
        pa.field("zones", pa.int64()),
        pa.field("line", pa.string()),
        pa.field("track", pa.string()),
        pa.field("year", pa.int32()),
        pa.field("seconds", pa.float64()),
    ]
)

#: What a task sends back of each recording: enough for the client to
#: name the failures and group the sites, nothing of the tables.
RUN_KEYS = ("source", "error", "line", "track", "date", "measured_mm")


def _concat(parts: list) -> Optional[pa.Table]:
    return pa.concat_tables(parts, promote_options="default") if parts else None


def analyse_task(urls: list[str], stage: str, task: int, options: dict) -> dict:
    """A task's recordings analysed on a worker, its tables written by the
    worker into ``stage`` (one file per table and partition): back go the
    files' paths and row counts, and per recording the ``RUN_KEYS``."""
    parts: dict = {"blocks": [], "zones": [], "third_octaves": [], "runs": []}
    for url in urls:
        for name, t in analyse_one(url, options).items():
            parts[name].append(t)
    runs = _concat(parts["runs"])
    files = store.write_tables(stage, {k: _concat(v) for k, v in parts.items()}, f"{task:06d}")
    return {"files": files, "runs": runs.select(list(RUN_KEYS)).to_pylist()}


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


class Sites:
    """The analysed recordings grouped by the ``line`` and ``track`` of
    their survey blocks, as the tasks report them. A recording without a
    line, track or date belongs to no site."""

    def __init__(self) -> None:
        self._groups: dict = {}

    def add(self, run: dict) -> None:
        if run["error"] is None and run["line"] is not None and run["track"] is not None and run["date"] is not None:
            self._groups.setdefault((run["line"], run["track"]), []).append((run["date"], run["source"]))

    def __len__(self) -> int:
        return len(self._groups)

    def __iter__(self) -> Iterator[tuple[str, str, list[str], list[str]]]:
        """(line, track, sources, dates), the sources in date order (then by name)."""
        for (line, track), surveys in sorted(self._groups.items()):
            surveys = sorted(surveys)
            yield line, track, [s for _, s in surveys], [d for d, _ in surveys]


def trend_one(line: str, track: str, urls: list[str], dates: list[str], options: dict) -> dict:
    """One site's trend: its rows and its ``trends`` row as tables, or the
    row with the error (the line ``cms-host trend`` prints, or why the
    site has no trend)."""
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
            tr = cms.trend(paths, dates=dates, **_with_register(options, tmp))
        t = tr.table
        n = t.num_rows
        for k in SITE_KEYS:
            t = t.append_column(pa.field(k, pa.string(), False), pa.array([row[k]] * n, pa.string()))
        out["trend"] = t
        row["blocks"] = len({(s, e) for s, e in zip(t["start_chainage_mm"].to_pylist(), t["end_chainage_mm"].to_pylist())})
    except (cms.Error, OSError) as e:
        # A copy's path in the message named as the job names the recording: its URL.
        msg = str(e)
        for p, u in copies.items():
            msg = msg.replace(p, u)
        row["error"] = msg if isinstance(e, cms.Error) else f"{line} / {track}: {msg}"
    row["seconds"] = time.perf_counter() - t0
    out["trends"] = pa.Table.from_pylist([row], schema=TRENDS_SCHEMA)
    return out


def trend_task(line: str, track: str, urls: list[str], dates: list[str], stage: str, task: int, options: dict) -> dict:
    """One site's trend on a worker, its tables written by the worker into
    ``stage``: back go the files and the site's error (``None``: followed)."""
    out = trend_one(line, track, urls, dates, options)
    files = store.write_tables(stage, out, f"{task:06d}")
    return {"files": files, "site": {"line": line, "track": track, "error": out["trends"]["error"][0].as_py()}}


def _local_copy_as(url: str, tmp: str, i: int) -> str:
    """A URL's recording copied to its own folder of ``tmp`` (two surveys
    of a site may share a file name)."""
    d = os.path.join(tmp, str(i))
    os.makedirs(d)
    return _local_copy(url, d)


def bounded(client, fn: Callable, argsets: Iterable[tuple], in_flight: int) -> Iterator:
    """``fn(*args)`` of every ``args`` on the Dask ``client``, at most
    ``in_flight`` tasks submitted at once: each result is yielded as it
    comes (in any order) and its future released, so neither the client
    nor the scheduler ever holds more than ``in_flight`` of them."""
    from dask.distributed import as_completed

    todo = iter(argsets)
    running = as_completed()
    for args in todo:
        running.add(client.submit(fn, *args, pure=False))
        if running.count() >= in_flight:
            break
    for future in running:
        result = future.result()
        future.release()
        nxt = next(todo, None)
        if nxt is not None:
            running.add(client.submit(fn, *nxt, pure=False))
        yield result


class Manifest:
    """What the tasks sent back, gathered on the client: the files of each
    table with their row counts, the recordings that failed, the sites."""

    def __init__(self) -> None:
        self.files: dict = {name: [] for name in TABLES}
        self.recordings = 0
        self.measured_mm = 0.0
        self.failed: list[tuple[str, str]] = []
        self.sites = Sites()
        self.untrended: list[dict] = []
        self.trends = 0

    def add_files(self, files: dict) -> None:
        for name, fs in files.items():
            self.files[name].extend(fs)

    def add_runs(self, runs: list[dict]) -> None:
        for r in runs:
            self.recordings += 1
            self.measured_mm += r["measured_mm"] or 0.0
            if r["error"] is not None:
                self.failed.append((r["source"], r["error"]))
            self.sites.add(r)

    def rows(self, name: str) -> int:
        return sum(n for _, n in self.files[name])


def run(recordings: list[tuple[str, int]], client, options: dict, stage: str, workers: int, m: Manifest) -> None:
    """Analyses ``recordings`` on the Dask ``client``, the workers writing
    the tables into ``stage``; what they send back gathered into ``m``."""
    tasks = ((urls, stage, i, options) for i, urls in enumerate(batches(recordings, workers)))
    for r in bounded(client, analyse_task, tasks, TASKS_IN_FLIGHT_PER_WORKER * max(1, workers)):
        m.add_files(r["files"])
        m.add_runs(r["runs"])


def run_trends(client, options: dict, stage: str, workers: int, m: Manifest) -> None:
    """The trend of every site of ``m`` on the Dask ``client``, the workers
    writing the ``trend`` and ``trends`` tables into ``stage``."""
    topts = {k: options[k] for k in TREND_OPTIONS if k in options}
    tasks = ((line, track, urls, dates, stage, i, topts) for i, (line, track, urls, dates) in enumerate(m.sites))
    for r in bounded(client, trend_task, tasks, TASKS_IN_FLIGHT_PER_WORKER * max(1, workers)):
        m.add_files(r["files"])
        m.trends += 1
        if r["site"]["error"]:
            m.untrended.append(r["site"])


def _inside(a: str, b: str) -> bool:
    """Whether location ``a`` is ``b`` or under it (folders, or URLs)."""
    if store.is_url(a) or store.is_url(b):
        a, b = a.rstrip("/"), b.rstrip("/")
        return a == b or a.startswith(b + "/")
    a, b = os.path.realpath(a), os.path.realpath(b)
    return a == b or a.startswith(b + os.sep)


class ClusterError(Exception):
    """The Dask scheduler cannot be reached: its address and why."""


def client_for(workers: Optional[int], scheduler: Optional[str]):
    """A Dask client: of the scheduler at ``scheduler``, else of a
    LocalCluster of ``workers`` single-threaded processes."""
    from dask.distributed import Client, LocalCluster

    # The cluster's own lines (workers starting, closing) are not the job's output.
    logging.getLogger("distributed").setLevel(logging.WARNING)
    if scheduler:
        try:
            return Client(scheduler)
        except OSError as e:
            raise ClusterError(f"{scheduler}: {e}".replace("\n", " ")) from e
    cluster = LocalCluster(
        n_workers=workers or os.cpu_count() or 1,
        threads_per_worker=1,
        processes=True,
        dashboard_address=":0",
        silence_logs=logging.WARNING,
    )
    return Client(cluster)


def _job(a: argparse.Namespace, options: dict, target: store.Target) -> tuple[Manifest, dict]:
    """The job's two passes on the cluster, into ``target``'s staging."""
    recordings = list_recordings(a.input)
    m = Manifest()
    t0 = time.perf_counter()
    with client_for(a.workers, a.scheduler) as client:
        if a.scheduler is None:
            client.wait_for_workers(a.workers or os.cpu_count() or 1)
        workers = len(client.nthreads())
        stage = target.begin()
        # Other runs' staging found beside this one: what was removed, what was left and why.
        for note in target.notes:
            print(f"note: {note}", file=sys.stderr)
        t1 = time.perf_counter()
        run(recordings, client, options, stage, workers, m)
        t2 = time.perf_counter()
        run_trends(client, options, stage, workers, m)
        t3 = time.perf_counter()
    about = {
        "schema": cms.SCHEMA_VERSION,
        "input": a.input,
        "recordings": m.recordings,
        "failed": len(m.failed),
        "km": round(m.measured_mm / 1e6, 6),
        "options": options,
        "workers": workers,
        "cluster_start_s": round(t1 - t0, 3),
        "analysis_s": round(t2 - t1, 3),
        "sites": m.trends,
        "trends_failed": len(m.untrended),
        "trend_s": round(t3 - t2, 3),
        "rows": {name: m.rows(name) for name in TABLES},
        "files": m.files,
    }
    return m, about


def main(argv: Optional[list[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="python -m cms.fleet.job", description=__doc__.split("\n\n")[1])
    p.add_argument("input", metavar="INPUT", help="a folder or fsspec URL holding *.cmsrec recordings")
    p.add_argument("output", metavar="OUTPUT", help="the dataset to write (a folder or a bucket URL; replaced whole)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, help="LocalCluster worker processes (default: one per CPU)")
    g.add_argument("--scheduler", metavar="ADDRESS", help="a Dask scheduler (tcp://host:8786) instead of a LocalCluster")
    p.add_argument("--edition", default="2006", choices=["2006", "2012"])
    p.add_argument("--block-m", type=float, default=50.0)
    p.add_argument("--dx-mm", type=float)
    p.add_argument("--segment-mm", type=float, default=1000.0)
    p.add_argument(
        "--track-register",
        metavar="REGISTER",
        help="a track register (CSV, a path or URL the workers can read): runs with GNSS fixes placed by them (as analyze --track-register)",
    )
    a = p.parse_args(argv)
    if a.workers is not None and a.workers < 1:
        p.error(f"--workers {a.workers}: at least 1")
    options = {"edition": a.edition, "block_m": a.block_m, "dx_mm": a.dx_mm, "segment_mm": a.segment_mm}
    if a.track_register is not None:
        if "://" not in a.track_register and not os.path.isfile(a.track_register):
            print(f"error: --track-register {a.track_register}: no such file", file=sys.stderr)
            return 2
        options["track_register"] = a.track_register
    target = None
    try:
        if _inside(a.output, a.input) or _inside(a.input, a.output):
            raise cms.Error(f"{a.output}: inside the input {a.input} (or holding it); write the dataset elsewhere")
        target = store.Target(a.output)
        target.check()
        m, about = _job(a, options, target)
        target.publish(about)
    except (cms.Error, store.StoreError) as e:
        if target is not None:
            target.discard()
        print(f"error: {e}", file=sys.stderr)
        # Bad input or output: 2; the dataset's location failing mid-way: 1.
        return 1 if isinstance(e, store.StoreError) and not isinstance(e, store.Refused) else 2
    except ClusterError as e:
        print(f"error: {e}", file=sys.stderr)
        return 3
    except BaseException:
        if target is not None:
            target.discard()
        raise
    for _, e in m.failed:
        print(f"error: {e}", file=sys.stderr)
    # A site without a trend is data, not a failure of the job: named, and in `trends`.
    for r in m.untrended:
        print(f"note: no trend for {r['line']} / {r['track']}: {r['error']}", file=sys.stderr)
    secs = about["analysis_s"]
    print(
        f"{a.output}: {m.recordings} recordings ({len(m.failed)} failed), {about['km']:.3f} km, "
        f"on {about['workers']} workers in {secs:.2f} s "
        f"({m.recordings / secs:.1f} recordings/s; cluster start {about['cluster_start_s']:.1f} s); "
        f"{about['sites']} sites, {about['sites'] - len(m.untrended)} with a trend, in {about['trend_s']:.2f} s"
    )
    return 1 if m.failed else 0


if __name__ == "__main__":
    sys.exit(main())
