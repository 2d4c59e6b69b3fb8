"""spare-twin: a physical-digital twin toolkit for articulated objects (after the SPARE paper).

Stages, low to high (each imports only from the stages below it; see the README's architecture):
core (`errors`, `io`, `validate`, `terminal`, `output`, `config`, `recording`) -> `object` -> `sim` ->
`capture` -> `dataset` -> `observe` -> `measure` -> `nets` -> `predict` -> `live` -> `compare` -> `bench`
-> `commands` / `cli`.
Heavy libraries (torch, open3d, pybullet, rerun) are imported inside the modules that use them,
so importing this package and `spare-twin --help` stay instant.
"""

import os

# Set before numpy loads OpenBLAS: spare-twin's numpy work is many small matrix problems (least-squares
# fits on a few thousand points, 3 x 3 and 4 x 4 poses), and it runs its own threads side by side
# (`threads`). There OpenBLAS's threads only contend (measured on 15 hand-held captures' layer measurement:
# 11.2 s with the default threads, 9.8 s with one; 32.7 s against 15.0 s beside a second busy process).
# torch keeps its own threads. A user's own setting wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from spare_twin.errors import SpareTwinError  # noqa: E402

__version__ = "0.6.48"

__all__ = ["SpareTwinError", "__version__"]
