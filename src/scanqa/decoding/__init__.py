"""Decoding: fringe images of a scan to the projector coordinate of every camera pixel.

- :mod:`~scanqa.decoding.coding`: what was projected (phase sets, Gray codes of any cell,
  white/black frames), the sensor noise model, the thresholds and the options;
- :mod:`~scanqa.decoding.parsing`: a parsed ``patterns.toml`` (version 1 or 2) to them;
- :mod:`~scanqa.decoding.chain`: the unwrapping order, with beats of non-nested periods;
- :mod:`~scanqa.decoding.patternset`: the images of a pattern folder, the ideal
  projected patterns, writing a pattern folder;
- :mod:`~scanqa.decoding.projection`: projector images and patterns.toml of a coding;
- :mod:`~scanqa.decoding.demodulate`: one N-step set to wrapped phase, modulation, noise;
- :mod:`~scanqa.decoding.gray`: Gray-code bits to cells;
- :mod:`~scanqa.decoding.noise`: the camera noise estimated from the images;
- :mod:`~scanqa.decoding.response`: projector nonlinearity, measured and corrected;
- :mod:`~scanqa.decoding.unwrap`: temporal unwrapping with reasons for every mask;
- :mod:`~scanqa.decoding.diagnostics`: the misstatement guard, period disagreement, hints;
- :mod:`~scanqa.decoding.decoder`: the whole scan, :func:`decode`;
- :mod:`~scanqa.decoding.phasemap`: the result, :class:`PhaseMap`, and its file.
"""
