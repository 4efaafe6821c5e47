"""Run the demo case from Python, read the run back with xarray, and draw its deformation."""

import capsim
from capsim.face.plot import write_figure

from _common import OUT, ROOT, TINY


def main():
    level, t_end = (0, 0.2) if TINY else (2, 10.0)
    case = capsim.load_case(ROOT / "configs" / "sphere.yaml", mesh__level=level, time__t_end=t_end,
                            output__path=str(OUT / "sphere.h5"))
    result = capsim.run(case, overwrite=True)                  # progress=True shows a progress line
    print(f"{result.status}: D_xy = {result['D_xy']:.4f}, theta/pi = {result['theta'] / 3.141592653589793:.4f}")

    ts = capsim.open_run(result.path)["timeseries"].to_dataset()
    print(f"{ts.sizes['t']} steps, D_xy from {float(ts['D_xy'][0]):.4f} to {float(ts['D_xy'][-1]):.4f}")
    print(write_figure([result.path], "deformation", OUT / "sphere_deformation.png", overwrite=True))


if __name__ == "__main__":
    main()
