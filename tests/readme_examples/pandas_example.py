# pandas: the whole dataset as a DataFrame (x and y hold one array per row)
import pandas as pd
import pyarrow.parquet as pq

root = "out/datasets/gaze_rnn"
df = pd.read_parquet(root, schema=pq.read_schema(f"{root}/_common_metadata"),
                     ignore_prefixes=[".", "_", "dataset.json"])
train = df[(df["split"] == "train") & ~df["mirrored"]]
print(train.groupby(["subject", "pose", "take"]).size())
