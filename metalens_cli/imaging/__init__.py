"""Imaging: from a design's PSFs to captures of scenes, and how good those captures are.

A capture (``formation``) is a clean scene on a ``canvas`` blurred by the far PSF, an
obstruction (``obstructions``) blurred by the near PSF over it, and the camera's light and
noise (``camera``). The modules, by what a reader looks for:

- PSFs a capture needs: ``channel_psfs`` (R, G, B at a near and a far depth, on axis),
  ``field_psfs`` (over the field of a radial design), ``psf_scan`` (PSF cubes for ``psf-scan``).
- Formation: ``canvas``, ``formation`` (on axis), ``field_formation`` (space-variant),
  ``obstructions`` with ``noise`` (Perlin), ``camera`` (light levels, shot and read noise),
  ``pipeline`` (design → captures) and ``simulation_output`` (what ``simulate`` writes).
- Scenes: ``images`` (photographs, sRGB ↔ linear), ``dead_leaves`` (ISO 19567-2 charts),
  ``scene_statistics`` (what tells a photograph from a synthetic scene).
- Scores: ``metrics`` (PSNR, SSIM, the photometric match), ``lpips``, ``evaluation`` (the
  metric table with statistics), ``obstruction_error`` (the added error taken apart),
  ``wiener`` (the oracle linear back end).
- Restoration: ``network`` (the U-Net), ``restore`` (applying it), ``export`` (``torch.export``).
- The lab loop: ``registration`` (a capture onto its reference) and ``captured_pairs``
  (``evaluate --pairs``).
"""
