"""The rail corrugation host library's analysis, for Python.

``cms.analyze`` reads recordings (or one profile file) and analyses them
exactly as ``cms-host analyze`` does — the same library code — returning
the tables of ``cms-host analyze --parquet`` as ``pyarrow.Table`` objects
and the object of ``cms-host analyze --json`` as a dict. ``cms.read_survey``
gives a recording's survey block (line, track, date, chainage…).
``cms.trend`` follows surveys of one site at different dates as
``cms-host trend`` does: per block and band the growth per year and the
projected date the limit is crossed, as a ``pyarrow.Table`` and the
``cms-host trend --json`` object.

Zero-copy: the Rust side writes every Arrow buffer (values, validity
bitmaps, string offsets and bytes) once, straight into Python ``bytes``
objects; here they are wrapped as Arrow buffers (``pa.py_buffer``) without
a copy. The ``source`` column of the profile (one string on every sample)
is a dictionary of one value.
"""

from __future__ import annotations

import json
import os
from typing import Optional, Sequence, Union

import pyarrow as pa

from . import _cms
from ._cms import SCHEMA_VERSION, Error

__all__ = ["Analysis", "Error", "SCHEMA_VERSION", "Trend", "analyze", "read_survey", "trend"]

PathLike = Union[str, "os.PathLike[str]"]


class Analysis:
    """One ``analyze`` call's result.

    ``profile``, ``blocks``, ``zones``, ``third_octaves``: the
    ``pyarrow.Table`` of each export (docs/exports.md, the schema
    ``SCHEMA_VERSION``; ``profile`` ``None`` when ``analyze`` was asked to
    leave it out; ``third_octaves`` is ``third_octaves.parquet``: each
    block's ISO 3095 third octaves, of each line and of their energy
    average); ``summary``: the ``--json`` object. ``tables`` holds the
    four by name.
    """

    __slots__ = ("profile", "blocks", "zones", "third_octaves", "summary")

    def __init__(
        self, profile: Optional[pa.Table], blocks: pa.Table, zones: pa.Table, third_octaves: pa.Table, summary: dict
    ):
        self.profile = profile
        self.blocks = blocks
        self.zones = zones
        self.third_octaves = third_octaves
        self.summary = summary

    @property
    def tables(self) -> dict:
        return {"profile": self.profile, "blocks": self.blocks, "zones": self.zones, "third_octaves": self.third_octaves}

    def __repr__(self) -> str:
        rows = ", ".join(f"{k} {t.num_rows} rows" for k, t in self.tables.items() if t is not None)
        return f"<cms.Analysis {rows}>"


_TYPES = {"f64": pa.float64(), "i32": pa.int32(), "bool": pa.bool_(), "str": pa.string(), "date32": pa.date32()}


def _array(kind: str, rows: int, nulls: int, buffers: list) -> pa.Array:
    if kind == "repeat":
        # A dictionary of the one value; its int32 indices all zero.
        indices = pa.Array.from_buffers(pa.int32(), rows, [None, pa.py_buffer(bytes(4 * rows))])
        return pa.DictionaryArray.from_arrays(indices, pa.array([bytes(buffers[0]).decode()], pa.string()))
    wrapped = [None if b is None else pa.py_buffer(b) for b in buffers]
    if kind == "list_f64":
        values = pa.Array.from_buffers(pa.float64(), len(buffers[2]) // 8, [None, wrapped[2]])
        return pa.Array.from_buffers(pa.list_(pa.float64()), rows, wrapped[:2], null_count=nulls, children=[values])
    return pa.Array.from_buffers(_TYPES[kind], rows, wrapped, null_count=nulls)


def _table(columns: list) -> pa.Table:
    arrays, fields = [], []
    for name, kind, nullable, rows, nulls, buffers in columns:
        a = _array(kind, rows, nulls, buffers)
        arrays.append(a)
        fields.append(pa.field(name, a.type, nullable=nullable))
    meta = {b"cms.schema": SCHEMA_VERSION.encode()}
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata=meta))


