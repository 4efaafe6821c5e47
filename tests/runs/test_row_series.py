"""The recorded series against the rows written before issue 57's compiled passes (commit 70cce17):
every column of every row of two short runs (the demo's sphere at level 2 to kt 2, quarter symmetry;
the red cell of configs/rbc.yaml at level 2 to kt 1), to round-off as the adaptive steps carry it.

tests/data/row_series_70cce17.npz was written by ``_series`` below, run on a checkout of 70cce17.
What differs there, on purpose and measured:

- the principal stretches (max_principal_stretch) and from them min_tension and compressed_fraction:
  λ1² − λ2² now comes from B's deviator, accurate to round-off (checked against numpy's eigh), where
  tr² − 4 det B lost half the digits: 1e-8 at rest (the rest shape's first row read 24 % of the
  sphere's vertices "compressed"), up to 1e-6 of the smallest tension in the red cell's run;
- an axis line's sign where the sign is decided by round-off (the red cell's long axis along z with
  x ~ 1e-11 at rest, perpendicular to the next row's): a line has no sign, its columns are compared
  up to the sign of each row.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "tests/data/row_series_70cce17.npz"
CASES = {
    "sphere_l2": ("configs/sphere.yaml", ["mesh.level=2", "time.t_end=2.0"]),
    "rbc_l2": ("configs/rbc.yaml", ["mesh.level=2", "time.t_end=1.0"]),
}
#: columns that carry the stretches' old √(round-off) error (module docstring), and lines (sign-free)
STRETCH_COLUMNS = ("max_principal_stretch", "min_tension", "compressed_fraction")
LINE_COLUMNS = ("long_axis", "short_axis")
#: the adaptive steps carry round-off: the step sizes agree to 2e-8, the state to ~1e-9
RTOL = 1e-7
#: the wall clock and its rates are not results
NOT_RESULTS = ("wall_s",)


def _series(name: str, tmp: Path) -> dict[str, np.ndarray]:
    import h5py

    import capsim

    config, sets = CASES[name]
    path = tmp / f"{name}.h5"
    capsim.run(ROOT / config, output=path, sets=sets)
    with h5py.File(path) as f:
        return {key: ds[()] for key, ds in f["timeseries"].items() if ds.ndim == 1}


@pytest.mark.parametrize("name", sorted(CASES))
def test_the_recorded_series_are_those_before_the_compiled_passes(name, tmp_path):
    reference = np.load(REFERENCE)
    old = {key.split("/", 1)[1]: reference[key] for key in reference.files if key.startswith(name + "/")}
    new = _series(name, tmp_path)
    assert set(old) <= set(new), sorted(set(old) - set(new))
    assert len(new["t"]) == len(old["t"])  # the same steps, accepted and rejected alike
    for key, before in old.items():
        if key.startswith(NOT_RESULTS):
            continue
        now = new[key]
        assert np.array_equal(np.isnan(now), np.isnan(before)), key
        finite = np.isfinite(before)
        scale = max(float(np.abs(before[finite]).max(initial=0.0)), 1e-6)
        if key.startswith(LINE_COLUMNS):
            axis = key.rsplit("_", 1)[0]
            sign = np.sign(sum(new[f"{axis}_{c}"] * old[f"{axis}_{c}"] for c in "xyz"))  # row by row
            now = sign * now
        tolerance = RTOL * scale
        rows = slice(None)
        if key in STRETCH_COLUMNS:  # the old √(round-off) (module docstring); the rest shape's row apart
            rows, tolerance = slice(1, None), 2e-6 * scale
            # at rest: no compressed vertex (before: round-off decided), no tension, stretch 1, to round-off
            rest = {"compressed_fraction": 0.0, "min_tension": 0.0, "max_principal_stretch": 1.0}[key]
            assert abs(now[0] - rest) < 1e-12, (key, now[0])
            if key != "compressed_fraction":  # the old row's noise, as measured (its share: 12-24 %)
                assert abs(before[0] - rest) < 1e-6 * scale
        error = np.abs(now[rows] - before[rows])[finite[rows]]
        assert error.max(initial=0.0) <= tolerance, (key, float(error.max()), tolerance)
