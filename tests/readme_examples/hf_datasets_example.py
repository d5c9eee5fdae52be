# Hugging Face datasets: the Parquet files as a datasets.Dataset with numpy rows
from datasets import load_dataset

files = "out/datasets/gaze_rnn/subject=*/pose=*/take=*.parquet"
hf = load_dataset("parquet", data_files={"rows": files}, split="rows")
train = hf.filter(lambda split: split == "train", input_columns="split")
train = train.with_format("numpy", columns=["x", "y"])
batch = train[:4]
print(len(train), batch["x"].shape, batch["y"].shape)
