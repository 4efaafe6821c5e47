"""Make fits/data/fit-modulus-shear.csv: synthetic D_xy of a capsule in shear, made by capsim.

A sphere (neo-Hookean thin shell, the default law) of radius 50 um in a 1 mPa*s fluid with a
surface shear modulus G_s = 5 uN/m (the truth a fit should recover), run at level 1 to kt = 2 at
shear rates 1-4 1/s (G = mu k a / (3 G_s) = 0.0033-0.013, small deformation), plus Gaussian noise
of 2 % of each D_xy (seed 56). Run from the repository root:

    .venv/bin/python fits/data/make_fit_modulus_shear.py
"""

from pathlib import Path
import tempfile

import numpy as np

import capsim

TRUTH = "5 uN/m"
RATES = ("1 1/s", "2 1/s", "3 1/s", "4 1/s")
REL_SD = 0.02
OUT = Path(__file__).with_name("fit-modulus-shear.csv")


def main() -> None:
    rng = np.random.default_rng(56)
    lines = [f"# synthetic: capsim level 1, kt = 2, physical.shear_modulus = {TRUTH}, plus N(0, sd), sd = "
             f"{REL_SD:g} D_xy, seed 56 (fits/data/make_fit_modulus_shear.py); not a measurement",
             "physical.shear_rate,D_xy,D_xy_sd"]
    with tempfile.TemporaryDirectory() as tmp:
        for rate in RATES:
            case = {"name": "truth", "shape": {"kind": "sphere"}, "mesh": {"level": 1}, "time": {"t_end": 2.0},
                    "physical": {"shear_rate": rate, "viscosity": "1 mPa*s", "radius": "50 um",
                                 "shear_modulus": TRUTH},
                    "output": {"path": f"{tmp}/truth.h5"}}
            D = float(capsim.run(case, overwrite=True)["D_xy"])
            sd = REL_SD * D
            lines.append(f"{rate},{D + rng.normal(0.0, sd):.6f},{sd:.6f}")
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
