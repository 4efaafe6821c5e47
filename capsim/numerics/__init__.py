"""The discrete capsule: meshes, quadrature, geometry, the Stokes kernels, the membrane's and the
membrane viscosity's mechanics, the Krylov solve and the thread count of the numba kernels.

The lowest layer: it imports nothing of capsim above ``capsim.errors`` and ``capsim.quantities``.
One public surface: ``capsim.numerics.<name>`` for every name of ``__all__`` (``unit_sphere_mesh``,
``element_geometry``, ``triangle_rule``, ``stokeslet_sum``, ``MembraneForce``, ``gmres``, ``apply_policy``
...), each loaded from its module on first access; ``import capsim.numerics`` loads no numba (a name of
``kernels``, ``membrane`` or ``rigid_surface`` applies the thread policy before numba loads). The
library's own modules import each other by their full name (``capsim.numerics.kernels``).
"""

from capsim._surface import lazy_surface

#: module -> the names it gives the package's surface
_SURFACE = {
    "mesh": ("SurfaceMesh unit_sphere_mesh rest_shape_mesh rest_shape_attributes REST_SHAPES BASE_POLYHEDRA "
             "linear_subtriangles node_element_incidence rotation_onto rotation_about_z"),
    "conduit_mesh": ("tube_mesh duct_mesh axisymmetric_conduit_mesh round_caps axial_spacing "
                     "cosine_constriction_radius INLET OUTLET SIDE"),
    "geometry": ("ElementGeometry element_geometry volume_area centroid second_moment vertex_triangle_quality "
                 "numpy_quadrature interpolate shape_functions"),
    "quadrature": ("triangle_rule triangle_rule_degree subdivided_rule singular_rules gauss_legendre_01 "
                   "REGULAR_ORDERS NODE_XI NODE_ETA"),
    "kernels": "stokeslet_sum double_layer_sum wall_image_sum wall_image_double_layer",
    "rigid_surface": "single_layer_matrix single_layer_at surface_integral_weights nodal_normals",
    "membrane": ("MembraneForce MembraneState VertexStrain HingeBending LAWS get_law law_attributes "
                 "principal_tensions tension_tensor TRACTION_METHODS"),
    "viscosity": "VISCOSITY_MODELS build is_active",
    "linearization": "StageSolver",
    "krylov": "gmres LinearSolveFailed SolverDivergence",
    "threads": ("apply_policy set_run_threads usable_cores threads_for_work available_layers policy_attrs "
                "ThreadsError ENV_THREADS ENV_LAYER ENV_WAIT ENV_BLAS_TIMEOUT"),
}
#: the modules that load numba on import (their names apply the thread policy first)
__all__, __getattr__, __dir__ = lazy_surface(__name__, _SURFACE, {'kernels', 'membrane', 'rigid_surface'})
