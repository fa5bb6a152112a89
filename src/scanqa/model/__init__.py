"""The model: the scanner description and the noise chain of the paper (Eqs. 1-19): the
config, the readings of Eqs. 17 and 19, the pinhole geometry and the defocus optics."""
