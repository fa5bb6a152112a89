"""File formats, one module per format, and atomic writing."""
