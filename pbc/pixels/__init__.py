"""Cloth pixels: per-vertex offsets in local frames and the linear operators between vertices and cloth images."""
