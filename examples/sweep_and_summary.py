"""A campaign from Python: sweep G and the viscosity ratio, then the summary as an xarray Dataset."""

import yaml

import capsim

from _common import OUT, TINY


def main():
    campaign = {
        "name": "example-sweep",
        "base": {"shape": {"kind": "sphere"}, "mesh": {"level": 0 if TINY else 2},
                 "time": {"t_end": 0.2 if TINY else 8.0}, "output": {"snapshot_every": 0.1 if TINY else 1.0}},
        "sweep": {"flow.shear_rate_G": [0.05, 0.1], "flow.viscosity_ratio": [1.0, 5.0]},
        "output": {"dir": str(OUT / "sweep")},
    }
    path = OUT / "sweep.yaml"
    path.write_text(yaml.safe_dump(campaign))

    done = capsim.sweep(path, workers=1)                        # completed runs are skipped on a rerun
    print(f"{done['total']} runs: {done['completed']} completed, {done['skipped']} skipped, {done['failed']} failed")
    ds = capsim.summarize(OUT / "sweep", overwrite=True)        # also written as sweep/summary.nc
    print(ds["D_xy"].round(4).to_pandas() if hasattr(ds["D_xy"], "to_pandas") else ds["D_xy"])


if __name__ == "__main__":
    main()
