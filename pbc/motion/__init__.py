"""Motion in, sequences out: BVH clips -> the body's poses (bvh.py, retarget.py), poses against the training
range (ranges.py), and per-frame meshes, a video and an animated GLB (writers.py). Between the models and
pbc.predict in the data flow (docs/architecture.md)."""
