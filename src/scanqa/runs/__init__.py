"""The runs that use the model: annotate a scan, batch and campaign runs, the demo, the design
page and optimiser, on-boarding and the board-noise characterisation."""
