# Hugging Face datasets: the folder as a DatasetDict with the train, validation and test splits
from datasets import load_dataset

hf = load_dataset("out/datasets/gaze_rnn")
train = hf["train"].with_format("numpy", columns=["x", "y"])
batch = train[:4]
print({name: split.num_rows for name, split in hf.items()}, batch["x"].shape, batch["y"].shape)
