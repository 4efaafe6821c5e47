"""One convention per screen (issue 30, finding 6): θ/π wherever θ is printed, ± defined,
one tension scale."""

import math

from capsim.face.display import summary_table
from capsim.campaigns.study import format_error_estimate


def _estimate() -> dict:
    out = {"coarse_level": 1, "loose_rtol": 1e-3, "wall_time_s": 2.0}
    for key, value, err in (("theta", 0.25 * math.pi, 0.01 * math.pi), ("D_xy", 0.3, 1e-3)):
        for suffix in ("", "_mean"):
            out[key + suffix] = err
            out[f"{key}{suffix}_mesh"], out[f"{key}{suffix}_time"] = -0.5 * err, 0.5 * err
        out[f"{key}_value"] = value
    return out


def test_the_error_estimate_prints_theta_over_pi_and_says_what_plus_minus_is():
    text = format_error_estimate({"theta": 0.25 * math.pi, "D_xy": 0.3}, _estimate())
    theta = [line for line in text.splitlines() if line.strip().startswith("theta")]
    assert theta and all(line.strip().startswith("theta/pi") for line in theta)
    assert all("0.250000 ± 1.00e-02" in line for line in theta), theta  # in units of π, as the table
    assert "± error estimate" in text.splitlines()[0]


def test_the_closing_table_defines_plus_minus_and_states_tensions_in_E_s():
    summary = {"status": "completed", "t": 1.0, "averaging_t_from": 0.5, "averaging_t_to": 1.0,
               "D_xy": 0.1, "D_xy_std": 1e-3, "compressed_fraction": 0.5, "min_tension": -2.0,
               "shear_rate_G": 0.05}
    table = summary_table(summary)
    assert "mean ± standard deviation over this window" in table
    assert "smallest tension -0.1 E_s" in table  # −2 μka × G = −0.1 E_s
