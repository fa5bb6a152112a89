"""Design: what a scanner will do before it is built - depth of field, the W curve,
the usable volume, the flattening filter's curve (Sect. 5 of the paper) - the design page
and its server, and the optimiser of a configuration."""
