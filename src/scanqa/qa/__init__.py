"""QA of artefacts: gauge blocks today (VDI/VDE 2634-2 artefacts alongside).

- :mod:`~scanqa.qa.layout`: an artefact's blocks, nominal heights and regions;
- :mod:`~scanqa.qa.planes`: orthogonal least-squares planes;
- :mod:`~scanqa.qa.blocks`: per-block and per-step QA with GUM uncertainties;
- :mod:`~scanqa.qa.detect`: finding the blocks without a layout.
"""
