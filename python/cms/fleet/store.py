"""Where a fleet dataset lives, how its workers write it, and how it is
swapped into place.

A dataset is a folder — local, or shared by the client and the workers at
the same path — or a prefix of a bucket named by an fsspec URL
(``s3://bucket/fleets/2026``, with the filesystem's package installed and
its credentials in the environment of the client and of every worker).
Either way the workers write their own partition files into a staging
location and the client, holding only their paths and row counts,
publishes the dataset whole:

- **a folder**: staged in a hidden sibling folder (``.cms-fleet-…``, on
  the same filesystem), then renamed into place: the folder holds the old
  dataset or the new one, never a mix.
- **a bucket**: objects cannot be renamed, so each run's files go under a
  prefix of their own, ``OUTPUT/v-<UTC time>-<random>/``, and the run is
  published by one write of ``OUTPUT/_cms_fleet.json`` naming that prefix
  and every file in it. An object store replaces an object whole, so a
  reader that reads the manifest first and then only the files it names
  sees the old dataset or the new one, never a mix, and never the files
  of a run still writing or of one that failed. The previous run's prefix
  is deleted after the new manifest is written: a reader still reading
  the old files at that moment can find them gone (read again).

A bucket run's staging prefix holds a **lease**, ``_cms_fleet_lease.json``,
written before any data and renewed by the client every
``LEASE_RENEW_S`` while the run lives: who runs it (host, process, and on
Linux the kernel's boot and pid namespace with the process's start time).
A run that starts sweeps OUTPUT's other staging prefixes: one is a dead
run's, removed and named, when its client is a process of this machine
that is gone, or when its lease has not been renewed for
``LEASE_STALE_S`` by the store's own clock (the objects' times, not the
machines'); a prefix without a lease counts from its newest object. Any
other is a run still writing: left alone, and named. The prefix the
manifest names is never touched, and a run publishes only when every file
it staged is still there (a run judged dead that was only paused fails
instead of publishing a part).

The manifest ``_cms_fleet.json`` is the dataset's marker too: an existing
OUTPUT without one (staging prefixes aside) is not the job's and is never
replaced.
"""

from __future__ import annotations

import datetime
import json
import os
import re
import secrets
import shutil
import socket
import tempfile
import threading
import time
from typing import Optional

import pyarrow as pa
import pyarrow.dataset as ds

#: The manifest: what was analysed, with which options; where the data is and its files.
MANIFEST = "_cms_fleet.json"
#: Each table's partition keys (a site's trend spans years).
PARTITIONS = {
    "blocks": ("line", "track", "year"),
    "zones": ("line", "track", "year"),
    "third_octaves": ("line", "track", "year"),
    "runs": ("line", "track", "year"),
    "trend": ("line", "track"),
    "trends": ("line", "track"),
}
_KEY_TYPES = {"line": pa.string(), "track": pa.string(), "year": pa.int32()}
#: A bucket run's lease, in its staging prefix.
LEASE = "_cms_fleet_lease.json"
#: How often a running job renews its lease, s.
LEASE_RENEW_S = 30.0
#: A lease not renewed for this long is a dead run's, s (twenty renewals
#: missed: a client paused or cut off that long has lost its staging).
LEASE_STALE_S = 600.0
#: The name of a run's staging prefix: ``v-<UTC time>-<8 hex digits>``.
STAGING = re.compile(r"^v-\d{8}T\d{6}Z-[0-9a-f]{8}$")


class StoreError(Exception):
    """The dataset's location cannot be written or read: one line naming
    it and why."""


class Refused(StoreError):
    """A location that cannot be used as given: a bad output, not a
    failure on the way."""


class NotADataset(Refused):
    """An existing OUTPUT that is not a dataset of the job (never replaced)."""


def is_url(location: str) -> bool:
    """Whether ``location`` names a filesystem other than the local one
    (``file://`` URLs are local folders)."""
    return "://" in location and not location.startswith("file://")


def _local(location: str) -> str:
    return os.path.abspath(location[len("file://") :] if location.startswith("file://") else location)


def _fs(url: str):
    import fsspec

    try:
        return fsspec.core.url_to_fs(url)
    except (ImportError, ValueError) as e:
        raise Refused(f"{url}: {e}".replace("\n", " ")) from e


def _join(base: str, rel: str) -> str:
    return base.rstrip("/") + "/" + rel


