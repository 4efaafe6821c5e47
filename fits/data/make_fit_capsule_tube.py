"""Make fits/data/fit-capsule-tube.csv: synthetic lengths of a capsule carried through a tube, made by capsim.

A spherical neo-Hookean capsule on the axis of circular tubes of radius R = 1.4, 1.7 and 2.0 a
(a/R = 0.71, 0.59, 0.5: a pore to a wide channel), carried by the Poiseuille flow at the
capillary number Ca = μU/E_s = flow.G = 0.1 (the truth a fit should recover), level 1 to t = 4 a/U;
its length along the tube and width across it (in a) at that time, plus Gaussian noise of 1 % of
each (seed 56). The inverse problem of Hu, Salsac & Barthès-Biesel (2013): a capsule's modulus
from its profile in a pore. Run from the repository root:

    .venv/bin/python fits/data/make_fit_capsule_tube.py
"""

from pathlib import Path
import tempfile

import numpy as np

import capsim
from capsim.campaigns.summary import read_run

TRUTH_G = 0.1
RADII = (1.4, 1.7, 2.0)
REL_SD = 0.01
OUT = Path(__file__).with_name("fit-capsule-tube.csv")


def main() -> None:
    rng = np.random.default_rng(56)
    lines = [f"# synthetic: capsim level 1, t = 4 a/U, flow.G = {TRUTH_G:g}, plus N(0, sd), sd = {REL_SD:g} of each "
             "value, seed 56 (fits/data/make_fit_capsule_tube.py); not a measurement",
             "conduit.radius,length_along,length_along_sd,width_across,width_across_sd"]
    with tempfile.TemporaryDirectory() as tmp:
        for radius in RADII:
            case = {"name": "truth", "shape": {"kind": "sphere"}, "membrane": {"law": "neo_hookean"},
                    "flow": {"kind": "conduit", "G": TRUTH_G, "viscosity_ratio": 1.0},
                    "conduit": {"kind": "tube", "radius": radius}, "mesh": {"level": 1}, "time": {"t_end": 4.0},
                    "output": {"path": f"{tmp}/truth.h5"}}
            capsim.run(case, overwrite=True)
            r = read_run(f"{tmp}/truth.h5")
            cells = [f"{radius:g}"]
            for name in ("length_along", "width_across"):
                value, sd = float(r[name]), REL_SD * float(r[name])
                cells += [f"{value + rng.normal(0.0, sd):.6f}", f"{sd:.6f}"]
            lines.append(",".join(cells))
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
