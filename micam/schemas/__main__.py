"""`python -m micam.schemas [DIR]`: write the JSON Schemas (default: into the package)."""

import sys
from pathlib import Path

from . import HERE, write

for written in write(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE):
    print(written)