def write_tables(stage: str, tables: dict, task: str) -> dict:
    """Writes each table of ``tables`` (name → ``pa.Table``, with its
    partition keys as columns) hive-partitioned under ``stage``/NAME, one
    file per partition named after ``task`` (a task run again writes the
    same names over its first try's). Returns NAME → [[path relative to
    ``stage``, rows], …]. Runs on a worker."""
    if is_url(stage):
        from pyarrow.fs import FSSpecHandler, PyFileSystem

        fs, base = _fs(stage)
        filesystem = PyFileSystem(FSSpecHandler(fs))
    else:
        filesystem, base = None, _local(stage)
    base = base.rstrip("/")
    if filesystem is not None:
        # A run given up as dead has lost its lease with its staging: its
        # tasks still running write nothing more there.
        fs.invalidate_cache(base)
        if not fs.exists(_join(base, LEASE)):
            raise StoreError(f"{stage}: its lease is gone (the run was given up as dead and its staging removed); nothing written")
    files: dict = {}
    for name, t in tables.items():
        if t is None or t.num_rows == 0:
            continue
        part = ds.partitioning(pa.schema([pa.field(k, _KEY_TYPES[k]) for k in PARTITIONS[name]]), flavor="hive")
        written: list = []
        try:
            ds.write_dataset(
                t,
                f"{base}/{name}",
                format="parquet",
                filesystem=filesystem,
                partitioning=part,
                basename_template=f"{name}-{task}-{{i}}.parquet",
                existing_data_behavior="overwrite_or_ignore",
                file_visitor=lambda f: written.append([f.path, f.metadata.num_rows]),
            )
        except (OSError, pa.ArrowException) as e:
            raise StoreError(f"{stage}: cannot write {name}: {e}".replace("\n", " ")) from e
        files[name] = [[os.path.relpath(p, base) if filesystem is None else p[len(base) + 1 :], n] for p, n in written]
    return files


def read_manifest(dataset: str) -> dict:
    """The manifest of the dataset at ``dataset``; ``StoreError`` when it
    is not a dataset of the job."""
    where = os.path.join(_local(dataset), MANIFEST) if not is_url(dataset) else None
    try:
        if where:
            with open(where) as f:
                return json.load(f)
        fs, path = _fs(dataset)
        return json.loads(fs.cat_file(_join(path, MANIFEST)))
    except FileNotFoundError:
        raise NotADataset(f"{dataset}: not a dataset of cms.fleet.job (no {MANIFEST})") from None
    except (OSError, ValueError) as e:
        raise StoreError(f"{dataset}/{MANIFEST}: {e}") from e


def data_root(dataset: str, manifest: Optional[dict] = None) -> str:
    """Where the published data of ``dataset`` is: the folder itself, or
    the bucket prefix its manifest names."""
    m = manifest if manifest is not None else read_manifest(dataset)
    data = m.get("data", ".")
    return dataset.rstrip("/") if data == "." else _join(dataset, data)


def table_files(dataset: str, name: str, manifest: Optional[dict] = None) -> list[str]:
    """The files of table ``name`` as the manifest lists them (paths or
    URLs)."""
    m = manifest if manifest is not None else read_manifest(dataset)
    root = data_root(dataset, m)
    if is_url(root):
        return [_join(root, rel) for rel, _ in m.get("files", {}).get(name, [])]
    return [os.path.join(_local(root), rel) for rel, _ in m.get("files", {}).get(name, [])]


def open_table(dataset: str, name: str) -> Optional[ds.Dataset]:
    """Table ``name`` of ``dataset`` read through its manifest, with its
    partition keys as columns; ``None`` when it has no rows."""
    m = read_manifest(dataset)
    root = data_root(dataset, m)
    part = ds.partitioning(pa.schema([pa.field(k, _KEY_TYPES[k]) for k in PARTITIONS[name]]), flavor="hive")
    if "files" not in m and not is_url(root):
        # A folder whose manifest predates the file lists: the folder is the dataset, whole.
        return ds.dataset(os.path.join(_local(root), name), format="parquet", partitioning=part)
    files = table_files(dataset, name, m)
    if not files:
        return None
    if is_url(root):
        from pyarrow.fs import FSSpecHandler, PyFileSystem

        fs, base = _fs(root)
        paths = [_fs(f)[1] for f in files]
        return ds.dataset(paths, filesystem=PyFileSystem(FSSpecHandler(fs)), format="parquet", partitioning=part, partition_base_dir=f"{base}/{name}")
    return ds.dataset(files, format="parquet", partitioning=part, partition_base_dir=os.path.join(_local(root), name))


