"""The README's top figure: simulated vs predicted shirts of the poses a `pbc.predict --poses test` run wrote.

    python -m pbc.predict <whole run> --poses test --body --out <predict dir>
    python docs/figures/predicted_vs_simulated.py <predict dir> <dataset dir> docs/figures/predicted_vs_simulated.png
"""

import json
import sys
from pathlib import Path

import numpy as np
import torch

from pbc.data.dataset import load_dataset
from pbc.geometry.body.base import pose_body
from pbc.jobs.writers import contact_sheet


def main(pred_dir: str, data_dir: str, out: str) -> None:
    pred_dir = Path(pred_dir)
    meta = json.loads((pred_dir / "predict.json").read_text())
    ds = load_dataset(data_dir)
    pred, poses = np.load(pred_dir / "vertices.npy"), np.load(pred_dir / "poses.npy")
    rows = [int(n.split("_")[1]) for n in meta["names"]]  # test_00015 -> dataset row 15
    body = pose_body(ds.body, torch.from_numpy(poses).float()).numpy()
    verts, bodies, titles = [], [], []
    for k, err in enumerate(meta["per_pose_vertex_error_cm"]):
        verts += [np.asarray(ds.verts[rows[k]]), pred[k]]
        bodies += [body[k], body[k]]
        titles += [f"simulated (test pose {rows[k]})", f"predicted: {err:.2f} cm mean error"]
    contact_sheet(Path(out), ds.garment.faces, np.stack(verts), titles, np.stack(bodies), ds.body.faces)


if __name__ == "__main__":
    main(*sys.argv[1:4])
