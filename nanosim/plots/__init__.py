"""Plots layer: every figure of nanosim; functions return matplotlib Figures and never write files."""
