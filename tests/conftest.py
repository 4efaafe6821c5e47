import numpy as np
import pytest

from capsim.mesh import unit_sphere_mesh
from capsim.solver import Discretization


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
