"""Make fits/data/fischer-2015-ttf.csv: Fischer & Korzeniewski (2015)'s tank-treading frequencies of
225 red cells in 28.9 mPa s as capsim's summary column, one row per group of shear rates.

The cells (benchmarks/data/fischer2015_ttf_eta28.9.csv, copied with its provenance from
cselab/tRBC-UQ, see benchmarks/data/README.md) are grouped by shear rate as the validation's table
groups them (rates within a factor 1.3 of the group's first; benchmarks/tran_son_tay.py,
fischer_groups): the group's mean rate, and its cells' mean and SD of f/k, their f in revolutions
per second, as ttf_ratio = omega / (k/2) = 4 pi f/k. The SD is the cells' spread (donor to donor
and cell to cell), as the Tran-Son-Tay fit's SD is. Run from the repository root:

    .venv/bin/python fits/data/make_fischer_2015_ttf.py
"""

import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OUT = Path(__file__).with_name("fischer-2015-ttf.csv")


def main() -> None:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from tran_son_tay import fischer_groups

    lines = ["# Fischer & Korzeniewski, Biophys. J. 2015, Fig. S11: f/k of 225 cells of 12 donors in 28.9 mPa s "
             "(cselab/tRBC-UQ validation/rbc_shear_flow/exp/TTF/data_donors12.csv at 650b4c7f, copied to "
             "benchmarks/data/fischer2015_ttf_eta28.9.csv); grouped by rate (fits/data/make_fischer_2015_ttf.py): "
             "ttf_ratio = 4 pi f/k, the cells' mean and SD"]
    groups = fischer_groups()
    lines.append("# cells per row: " + ", ".join(str(n) for *_, n in groups))
    lines.append("physical.shear_rate,ttf_ratio,ttf_ratio_sd")
    for k, ratio, sd, _ in groups:
        lines.append(f"{k:.4g} 1/s,{4 * math.pi * ratio:.6f},{4 * math.pi * sd:.6f}")
    OUT.write_text("\n".join(lines) + "\n")
    print(OUT.read_text())


if __name__ == "__main__":
    main()
