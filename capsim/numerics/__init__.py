"""The discrete capsule: meshes, quadrature, geometry, the Stokes kernels, the membrane's and the
membrane viscosity's mechanics, the Krylov solve and the thread count of the numba kernels.

The lowest layer: it imports nothing of capsim above ``capsim.errors`` and ``capsim.quantities``.
Its modules are imported by their full name (``capsim.numerics.kernels``); this ``__init__`` loads
nothing, so that importing a numpy-only module here (``geometry``, ``mesh``) does not load numba.
"""
