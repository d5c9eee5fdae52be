# polars and DuckDB: the Parquet files by a glob (polars refuses a folder that holds other files)
import duckdb
import polars as pl

df = pl.read_parquet("out/datasets/gaze_rnn/**/*.parquet")
per_split = duckdb.sql("SELECT split, count(*) AS rows FROM read_parquet('out/datasets/gaze_rnn/**/*.parquet') "
                       "GROUP BY split ORDER BY split").fetchall()
print(df.shape, per_split)
