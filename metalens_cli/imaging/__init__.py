"""Obstructions, image formation and image metrics."""
