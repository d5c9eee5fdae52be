# pyarrow.dataset: filter on the identifier columns, then x as an (N, 66) float32 array without copying
import json

import pyarrow.compute as pc
import pyarrow.dataset as ds

data = ds.dataset("out/datasets/gaze_rnn")
table = data.to_table(filter=(pc.field("split") == "train") & (pc.field("pose") == "standing"))
x = table.column("x").combine_chunks()
x = x.flatten().to_numpy().reshape(len(x), -1)
names = json.loads(data.schema.field("x").metadata[b"gazepipe.elements"])   # what each of the 66 values is
print(x.shape, x.dtype, names[:4])     # ... ['target_dir.x', 'target_dir.y', 'target_dir.z', 'pelvis.fwd.x']
