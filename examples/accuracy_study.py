"""Accuracy against cost: a ladder of mesh levels and tolerances, each compared with the finest."""

import capsim
from capsim.campaigns.study import format_study_table

from _common import OUT, ROOT, TINY


def main():
    levels, rtols, t_end = ((0, 1), (1e-3, 1e-4), 0.2) if TINY else ((1, 2, 3), (1e-3, 1e-4), 2.0)
    ds = capsim.study(ROOT / "configs" / "sphere.yaml", levels, rtols, time__t_end=t_end,
                      output=OUT / "study.nc", overwrite=True)   # the Pareto plot goes to study.png
    print(format_study_table(ds))


if __name__ == "__main__":
    main()
