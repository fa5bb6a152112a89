"""Decoding: fringe images of a scan to the projector coordinate of every camera pixel.

- :mod:`~scanqa.decoding.coding`: what was projected (``patterns.toml``), the sensor
  noise model and the decision thresholds;
- :mod:`~scanqa.decoding.patternset`: the images of a pattern folder, the ideal
  projected patterns, writing a pattern folder;
- :mod:`~scanqa.decoding.demodulate`: one N-step set to wrapped phase, modulation, noise;
- :mod:`~scanqa.decoding.unwrap`: temporal unwrapping with reasons for every mask;
- :mod:`~scanqa.decoding.decoder`: the whole scan, :func:`decode`;
- :mod:`~scanqa.decoding.phasemap`: the result, :class:`PhaseMap`, and its file.
"""
