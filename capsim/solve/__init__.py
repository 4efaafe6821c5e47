"""One step after another: the boundary-integral model of a scene (solver), the time schemes and
their cost model, the observables measured along a run, and the error model behind
``time.rtol: auto`` and accuracy targets (``error_model.json``).

Imports the numerics and the scene; never the schema's users above it (run files, runs,
campaigns, the CLI). One public surface: ``capsim.solve.<name>`` for every name
of ``__all__`` (``build_model``, ``CapsuleModel``, ``build_integrator``, ``SCHEMES``, ``StepObserver``,
``run_summary`` ...), each loaded from its module on first access; ``import capsim.solve`` loads no
numba (the solver's and the observables' names apply the thread policy first). The library's own
modules import each other by their full name.
"""

from capsim._surface import lazy_surface

#: module -> the names it gives the package's surface
_SURFACE = {
    "solver": "build_model CapsuleModel Discretization shear_flow",
    "timestepping": ("build_integrator make_integrator Integrator SCHEMES DEFAULT_SCHEME Automatic "
                     "EmbeddedRungeKutta LinearlyImplicit RungeKuttaChebyshev RKF23 ROSENBROCK"),
    "scheme_cost": "costs_for run_counts OPERATIONS",
    "stageclock": "StageClock",
    "observables": ("StepObserver run_summary scene_summary relaxation_summary orbit_summary stresslet_observables "
                    "particle_stresslet classify_motion classify_orbit is_steady series_settled orbit_settled "
                    "window_stats unwrap_defined ellipsoid_axes ellipsoid_of_moment rest_aspect_ratio "
                    "revolution_rate slow_relaxation_time body_axis capsule_mean centroid_travel MaterialDirector "
                    "TankTreadingTracker MAY_BE_UNDEFINED DRIFT_RTOL SETTLED_RTOL SETTLE_RELAXATION_TIMES "
                    "THETA_UNDEFINED_GAP"),
    "accuracy": "observed_order LADDER_TWO_LEVEL_ORDER SAFETY_QUANTILE",
}
#: the modules that load numba on import (their names apply the thread policy first)
__all__, __getattr__, __dir__ = lazy_surface(__name__, _SURFACE, {'observables', 'solver'})
