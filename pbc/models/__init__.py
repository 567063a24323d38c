"""Decoders (CNN and fully connected) that map a pose to cloth images or per-vertex values."""
