# Closed-loop gaze animation, after `gazepipe train gaze_rnn --data out/datasets/gaze_rnn --out models/gaze_rnn`
import numpy as np

from gazepipe.datasets import open_dataset
from gazepipe.trainers.gaze_rnn import GazeRNNPredictor, angle_errors_deg

rnn = GazeRNNPredictor.load("models/gaze_rnn")     # device="cuda" runs it on a GPU
val = open_dataset("out/datasets/gaze_rnn").windows("val", normalise=False)   # 120-frame windows, stored units
x, y = val.x, val.y                                # (n, 120, 66) and (n, 120, 63)
out = rnn.rollout(start_pose=x[:, 0, 3:], target_dirs=x[:, :, :3])   # each window from its first previous pose
print(out.segments[-1], out.quat.shape, out.eye_dir.shape)   # head (n, 120, 10, 4) w, x, y, z and (n, 120, 3)
seg, eyes = angle_errors_deg(out.y, y, len(out.segments), rnn.has_eyes)   # degrees, (n, 120, 10) and (n, 120)
degrees = np.mean(np.concatenate([seg, eyes[..., None]], axis=-1))   # the trainer's validation closed_loop_deg
mse = np.mean(((out.y - y) / rnn.y_std) ** 2)      # the training loss's figure: validation mse.closed_loop
