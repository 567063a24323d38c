"""Inference: trained runs -> garment meshes for any pose (``predictor``), and the poses asked for (``poses``)."""
