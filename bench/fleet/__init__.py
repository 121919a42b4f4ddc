"""`bench fleet`: many logs replayed in parallel on Dask into one queryable Parquet output."""
