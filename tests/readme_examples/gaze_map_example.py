# A parametric gaze map, after `gazepipe train gaze_map --data out/datasets/gaze_map --out models/gaze_map`
from gazepipe.trainers.gaze_map import GazeMap

gmap = GazeMap.load("models/gaze_map")
motion = gmap.motion(yaw_deg=30.0, pitch_deg=10.0)   # blend of the nearest examples in (yaw, pitch)
t, q = motion.curve(fps=30)     # seconds (T,); displacement quaternions w, x, y, z (T, segments + eyes, 4)
print(motion.names[-2:], round(motion.duration_s, 3), q.shape)