def analyze(
    paths: Union[PathLike, Sequence[PathLike]],
    chainage: Optional[Sequence[str]] = None,
    edition: str = "2006",
    block_m: float = 50.0,
    search_m: float = 25.0,
    dx_mm: Optional[float] = None,
    direction: Optional[str] = None,
    register: Optional[str] = None,
    segment_mm: float = 1000.0,
    spike_removal: bool = True,
    curvature: bool = True,
    calibration: Optional[PathLike] = None,
    allow_repeated_runs: bool = False,
    allow_mixed_heads: bool = False,
    profile: bool = True,
    track_register: Optional[PathLike] = None,
) -> Analysis:
    """``cms-host analyze PATHS…`` with the same options (``--chainage``,
    ``--edition 2006|2012``, ``--block-m``, ``--search-m``, ``--dx-mm``,
    ``--direction auto|forward|reverse``, ``--register joint|joint-pitch|offset-tilt|offset|none``,
    ``--segment-mm``, ``--no-spike-removal``, ``--no-curvature``,
    ``--calibration``, ``--allow-repeated-runs``, ``--allow-mixed-heads``,
    ``--track-register``: the summary's ``gnss_placing`` says what placed
    each run).
    ``profile=False`` leaves the profile out (``None``): one row per sample
    of track, which a job over many long recordings has no use for.

    Raises ``cms.Error`` with the message ``cms-host analyze`` prints after
    ``error:``. The GIL is released while the recordings are analysed.
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    if isinstance(chainage, str):
        chainage = [chainage]
    profile, blocks, zones, third_octaves, summary = _cms.analyze(
        [os.fspath(p) for p in paths],
        chainage=None if chainage is None else list(chainage),
        edition=str(edition),
        block_m=float(block_m),
        search_m=float(search_m),
        dx_mm=None if dx_mm is None else float(dx_mm),
        direction=direction,
        register=register,
        segment_mm=float(segment_mm),
        spike_removal=bool(spike_removal),
        curvature=bool(curvature),
        calibration=None if calibration is None else os.fspath(calibration),
        allow_repeated_runs=bool(allow_repeated_runs),
        allow_mixed_heads=bool(allow_mixed_heads),
        profile=bool(profile),
        track_register=None if track_register is None else os.fspath(track_register),
    )
    return Analysis(
        None if profile is None else _table(profile), _table(blocks), _table(zones), _table(third_octaves), json.loads(summary)
    )


class Trend:
    """One ``trend`` call's result: ``table``, a ``pyarrow.Table`` of one
    row per block and band (docs/trend.md, "In Python"), and ``summary``,
    the ``cms-host trend --json`` object."""

    __slots__ = ("table", "summary")

    def __init__(self, table: pa.Table, summary: dict):
        self.table = table
        self.summary = summary

    def __repr__(self) -> str:
        return f"<cms.Trend {len(self.summary['surveys'])} surveys, {self.table.num_rows} rows>"


def trend(
    paths: Sequence[PathLike],
    dates: Optional[Sequence[str]] = None,
    chainage: Optional[Sequence[str]] = None,
    edition: str = "2006",
    block_m: float = 50.0,
    search_m: float = 2.0,
    horizon_years: float = 10.0,
    track_register: Optional[PathLike] = None,
) -> Trend:
    """``cms-host trend PATHS…`` with the same options (``--date
    YYYY-MM-DD`` and ``--chainage KM+M[:up|:down]``, one per recording in
    order; ``--edition 2006|2012``, ``--block-m``, ``--search-m``,
    ``--horizon-years``, ``--track-register``): each recording one survey
    of the site; with a track register, each survey's ``gnss_placing`` in
    the summary says what placed its runs.

    Raises ``cms.Error`` with the message ``cms-host trend`` prints after
    ``error:``. The GIL is released while the surveys are analysed.
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    if isinstance(dates, str):
        dates = [dates]
    if isinstance(chainage, str):
        chainage = [chainage]
    columns, summary = _cms.trend(
        [os.fspath(p) for p in paths],
        dates=None if dates is None else [str(d) for d in dates],
        chainage=None if chainage is None else list(chainage),
        edition=str(edition),
        block_m=float(block_m),
        search_m=float(search_m),
        horizon_years=float(horizon_years),
        track_register=None if track_register is None else os.fspath(track_register),
    )
    return Trend(_table(columns), json.loads(summary))


def read_survey(path: PathLike) -> Optional[dict]:
    """A recording's survey block as a dict (``line``, ``track``, ``rail``,
    ``start_chainage``, ``chainage``, ``date``, ``operator``,
    ``instrument``, ``notes``, and ``year`` from ``date``; a key not given
    is None), or None when the recording has none. Raises ``cms.Error``
    (a damaged block, a survey ``analyze`` would refuse)."""
    return json.loads(_cms.read_survey(os.fspath(path)))
