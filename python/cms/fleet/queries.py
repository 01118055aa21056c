"""``python -m cms.fleet.queries DATASET``: example DuckDB queries over a
dataset of ``cms.fleet.job`` — the blocks by their ISO 3095 verdict
across the network (``iso3095_verdict``: of the lines' energy average),
the ISO 3095 third octaves whose rail exceeds the limit most often, the
worst sites, the reprofiling length per line, and the blocks that will
cross their limit soonest. Each is a plain SQL text (``QUERIES``) over ``read_parquet(…, hive_partitioning = true)``:
copy it into any DuckDB."""

from __future__ import annotations

import os
import re
import sys

import duckdb

from . import store

ISO3095_QUERY = "blocks by ISO 3095 verdict (within, EXCEEDS, not judged), per line and track"
THIRD_OCTAVE_QUERY = "ISO 3095 third octaves of the blocks (lines' energy average) by verdict, per line, track and wavelength"

QUERIES = {
    ISO3095_QUERY: """
        SELECT line, track, year,
               count(*) FILTER (WHERE iso3095_verdict = 'EXCEEDS') AS blocks_exceeding,
               count(*) FILTER (WHERE iso3095_verdict = 'not judged') AS blocks_not_judged,
               count(*) FILTER (WHERE iso3095_verdict = 'within') AS blocks_within,
               round(sum(end_chainage_mm - start_chainage_mm) FILTER (WHERE iso3095_verdict = 'EXCEEDS') / 1000, 1) AS exceeding_m,
               round(100.0 * count(*) FILTER (WHERE iso3095_verdict = 'EXCEEDS') / nullif(count(iso3095_verdict), 0), 1)
                   AS exceeding_percent
        FROM read_parquet('{d}/blocks/**/*.parquet', hive_partitioning = true, union_by_name = true)
        GROUP BY ALL ORDER BY blocks_exceeding DESC, blocks_not_judged DESC, line, track, year""",
    THIRD_OCTAVE_QUERY: """
        SELECT line, track, wavelength_mm, any_value(limit_db) AS limit_db,
               count(*) FILTER (WHERE verdict = 'EXCEEDS') AS exceeding,
               count(*) FILTER (WHERE verdict = 'not judged') AS not_judged,
               count(*) FILTER (WHERE verdict = 'within') AS within,
               round(max(rail_db), 1) AS worst_rail_db,
               round(max(rail_lo_db - limit_db) FILTER (WHERE verdict = 'EXCEEDS'), 1) AS worst_over_limit_db
        FROM read_parquet('{d}/third_octaves/**/*.parquet', hive_partitioning = true, union_by_name = true)
        WHERE laser IS NULL
        GROUP BY ALL ORDER BY exceeding DESC, not_judged DESC, line, track, wavelength_mm DESC""",
    "the worst sites (EN 13231-3 zones, by worst peak-to-peak over the band's limit)": """
        SELECT line, track, year, round(start_chainage_mm / 1000, 1) AS from_m, round(end_chainage_mm / 1000, 1) AS to_m,
               band_lo_mm || '-' || band_hi_mm AS band_mm,
               round(exceeding_mm / 1000, 2) AS exceeding_m,
               round(1000 * worst_pp_mm, 1) AS worst_pp_um,
               round(worst_pp_mm / limit_mm, 2) AS times_limit, source
        FROM read_parquet('{d}/zones/**/*.parquet', hive_partitioning = true)
        ORDER BY times_limit DESC, source LIMIT 10""",
    "reprofiling length per line (EN 13231-3 verdict of each run, summed)": """
        SELECT line, track,
               count(*) AS runs,
               round(sum(measured_mm) / 1000, 1) AS measured_m,
               round(sum(reprofile_mm) / 1000, 1) AS reprofile_m,
               round(100 * sum(reprofile_mm) / nullif(sum(measured_mm), 0), 1) AS reprofile_percent
        FROM read_parquet('{d}/runs/**/*.parquet', hive_partitioning = true)
        WHERE error IS NULL
        GROUP BY ALL ORDER BY reprofile_m DESC, line, track""",
    "the blocks that will cross their EN 13231-3 limit soonest (trend of each site)": """
        SELECT line, track, round(start_chainage_mm / 1000, 1) AS from_m, round(end_chainage_mm / 1000, 1) AS to_m,
               band_lo_mm || '-' || band_hi_mm AS band_mm,
               round(1000 * limit_mm, 1) AS limit_um,
               round(1000 * last_figure_mm, 1) AS last_um, last_date,
               round(1000 * growth_mm_per_year, 2) AS growth_um_per_year,
               round(1000 * u_growth_mm_per_year, 2) AS u_growth_um_per_year,
               crossing, crossing_date, crossing_earliest_date, crossing_latest_date
        FROM read_parquet('{d}/trend/**/*.parquet', hive_partitioning = true)
        WHERE crossing IN ('already_over', 'on')
        ORDER BY crossing <> 'already_over', crossing_date, line, track, start_chainage_mm
        LIMIT 10""",
}


def _table_of(sql: str) -> str:
    return re.search(r"\{d\}/(\w+)/", sql).group(1)


def _has_rows(dataset: str, manifest: dict, table: str) -> bool:
    """Whether ``table`` holds a row: a table the job wrote no row of (no
    site surveyed at two dates has no ``trend``) has no file, which
    DuckDB's ``read_parquet`` refuses. A dataset whose manifest predates
    the row counts is looked at."""
    rows = manifest.get("rows")
    if rows is not None:
        return rows.get(table, 0) > 0
    return any(f.endswith(".parquet") for _, _, files in os.walk(os.path.join(dataset, table)) for f in files)


def run(dataset: str) -> dict:
    """Each query's result as (column names, rows); ``([], [])`` when the
    table it reads holds no row. The dataset is read through its
    manifest: for a bucket, only under the prefix it names (the run
    published last), with the bucket's fsspec filesystem."""
    manifest = store.read_manifest(dataset)
    root = store.data_root(dataset, manifest)
    con = duckdb.connect()
    if store.is_url(root):
        import fsspec

        con.register_filesystem(fsspec.core.url_to_fs(root)[0])
    out = {}
    for title, sql in QUERIES.items():
        if not _has_rows(dataset, manifest, _table_of(sql)):
            out[title] = ([], [])
            continue
        cur = con.execute(sql.format(d=root.replace("'", "''")))
        out[title] = ([c[0] for c in cur.description], cur.fetchall())
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m cms.fleet.queries DATASET", file=sys.stderr)
        return 2
    try:
        results = run(argv[0])
    except (store.StoreError, duckdb.Error) as e:
        print(f"error: {e}".replace("\n", " "), file=sys.stderr)
        return 2
    for title, (cols, rows) in results.items():
        print(f"## {title}\n")
        if not cols:
            print("(no rows: the dataset holds none of this table)\n")
            continue
        print("| " + " | ".join(cols) + " |")
        print("|" + "---|" * len(cols))
        for r in rows:
            print("| " + " | ".join("" if v is None else str(v) for v in r) + " |")
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
