"""Optics: the physics core (torch and numpy, SI metres, reads no files).

- The lens: ``lens`` (θ map and its geometric phase), ``source`` (point sources on and off
  axis), ``window`` (the PSF window convention).
- Propagation: ``sampling`` (the PSF grid, sampling plans and the guard against aliasing),
  ``propagate`` (angular spectrum, Hankel, direct Rayleigh-Sommerfeld), ``sensor`` (intensity
  over square pixels).
- PSFs: ``psf`` (on axis, the entry point), ``field`` (off axis), ``blur`` (where the light
  lands: window sizes), ``channel_psf`` (R, G, B PSFs in windows sized by their light),
  ``zero_order`` (the unconverted light).
- The meta-atom: ``fin`` (the cell), ``nanofin`` (η(λ) by RCWA), ``fin_modes`` (fast RCWA by
  the fin's mirror symmetries), ``materials``.
- Spectra: ``spectra`` (channel sensitivities, wavelength sampling), ``band_rules`` and
  ``split_spectrum`` (a band filter's limits and the split-spectrum conditions).
"""
