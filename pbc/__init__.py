"""pbc: pixel-based cloth.

Data flows one way: core (files) -> geometry -> sim -> pixels -> data -> models -> stitch -> motion ->
inference -> jobs -> cli (docs/architecture.md).
"""

__version__ = "0.1.0"
