"""Compiled (numba) kernels for the per-point loops of the method.

numba's threading layer (the few ``parallel=True`` kernels) is chosen here,
before any kernel runs: GNU OpenMP, else numba's own workqueue. numba's
default order tries TBB first, and the older libtbb that open3d and pymeshlab
load makes it warn ("The TBB threading layer requires TBB version 2021 update
6") in every process that imported them first; OpenMP is the layer it then
took anyway. ``NUMBA_THREADING_LAYER`` or ``NUMBA_THREADING_LAYER_PRIORITY``
in the environment still decide.
"""

import os

import numba

if not {"NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY"} & set(os.environ):
    numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]
