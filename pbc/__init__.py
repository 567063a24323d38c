"""pbc: pixel-based cloth.

Data flows one way: geometry -> sim -> pixels -> data -> models -> stitch -> sweeps/report.
"""

__version__ = "0.1.0"
