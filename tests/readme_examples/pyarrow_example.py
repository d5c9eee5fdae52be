# pyarrow.dataset: filter on the identifier columns, then x as an (N, 66) float32 array without copying
import pyarrow.compute as pc
import pyarrow.dataset as ds

data = ds.dataset("out/datasets/gaze_rnn", format="parquet", partitioning="hive",
                  ignore_prefixes=[".", "_", "dataset.json"])
table = data.to_table(filter=(pc.field("split") == "train") & (pc.field("pose") == "standing"))
x = table.column("x").combine_chunks()
x = x.flatten().to_numpy().reshape(len(x), -1)
print(x.shape, x.dtype)
