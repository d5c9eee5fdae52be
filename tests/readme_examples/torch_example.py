# PyTorch: 120-frame windows of (x, y), normalised with the training statistics, in a DataLoader
import torch

from gazepipe.datasets import open_dataset

ds = open_dataset("out/datasets/gaze_rnn")
loader = torch.utils.data.DataLoader(ds.to_torch("train"), batch_size=64, shuffle=True,
                                     generator=torch.Generator().manual_seed(0))
x, y = next(iter(loader))
print(x.shape, y.shape)     # on the sample: torch.Size([64, 120, 66]) torch.Size([64, 120, 63])
#                             (a batch of 64 of its training windows; an epoch's last batch may be shorter)
