"""A fleet's recordings analysed in parallel on Dask into one
hive-partitioned Parquet dataset (``cms.fleet.job``), and example DuckDB
queries over it (``cms.fleet.queries``). docs/fleet.md describes both."""
