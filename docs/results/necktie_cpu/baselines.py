"""Mean-shape baseline and image floor of the necktie run, on its test split (root-frame offsets)."""
import json, sys
import numpy as np, torch
from pbc.predict import ClothPredictor
run = sys.argv[1]
pred = ClothPredictor.from_runs(run, None)
ds = pred.dataset
tr, te = ds.split("train"), ds.split("test")
def off(idx):
    p = torch.from_numpy(np.array(ds.poses[idx])).float(); v = torch.from_numpy(np.array(ds.verts[idx])).float()
    return p, v, *pred.offsets_of(p, v)
_, _, o_tr, _, _ = off(tr)
p, v, o, a, f = off(te)
from pbc.pixels.frames import from_offsets
err = lambda x: float((x - v).norm(dim=-1).mean() * 100)
mean = from_offsets(o_tr.mean(0, keepdim=True).expand_as(o), a, f, pred.space)
floor = from_offsets(pred.whole_target.values(pred.whole_target.encode(o)), a, f, pred.space)
model = pred(p)
print(json.dumps({"test_poses": len(te), "train_poses": len(tr), "mean_shape_cm": round(err(mean), 4),
                  "image_floor_cm": round(err(floor), 6), "model_cm": round(err(model), 4)}))
