"""Pose sampling and the physical drape of the garment on a posed body."""