def _start_ticks(pid: int) -> Optional[int]:
    """When process ``pid`` of this machine started (clock ticks since
    boot), or ``None`` when there is no such process running (a zombie is
    none)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    # After the command: the state (field 3), ..., the start time (field 22).
    return None if fields[0] in ("Z", "X") else int(fields[19])


def identity() -> Optional[dict]:
    """This process as a lease names it so that another process of the
    same machine can tell whether it still runs: the kernel's boot, the
    pid namespace, the pid and its start time (Linux); ``None`` where
    ``/proc`` does not tell."""
    try:
        with open("/proc/sys/kernel/random/boot_id") as f:
            boot = f.read().strip()
        ns = os.stat("/proc/self/ns/pid").st_ino
    except OSError:
        return None
    start = _start_ticks(os.getpid())
    return None if start is None else {"boot_id": boot, "pid_ns": ns, "pid": os.getpid(), "start": start}


def judge(lease: Optional[dict], since: datetime.datetime, now: datetime.datetime, here: Optional[dict], stale_s: float = LEASE_STALE_S) -> tuple[bool, str]:
    """Whether a staging prefix is a dead run's, and why (or why not).
    ``lease``: its lease (``None``: it has none); ``since``: when the lease
    was last written, or without one the prefix's newest object; ``now``:
    the store's time (its newest write, the caller's own lease); ``here``:
    this process's ``identity()``."""
    age = (now - since).total_seconds()
    if lease is None:
        if age > stale_s:
            return True, f"it has no lease and its newest object is {age:.0f} s old"
        return False, f"it has no lease and its newest object is {age:.0f} s old (removed once {stale_s:.0f} s old)"
    who = lease.get("identity") or {}
    client = f"its client, pid {lease.get('pid')} on {lease.get('host')}"
    if here and who.get("boot_id") == here["boot_id"] and who.get("pid_ns") == here["pid_ns"]:
        if _start_ticks(int(who.get("pid", 0))) != who.get("start"):
            return True, f"{client}, is gone"
        return False, f"{client}, is running"
    if age > stale_s:
        return True, f"{client}, last renewed its lease {age:.0f} s ago (a lease is stale after {stale_s:.0f} s)"
    return False, f"{client}, renewed its lease {age:.0f} s ago (removed once not renewed for {stale_s:.0f} s)"


