# pandas: the whole dataset as a DataFrame (x and y hold one array per row)
import pandas as pd

df = pd.read_parquet("out/datasets/gaze_rnn")
train = df[(df["split"] == "train") & ~df["mirrored"]]
print(train.groupby(["session", "take"]).size())
