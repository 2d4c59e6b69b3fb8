"""spare-twin: a physical-digital twin toolkit for articulated objects (after the SPARE paper).

Stages, low to high (each imports only from the stages below it; see the README's architecture):
core (`errors`, `io`, `validate`, `terminal`, `output`, `config`, `recording`) -> `object` -> `sim` ->
`capture` -> `dataset` -> `observe` -> `measure` -> `nets` -> `predict` -> `live` -> `compare` -> `bench`
-> `commands` / `cli`.
Heavy libraries (torch, open3d, pybullet, rerun) are imported inside the modules that use them,
so importing this package and `spare-twin --help` stay instant.
"""

from spare_twin.errors import SpareTwinError

__version__ = "0.6.10"

__all__ = ["SpareTwinError", "__version__"]
