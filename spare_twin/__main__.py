"""`python -m spare_twin ARGS` is `spare-twin ARGS`; it is how torchrun starts data-parallel training:
`torchrun --nproc-per-node N -m spare_twin train ...` (docs/scale_out.md)."""

import sys

from spare_twin.cli import main

if __name__ == "__main__":
    sys.exit(main())
