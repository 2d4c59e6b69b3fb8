"""spare-twin: a physical-digital twin toolkit for articulated objects (after the SPARE paper).

The pipeline: config -> cad -> urdf -> sim -> dataset -> nets -> capture -> compare.
Heavy libraries (torch, open3d, pybullet, rerun) are imported inside the modules that use them,
so importing this package and `spare-twin --help` stay instant.
"""

__version__ = "0.1.0"


class SpareTwinError(Exception):
    """A user-facing error: the CLI prints its message on one line and exits non-zero."""
