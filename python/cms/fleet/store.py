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

The manifest ``_cms_fleet.json`` is the dataset's marker too: an existing
OUTPUT without one is not the job's and is never replaced.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import tempfile
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
    "runs": ("line", "track", "year"),
    "trend": ("line", "track"),
    "trends": ("line", "track"),
}
_KEY_TYPES = {"line": pa.string(), "track": pa.string(), "year": pa.int32()}


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


class Target:
    """The dataset a run of the job writes: checked, staged, then
    published whole or discarded."""

    def __init__(self, output: str):
        self.output = output
        self.remote = is_url(output)
        self.stage: Optional[str] = None
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
                # This run's own staged files do not make the prefix someone else's.
                staged = _join(self._path, self._version) if self.stage else None
                entries = [e for e in self._fs.ls(self._path) if e.rstrip("/") != staged] if self._fs.exists(self._path) else []
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
        """Makes the staging location; its path or URL, for the workers."""
        self.check()
        if self.remote:
            version = f"v-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}-{secrets.token_hex(4)}"
            self.stage = self._fs.unstrip_protocol(_join(self._path, version))
            self._version = version
        else:
            parent = os.path.dirname(self._path)
            try:
                os.makedirs(parent, exist_ok=True)
                self.stage = tempfile.mkdtemp(prefix=".cms-fleet-", dir=parent)
            except OSError as e:
                raise StoreError(f"{self.output}: cannot stage beside it: {e}") from e
        return self.stage

    def publish(self, manifest: dict) -> None:
        """Swaps the staged data into place with ``manifest`` (to which
        the data's location is added) as the dataset's manifest."""
        assert self.stage is not None, "begin() first"
        self.check()
        try:
            if self.remote:
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
        key = _join(self._path, MANIFEST)
        try:
            previous = json.loads(self._fs.cat_file(key)).get("data")
        except FileNotFoundError:
            previous = None
        # One PUT: readers get the old manifest or this one, whole.
        self._fs.pipe_file(key, json.dumps({**manifest, "data": self._version}, indent=1).encode())
        if previous and previous not in (".", self._version):
            try:
                self._fs.rm(_join(self._path, previous), recursive=True)
            except FileNotFoundError:
                pass

    def discard(self) -> None:
        """Removes what a run that is not published left staged."""
        if self.stage is None:
            return
        if self.remote:
            try:
                self._fs.rm(_join(self._path, self._version), recursive=True)
            except (FileNotFoundError, OSError):
                pass
        else:
            shutil.rmtree(self.stage, ignore_errors=True)
        self.stage = None
