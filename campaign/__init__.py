"""Monte Carlo campaign service: plan, run on dask, store in Parquet, tables, sweeps, reports."""
