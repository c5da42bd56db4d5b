"""The processes of simecs: hub, proxy, simulator (and its workers), hot-feedback, recorder; the
`simecs` CLI with its `up`, `replay` and `export` commands.

Every node runs its linear algebra on one thread: numpy's and scipy's BLAS pools would otherwise
spin on the other cores after each small solve (the proxy's planning refused a pose past the reach
in 8-23 ms with one thread, up to 2.5 s with the default pool on a loaded 2-core server), taking CPU
from the runs. Set before any node module imports numpy; a deployment may still choose otherwise.
"""

import os as _os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
