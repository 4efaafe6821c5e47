# The thread policy of the CLI, applied before anything imports numba: on a
# shared machine numba's spinning default makes a parallel kernel wait out the
# time slice of a descheduled thread (docs/performance.md, "Threads").
import os

from capsim.numerics.threads import ENV_BLAS_TIMEOUT, ENV_LAYER, ENV_THREADS, ENV_WAIT, apply_policy

# The tests run under capsim's own policy, as CI does, however they are started: a thread
# variable of the user's environment makes every CLI say so on stderr first (one line more
# before each one-line error the tests read); tests of those variables pass their own.
for _name in (ENV_THREADS, ENV_LAYER, ENV_WAIT, ENV_BLAS_TIMEOUT, "CAPSIM_THREAD_POLICY"):
    os.environ.pop(_name, None)
apply_policy()

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from capsim.numerics.mesh import unit_sphere_mesh  # noqa: E402
from capsim.solve.solver import Discretization  # noqa: E402


@pytest.fixture(scope="session")
def sphere3():
    """Level-3 octahedral unit sphere (1026 nodes, 512 elements) and its tables."""
    mesh = unit_sphere_mesh("octahedron", 3)
    return mesh, Discretization(mesh.elements, mesh.n_vertices)


@pytest.fixture(scope="session")
def sphere2():
    mesh = unit_sphere_mesh("octahedron", 2)
    return mesh, Discretization(mesh.elements, mesh.n_vertices)


def single_layer_tensor(disc, x):
    """∫ G dS at every node as (N_p, 3, 3), from three element-constant densities."""
    geo = disc.geometry(x)
    cols = []
    for j in range(3):
        f = np.zeros((disc.elements.shape[0], 3))
        f[:, j] = 1.0
        cols.append(disc.single_layer(x, geo, f))
    return np.stack(cols, axis=2)
