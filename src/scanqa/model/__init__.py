"""The model: the scanner description, the noise chain of the paper (Eqs. 1-19), its fit to
data, the design tools and the annotated cloud they produce."""
