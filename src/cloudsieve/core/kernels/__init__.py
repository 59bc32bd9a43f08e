"""Compiled (numba) kernels of the in-memory method; private: inputs are assumed valid.

The public, validating functions live one level up (:mod:`cloudsieve.core`).
"""
