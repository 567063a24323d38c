"""Stitching the cage's P patch predictions (28 on the T-shirt) into one garment and removing the seams."""
