"""Analysis: SNR, EMVA-style noise, MTF, sharpness, polarisation fit (pure functions).

- ``camd.analysis.sensor_noise``: the lumped sensor noise model of docs/physics.md §5 (and §3 for
  2x2 binning) that measurements on the simulated or real camera are compared with.
- ``camd.analysis.tdi_snr``: SNR against the TDI stage count, the models of §5 and the
  along-track / periodic measurements of a scan.
- ``camd.analysis.emva``: EMVA-style temporal dark noise and SNR from A frames (§5 eqs 9-13),
  region PSNR, 2x2 binning SNR (§3); cross-checked against the emva1288 package.
- ``camd.analysis.snr_models``: the three SNR-versus-M models of §5 side by side and a fit of
  a model's parameters to measured points.
- ``camd.analysis.mtf``: the MTF models of §6 (eqs 3, 8), slanted-edge MTF (ISO 12233 style),
  periodic edge targets, bar-target modulation.
- ``camd.analysis.sharpness``: the grey-gradient sharpness of §7.
- ``camd.analysis.polarization``: the sinusoid fit of §4 for a polariser's azimuth.
- ``camd.analysis.roi``: per-frame statistics of named rectangles (mean, std, min, max, sum, SNR,
  saturated pixels, background-subtracted mean), shared by the daemon's ROI monitor and tests.
- ``camd.analysis.image_motion``: the image's motion per line (dV/V, drift angle) measured by
  registering successive TDI windows or area frames (docs/physics.md §10).
"""
