"""Stitching 28 patch predictions into one garment and removing the seams."""
