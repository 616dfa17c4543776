"""sfs_ros: a turntable + C-arm camera cell that reconstructs 3-D shape from silhouettes."""

import os

# Per-view work runs in the package's own threads (and numba's). BLAS only ever multiplies
# thin (n, 3) by (3, 3) matrices here, where threads of its own gain nothing and, on a busy
# machine, spin against the others (measured: projecting a mesh's vertices 15x slower).
# It must be set before numpy is first imported; a value set by the user wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
