"""Rendering only: plots and reports from results computed elsewhere."""
