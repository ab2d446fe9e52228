"""dcsms_ros: simulate, control and analyse a dual-stage cascade spring-mass isolation system."""

import os as _os

# Our matrices are at most a few hundred wide: BLAS threads cannot speed them up, and on a
# loaded 2-core box OpenBLAS's spinning threads made a 170x170 Schur form 25x slower (5.8 s
# against 0.23 s). One thread per process unless the user chose otherwise; set before numpy is
# imported by anything of ours.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
