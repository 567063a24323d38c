"""Shared test helpers: synthetic garments and skinners (seconds, no draping) and a RunIf-style skip."""
