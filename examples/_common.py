"""Settings shared by the examples: where they write, and how small they run.

``CAPSIM_EXAMPLES_OUT`` sets the output folder (default ``runs/examples``);
``CAPSIM_EXAMPLES_TINY=1`` makes every example run at the coarsest mesh for a moment of
simulated time, as the tests run them.
"""

import os
from pathlib import Path

OUT = Path(os.environ.get("CAPSIM_EXAMPLES_OUT", "runs/examples"))
TINY = os.environ.get("CAPSIM_EXAMPLES_TINY") == "1"
ROOT = Path(__file__).resolve().parents[1]
OUT.mkdir(parents=True, exist_ok=True)
