"""QA of artefacts: one core under two families, gauge blocks and VDI/VDE 2634-2 artefacts.

The core, shared by both families:

- :mod:`~scanqa.qa.verdict`: the ISO 14253-1 decision (the one rule) and the verdict;
- :mod:`~scanqa.qa.correlation`: the noise-correlation factor of a fit (the one factor);
- :mod:`~scanqa.qa.results`: the frozen result types of both families;
- :mod:`~scanqa.qa.budget`: the GUM budget of a step (components, Welch-Satterthwaite);
- :mod:`~scanqa.qa.planes`, :mod:`~scanqa.qa.sphere`, :mod:`~scanqa.qa.flat`: the
  least-squares plane, sphere and the minimum zones;
- :mod:`~scanqa.qa.ransac`: finding spheres and planes in a cloud.

Gauge blocks:

- :mod:`~scanqa.qa.layout`: an artefact's blocks, nominal heights and regions;
- :mod:`~scanqa.qa.blocks`: per-block and per-step QA with GUM uncertainties;
- :mod:`~scanqa.qa.detect`: finding the blocks without a layout.
- :mod:`~scanqa.qa.paper`: the paper's Table 3 beside scanqa's per-block numbers.

VDI/VDE 2634-2 artefacts:

- :mod:`~scanqa.qa.ballbar`: the ball bar's two spheres and their distance;
- :mod:`~scanqa.qa.vdi2634`: PF, PS, SD and F with their uncertainties and decisions;
- :mod:`~scanqa.qa.form_range`: the predicted form error (the range of the residuals);
- :mod:`~scanqa.qa.artefacts`: finding each artefact in a cloud and selecting its points;
- :mod:`~scanqa.qa.artefact_sigma`: the points' sigma, oblique-view factor and shared
  errors.
"""
