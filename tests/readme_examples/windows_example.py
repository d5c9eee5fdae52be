# gazepipe.datasets: numpy windows cut inside segments (face_clean: 200-frame chunks, stride 50)
from gazepipe.datasets import open_dataset

ds = open_dataset("out/datasets/face_clean")
chunks = ds.windows("train", normalise=False)
print(len(chunks), "chunks;", chunks.dropped_rows, "rows in no chunk")
tracked, clean = chunks[0]          # (200, 52) each
mean, std = ds.mean_std("clean")    # training statistics from _dataset.json
