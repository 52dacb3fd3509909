"""palpate: learning the shape of unknown objects by touch.

The runtime (bus, launcher, recorder, CLI) lives here; the nodes live in `palpate.nodes` and the
message schemas in `palpate.messages`.
"""

import os

# One node, one core: multithreaded BLAS in several node processes on a small machine makes every
# solve slower (measured: GPIS surface 120 ms of CPU instead of 28 on 2 cores). Set before numpy loads;
# an explicit setting in the environment wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
