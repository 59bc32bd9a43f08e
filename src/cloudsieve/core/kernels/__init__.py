"""Compiled (numba) kernels for the per-point loops of the method.

numba's threading layer is chosen here: GNU OpenMP, else workqueue. numba's own
default tries TBB first, which warns with the old libtbb open3d and pymeshlab load.
``NUMBA_THREADING_LAYER`` or ``NUMBA_THREADING_LAYER_PRIORITY`` still decide.
"""

import os

import numba

if not {"NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY"} & set(os.environ):
    numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]
