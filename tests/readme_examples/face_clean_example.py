# Cleaning tracked blendshapes, after `gazepipe train face_clean --data out/datasets/face_clean --out models/face`
import numpy as np

from gazepipe.datasets import open_dataset
from gazepipe.trainers.face_clean import FaceCleaner

cleaner = FaceCleaner.load("models/face")
chunks = open_dataset("out/datasets/face_clean").windows("val", normalise=False,
                                                         columns=["tracked", "clean", "time_s"])
tracked, clean, t = chunks.stack("tracked"), chunks.stack("clean"), chunks.stack("time_s")[..., 0]
cleaned = cleaner.clean(tracked, t)    # (n, 200, 52) values and (n, 200) seconds; (T, 52) and (T,) for one take
rmse = np.sqrt(np.mean((cleaned[:, 1:] - clean[:, 1:]) ** 2))   # the trainer's validation cleaned_rmse