class Target:
    """The dataset a run of the job writes: checked, staged, then
    published whole or discarded. On a bucket, ``begin`` sweeps dead runs'
    staging and ``notes`` says what it removed or left."""

    def __init__(self, output: str, stale_s: float = LEASE_STALE_S):
        self.output = output
        self.remote = is_url(output)
        self.stage: Optional[str] = None
        self.stale_s = stale_s
        #: What ``begin`` found of other runs' staging: one line each.
        self.notes: list[str] = []
        self._renewing: Optional[threading.Thread] = None
        self._stop = threading.Event()
        if self.remote:
            self._fs, self._path = _fs(output)
            self._path = self._path.rstrip("/")
        else:
            self._path = _local(output)

    def check(self) -> None:
        """Refuses an existing OUTPUT that is not a dataset of the job."""
        if self.remote:
            try:
                self._fs.invalidate_cache()
                # Runs' staging (this one's, or others') does not make the prefix someone else's.
                entries = [e for e in self._fs.ls(self._path) if not STAGING.match(e.rstrip("/").rsplit("/", 1)[-1])] if self._fs.exists(self._path) else []
                exists = bool(entries)
                ours = self._fs.isfile(_join(self._path, MANIFEST))
            except OSError as e:
                raise StoreError(f"{self.output}: {e}") from e
        else:
            exists = os.path.lexists(self._path)
            ours = os.path.isdir(self._path) and os.path.isfile(os.path.join(self._path, MANIFEST))
        if exists and not ours:
            raise NotADataset(f"{self.output}: exists and is not a dataset of cms.fleet.job; give a new folder")

    def begin(self) -> str:
        """Makes the staging location; its path or URL, for the workers.
        On a bucket: writes this run's lease, keeps it renewed, and sweeps
        the staging of dead runs (``notes``)."""
        self.check()
        if self.remote:
            version = f"v-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}-{secrets.token_hex(4)}"
            self._version = version
            self._lease = _join(self._path, f"{version}/{LEASE}")
            about = {"job": version, "host": socket.gethostname(), "pid": os.getpid(), "identity": identity(), "started": _utc_now()}
            try:
                self._fs.pipe_file(self._lease, json.dumps(about).encode())
                self.stage = self._fs.unstrip_protocol(_join(self._path, version))
                self.notes = self._sweep()
            except OSError as e:
                raise StoreError(f"{self.output}: cannot stage: {e}") from e
            self._renewing = threading.Thread(target=self._renew, args=(about,), name="cms-fleet-lease", daemon=True)
            self._renewing.start()
        else:
            parent = os.path.dirname(self._path)
            try:
                os.makedirs(parent, exist_ok=True)
                self.stage = tempfile.mkdtemp(prefix=".cms-fleet-", dir=parent)
            except OSError as e:
                raise StoreError(f"{self.output}: cannot stage beside it: {e}") from e
        return self.stage

    def _renew(self, about: dict) -> None:
        """Writes the lease again every ``LEASE_RENEW_S`` until stopped, or
        until it is gone (a sweep judged the run dead: ``publish`` then
        finds its files gone and fails)."""
        while not self._stop.wait(LEASE_RENEW_S):
            try:
                self._fs.invalidate_cache(self._lease)
                if not self._fs.exists(self._lease):
                    return
                self._fs.pipe_file(self._lease, json.dumps({**about, "renewed": _utc_now()}).encode())
            except OSError:
                # The store out of reach for a while: the next turn tries again.
                continue

    def _stop_renewing(self) -> None:
        self._stop.set()
        if self._renewing is not None:
            self._renewing.join()
            self._renewing = None

    def _published(self) -> Optional[str]:
        """The prefix the dataset's manifest names now, if any."""
        try:
            return json.loads(self._fs.cat_file(_join(self._path, MANIFEST))).get("data")
        except FileNotFoundError:
            return None

    def _sweep(self) -> list[str]:
        """Removes the staging prefixes of dead runs (``judge``) beside
        this run's; one line per prefix removed or left."""
        self._fs.invalidate_cache()
        now = self._fs.info(self._lease)["LastModified"]
        published = self._published()
        notes = []
        here = identity()
        for entry in self._fs.ls(self._path, detail=True):
            name = entry["name"].rstrip("/").rsplit("/", 1)[-1]
            if entry["type"] != "directory" or not STAGING.match(name) or name in (self._version, published):
                continue
            prefix = _join(self._path, name)
            objects = self._fs.find(prefix, detail=True)
            if not objects:
                continue
            key = _join(prefix, LEASE)
            lease, since = None, max(o["LastModified"] for o in objects.values())
            if key in objects:
                try:
                    lease, since = json.loads(self._fs.cat_file(key)), objects[key]["LastModified"]
                except (FileNotFoundError, ValueError):
                    lease = None
            dead, why = judge(lease, since, now, here, self.stale_s)
            where = self._fs.unstrip_protocol(prefix)
            # Read again: a run that published this prefix meanwhile keeps it.
            if not dead or self._published() == name:
                notes.append(f"{where}/: {len(objects)} objects of another run left in place: {why}")
                continue
            self._fs.rm(prefix, recursive=True)
            notes.append(f"removed {where}/, {len(objects)} objects staged by a run that did not finish: {why}")
        return notes

    def publish(self, manifest: dict) -> None:
        """Swaps the staged data into place with ``manifest`` (to which
        the data's location is added) as the dataset's manifest."""
        assert self.stage is not None, "begin() first"
        self.check()
        try:
            if self.remote:
                self._stop_renewing()
                self._publish_bucket(manifest)
            else:
                self._publish_folder(manifest)
        except OSError as e:
            raise StoreError(f"{self.output}: cannot publish: {e}") from e
        self.stage = None

    def _publish_folder(self, manifest: dict) -> None:
        for name in PARTITIONS:
            os.makedirs(os.path.join(self.stage, name), exist_ok=True)
        with open(os.path.join(self.stage, MANIFEST), "w") as f:
            json.dump({**manifest, "data": "."}, f, indent=1)
        parent = os.path.dirname(self._path)
        old = None
        if os.path.lexists(self._path):
            old = tempfile.mkdtemp(prefix=".cms-fleet-old-", dir=parent)
            os.rename(self._path, os.path.join(old, "d"))
        os.rename(self.stage, self._path)
        if old:
            shutil.rmtree(old)

    def _publish_bucket(self, manifest: dict) -> None:
        prefix = _join(self._path, self._version)
        self._fs.invalidate_cache()
        staged = {p[len(prefix) + 1 :] for p in self._fs.find(prefix)}
        named = [rel for files in manifest.get("files", {}).values() for rel, _ in files]
        missing = [rel for rel in named if rel not in staged]
        if missing or LEASE not in staged:
            raise StoreError(
                f"{self.output}: {len(missing)} of the {len(named)} files staged under {self._version}/ are gone "
                f"(another run took this one for dead and removed its staging); nothing published"
            )
        key = _join(self._path, MANIFEST)
        previous = self._published()
        # One PUT: readers get the old manifest or this one, whole.
        self._fs.pipe_file(key, json.dumps({**manifest, "data": self._version}, indent=1).encode())
        if previous and previous not in (".", self._version):
            try:
                self._fs.rm(_join(self._path, previous), recursive=True)
            except FileNotFoundError:
                pass
        # The published prefix holds the manifest's files only.
        self._fs.rm(self._lease)

    def discard(self) -> None:
        """Removes what a run that is not published left staged."""
        if self.stage is None:
            return
        if self.remote:
            self._stop_renewing()
            try:
                self._fs.rm(_join(self._path, self._version), recursive=True)
            except (FileNotFoundError, OSError):
                pass
        else:
            shutil.rmtree(self.stage, ignore_errors=True)
        self.stage = None


def _utc_now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
