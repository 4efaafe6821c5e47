"""Closed-form tensions of the membrane laws, as docs/laws.md gives them: one module at the tests'
root, importable however a test is started (tests/numerics/test_laws.py, test_stress_free_shape.py)."""

import numpy as np


def inflation_tension(name, params, s):
    """Closed-form isotropic tension of a uniform stretch s (docs/laws.md)."""
    if name == "thin_shell":
        return (s * s - 1 + 4 * np.log(s)) / (3 * s * s)
    if name in ("neo_hookean", "mooney_rivlin"):
        psi = params.get("psi", 0.0)
        return (1 - psi) * (1 - s**-6) / 3 + psi * (s * s - s**-4) / 3
    if name == "skalak":
        c = params["skalak_c"]
        return (s * s - 1 + c * s * s * (s**4 - 1)) / 3
    raise AssertionError(name)
