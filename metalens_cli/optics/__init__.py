"""Optics: lens, source, propagators, sensor PSF and spectra (torch, SI units)."""
