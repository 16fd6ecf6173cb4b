"""Units, presets, EXR and layout files."""
