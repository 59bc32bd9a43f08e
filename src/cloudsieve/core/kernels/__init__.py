"""Compiled (numba) kernels of the in-memory method; private: inputs are assumed valid."""
