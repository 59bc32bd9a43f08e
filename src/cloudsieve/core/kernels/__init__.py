"""Compiled (numba) kernels of the core's hot loops; private: inputs are assumed valid."""
