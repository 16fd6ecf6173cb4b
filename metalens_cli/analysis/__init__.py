"""Closed-form and numerical analyses: symmetry, bands, MTF (no torch at import)."""
