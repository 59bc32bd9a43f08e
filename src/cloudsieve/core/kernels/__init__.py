"""Compiled (numba) kernels for the per-point loops of the method (issue 11)."""
