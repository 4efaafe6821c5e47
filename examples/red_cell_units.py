"""A red blood cell in physical units: the conversion to capsim's numbers, then a short run."""

import capsim
from capsim.units import conversion

from _common import OUT, ROOT, TINY


def main():
    numbers = conversion(shear_rate="100 1/s", viscosity="1.2 mPa*s", radius="2.8 um", shear_modulus="2.5 uN/m")
    print(f"G = {numbers['G']:.4f}, Ca = {numbers['Ca']:.4f}, time unit 1/k = {numbers['time_unit_s'] * 1e3:g} ms")

    # configs/rbc.yaml gives the same values in its `physical:` block; G is computed from them
    case = capsim.load_case(ROOT / "configs" / "rbc.yaml", mesh__level=0 if TINY else 2,
                            time__t_end=0.1 if TINY else 20.0, output__path=str(OUT / "rbc.h5"))
    print(f"the case's G = {case.flow.shear_rate_G:.4f}, viscosity ratio = {case.flow.viscosity_ratio:g}")
    result = capsim.run(case, overwrite=True)
    kt = result.t
    print(f"{result.status} at kt = {kt:g}, that is {kt * numbers['time_unit_s'] * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
