"""Analysis: SNR, EMVA-style noise, MTF, sharpness, polarisation fit (pure functions).

- ``camd.analysis.sensor_noise``: the lumped sensor noise model of physics.md §5 (and §3 for
  2x2 binning) that measurements on the simulated or real camera are compared with.
"""
