# PyTorch: 120-frame windows of (x, y), normalised with the training statistics, in a DataLoader
import torch

from gazepipe.datasets import open_dataset

ds = open_dataset("out/datasets/gaze_rnn")
loader = torch.utils.data.DataLoader(ds.to_torch("train"), batch_size=64, shuffle=True,
                                     generator=torch.Generator().manual_seed(0))
x, y = next(iter(loader))
print(x.shape, y.shape)     # on the sample: torch.Size([60, 120, 66]) torch.Size([60, 120, 63])
#                             (its 60 training windows make one short batch; larger sets give batches of 64)
