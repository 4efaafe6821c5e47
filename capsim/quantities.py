"""The one table of the quantities capsim writes: units, long name, definition.

Every dataset of a run file (``mesh/``, ``timeseries/`` and the groups
``membrane_law``, ``rest_shape``, ``run``, ``summary``, ``error_estimate``),
every variable and coordinate of a campaign summary (netCDF, :mod:`capsim.campaigns.summary`)
and of a study file (:mod:`capsim.campaigns.study`) takes its attributes from :data:`TABLE`
through :func:`attrs_for`. ``tests/test_quantities.py`` checks that everything a
short run, a summary and a study write has an entry, and that every entry is used
(or listed in :data:`PLANNED`).

Scaling: capsim computes in the scales a (equal-volume radius), 1/k (inverse
shear rate), E_s (membrane elastic modulus) and μ (outer viscosity), so most
values are dimensionless. ``units`` is a UDUNITS string ("1" for a
dimensionless number, "rad", "degree", "s"); ``scale`` names the capsim scale the
dimensionless value is measured in ("a", "1/k", "E_s", "mu k a" …; "" for a pure
number), so that kt = 2 is ``units: "1", scale: "1/k"``. String-valued entries
(status, motion, names) have ``units: ""``.

A name means one thing in every file. Where the same name means something else
in one place (the ``error_estimate`` group holds error bars named after the
quantity; a campaign summary's ``D_xy`` is a window mean when the run reports
one, a study's its value at t_end), the table has a qualified entry
``"<where>/<name>"`` that :func:`attrs_for` prefers when given ``where``.

Root attributes of the run file and global attributes of the netCDF files are
metadata (status, versions, the resolved case, dates, thread settings), not
quantities: HDF5 attributes carry no attributes of their own, and CF maps
global attributes by its own conventions. They are not in this table.

This module imports nothing from capsim (and no numba): writers and readers of
any kind may use it.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CONVENTIONS", "FLAGS", "GROUPS", "MOTIONS", "MOTION_ALIASES", "MOTION_MEANINGS", "PERIODIC_MOTIONS",
           "PLANNED", "SETTLED_MOTIONS", "TTF_RATIO_KINDS", "TURNING_MOTIONS", "canonical_motion", "Quantity", "SCALES", "SCALE_UNITS", "TABLE", "UNIT_SYSTEMS",
           "attrs_for", "case_field_attrs", "global_attrs", "key_for", "physical_attrs", "physical_units"]


@dataclass(frozen=True)
class Quantity:
    """One entry of the table."""

    long_name: str
    units: str  # UDUNITS: "1", "rad", "degree", "s"; "" for strings
    definition: str
    scale: str = ""  # capsim scale of the dimensionless value: "a", "1/k", "E_s", "mu k a" …
    #: long name of the value times its scale, where that is another quantity (S*_xy × (5/2)μkV
    #: is the stresslet S_xy); "" when the long name holds (a time in 1/k or in s is a time)
    physical_name: str = ""

    def attrs(self) -> dict[str, str]:
        out = {"long_name": self.long_name, "units": self.units, "definition": self.definition}
        if self.scale:
            out["scale"] = self.scale
        return out


TABLE: dict[str, Quantity] = {}


def _add(key: str, long_name: str, units: str, definition: str, scale: str = "", physical_name: str = "") -> Quantity:
    if key in TABLE:
        raise ValueError(f"quantity {key!r} defined twice")
    TABLE[key] = q = Quantity(long_name, units, definition, scale, physical_name)
    return q


_STRESSLET = ("particle stresslet S = ∫ [Δf x − μ(1−λ)(u n + n u)] dS about the centroid, divided by "
              "its rigid-sphere value (5/2) μ k V")

# ---------------------------------------------------------------- mesh/

_add("elements", "node indices of the 6-node triangles", "1",
     "(Ne, 6) zero-based indices into the node arrays: the 3 vertices, then the 3 mid-side nodes")
_add("rest_positions", "node positions of the rest shape", "1",
     "(Np, 3) positions of the nodes at rest (the reference of the membrane strain), in units of a", "a")
_add("positions", "node positions", "1",
     "(n_snap, Np, 3) node positions at the snapshot times, in units of a", "a")
_add("snapshot_t", "time of the snapshot", "1", "kt at which the snapshot was taken (time in units of 1/k)", "1/k")
# index coordinates of the netCDF-4 dimensions of mesh/ (issue 16: xarray opens the group as it is)
_add("node", "node index", "1", "zero-based index of a mesh node (vertices first, then mid-side nodes)")
_add("element", "element index", "1", "zero-based index of a 6-node triangle")
_add("element_node", "node of the element", "1",
     "0, 1, 2: the vertices of the 6-node triangle; 3, 4, 5: its mid-side nodes")
_add("xyz", "Cartesian component", "1",
     "0: x (flow direction), 1: y (velocity gradient), 2: z (vorticity axis)")

# ---------------------------------------------------------------- timeseries/ (one row per accepted step)

_add("t", "time", "1", "kt, the time in units of the inverse shear rate 1/k", "1/k")
_add("dt", "accepted time step", "1",
     "k Δt of the step that led to this row (0 on the initial row), in units of 1/k", "1/k")
_add("error_estimate", "local error estimate of the accepted step", "1",
     "local error estimate of the time scheme's embedded pair divided by rtol (≤ 1 for an accepted step; "
     "0 on the initial row)")
_add("D_xy", "Taylor deformation parameter in the xy-plane", "1",
     "(L − l)/(L + l), L and l the longest and shortest semi-axes in the xy-plane (axis_L, axis_l) of the "
     "equivalent ellipsoid (same second moment of volume); the seed's definition, meant for a shape with an "
     "axis in the shear plane: when no principal axis is near z (a shape turned off the plane) it describes "
     "the two axes farthest from z, not the deformation — use ellipsoid_a/b/c then")
_add("theta", "inclination of the long axis", "rad",
     "angle from the x-axis (flow direction) to the long axis in the xy-plane, in (−π/2, π/2]; the seed's "
     "definition: for a shape turned off the plane it is the inclination of the projected axis (see "
     "long_axis_x/y/z and director_azimuth); NaN where the shape has no long axis in the plane (its two in-plane "
     "second moments equal to a relative 1e-10: a sphere at rest)")
_add("volume", "enclosed volume", "1", "volume V enclosed by the membrane, in units of a³", "a^3")
_add("area", "surface area", "1", "area S of the membrane, in units of a²", "a^2")
_add("volume_drift", "relative volume change", "1", "(V − V0)/V0, V0 the volume at t = 0")
for _c in "xyz":
    _add(f"centroid_{_c}", f"{_c} coordinate of the centroid", "1",
         f"{_c} coordinate of the volume centroid of the capsule, in units of a", "a")
for _c in "xyz":
    _add(f"centroid_velocity_{_c}", f"{_c} velocity of the centroid", "1",
         f"{_c} component of the centroid's velocity dc/dt = (∮ x (u·n) dS − c ∮ u·n dS)/V (Reynolds' transport "
         "theorem on the membrane's velocity), in units of k a: with a wall its y component is the lift, in "
         "Poiseuille flow the migration across streamlines", "a k")
for _c in "xyz":
    _add(f"slip_velocity_{_c}", f"{_c} slip of the centroid", "1",
         f"{_c} component of the centroid's velocity less the undisturbed flow at the centroid, in units of k a "
         "(a capsule lagging a Poiseuille flow or a wall's shear has slip_velocity_x < 0); in a summary: its mean "
         "over the averaging window", "a k")
_add("dissipation_ratio", "extra dissipation over a rigid sphere's", "1",
     "the particle's extra viscous dissipation S:E (Batchelor 1970; E the undisturbed flow's rate of strain at "
     "the centroid) over a rigid sphere's 5μV E:E, i.e. S*:E/(2 E:E): 1 for a rigid sphere in any linear flow, "
     "S*_xy in simple shear; NaN where E vanishes (the axis of Poiseuille flow); in a summary: its window mean")
_add("centroid_travel", "distance the centroid travelled", "1",
     "distance from the volume centroid at the run's first row to its last, in units of a (several capsules: "
     "the largest); every shape value is measured about the centroid, wherever it went", "a")
_add("wall_gap", "gap between membrane and wall", "1",
     "smallest distance of a membrane node from the wall or the conduit's wall (runs with one only), in units "
     "of a", "a")
# a run's summary (issue 54): the wall's gap and the migration across the flow, from start to end
_add("wall_gap_initial", "gap between membrane and wall at the start", "1", "wall_gap at t = 0, in units of a", "a")
_add("wall_gap_final", "gap between membrane and wall at the end", "1",
     "wall_gap at the end of the run, in units of a", "a")
_add("wall_gap_min", "smallest gap between membrane and wall", "1",
     "the smallest wall_gap over the run, in units of a", "a")
_add("centroid_y_initial", "y coordinate of the centroid at the start", "1",
     "centroid_y at t = 0, in units of a", "a")
_add("centroid_y_final", "y coordinate of the centroid at the end", "1",
     "centroid_y at the end of the run, in units of a", "a")
_add("migration_y", "migration across the flow", "1",
     "centroid_y_final − centroid_y_initial: how far the centroid moved along y (the velocity gradient; away "
     "from a wall, towards or away from the Poiseuille axis) over the run, in units of a", "a")
# conduits (conduit:, capsim.scene.conduit): velocities in units of the mean velocity U (k = U/a)
_add("extra_pressure_drop", "additional pressure drop", "1",
     "ΔP+, the pressure drop the capsule adds to the empty conduit's at the same flow rate, in units of μU/a "
     "(runs in a conduit only; U the conduit's mean velocity): by the reciprocal theorem with the empty "
     "conduit's flow, ΔP+ Q = ∫ u∞·Δf dS + (λ − 1) ∫ u·σ∞·n dS (docs/conduits.md); ΔP+ R/(μU) is it times R/a")
_add("axis_offset", "distance of the centroid from the conduit's axis", "1",
     "distance of the volume centroid from the conduit's axis (the x-axis), in units of a (runs in a conduit "
     "only): a capsule's lateral migration", "a")
_add("length_along", "the capsule's length along the conduit", "1",
     "extent of the membrane's nodes along the conduit's axis (x), in units of a (runs in a conduit only); 2 "
     "for the sphere at rest", "a")
_add("width_across", "the capsule's width across the conduit", "1",
     "twice the largest distance of a membrane node from the axis line through the centroid (parallel to x), in "
     "units of a (runs in a conduit only); 2 for the sphere at rest", "a")
# several capsules (capsules:, issue 43): the scene's columns beside every capsule's own
_add("capsule", "capsule index", "1",
     "zero-based index of a capsule of the scene, in the order of the case's capsules list; a per-capsule "
     "column is (t, capsule)")
_add("min_capsule_gap", "smallest gap between two capsules", "1",
     "smallest node-to-node distance between two capsules' membranes (runs of several capsules), in units of a; "
     "in a summary: the closest approach over the run", "a")
for _c, _dir in (("x", "streamwise"), ("y", "cross-stream"), ("z", "spanwise")):
    _add(f"separation_{_c}", f"{_dir} separation of the pair", "1",
         f"{_c} of capsule 1's centroid less capsule 0's (runs of two capsules), in units of a", "a")
for _key in ("Sxy_star", "N1_star", "N2_star"):
    _add(f"suspension_{_key}", f"mean over the capsules of {_key}", "1",
         f"{_key} of the capsules' mean particle stresslet (runs of several capsules), in units of (5/2) μ k V: "
         "the particle stress of the suspension is the volume fraction times (5/2) μ k times it", "5/2 mu k V")
_add("separation_y_initial", "cross-stream separation at the start", "1",
     "separation_y at t = 0, in units of a", "a")
_add("separation_y_peak", "peak cross-stream separation", "1",
     "separation_y of the largest magnitude over the run (the pair's closest passage lifts it), in units of a", "a")
_add("separation_y_final", "final cross-stream separation", "1",
     "separation_y at the end of the run: after a collision, the pair's net cross-stream displacement plus the "
     "initial offset, in units of a", "a")
_add("separation_x_final", "final streamwise separation", "1", "separation_x at the end of the run, in units of a",
     "a")
_add("axis_L", "longest in-plane semi-axis", "1",
     "longer of the two semi-axes in the xy-plane of the equivalent ellipsoid (same second moment of volume), "
     "in units of a", "a")
_add("axis_l", "shortest in-plane semi-axis", "1",
     "shorter of the two semi-axes in the xy-plane of the equivalent ellipsoid, in units of a", "a")
_add("axis_W", "out-of-plane semi-axis", "1",
     "semi-axis of the equivalent ellipsoid closest to the z-axis (vorticity direction), in units of a", "a")
_add("ellipsoid_a", "longest semi-axis of the equivalent ellipsoid", "1",
     "largest of the three semi-axes a ≥ b ≥ c of the ellipsoid with the capsule's volume and second moment of "
     "volume (seed 3.10), in units of a; unlike axis_L and axis_l not tied to the xy-plane", "a")
_add("ellipsoid_b", "middle semi-axis of the equivalent ellipsoid", "1",
     "middle semi-axis b of the equivalent ellipsoid, in units of a", "a")
_add("ellipsoid_c", "shortest semi-axis of the equivalent ellipsoid", "1",
     "smallest semi-axis c of the equivalent ellipsoid, in units of a", "a")
for _c in "xyz":
    _add(f"long_axis_{_c}", f"{_c} component of the longest axis of the equivalent ellipsoid", "1",
         f"{_c} component of the unit vector along the semi-axis ellipsoid_a; a line has no sign: on the first "
         "row its first component that is not ~0 (x, then y, then z) is positive, on every later row the sign "
         "that points it along the row before (a continuous series); of two equal semi-axes (a shape of "
         "revolution at rest) the one the shear stretches most (capsim.solve.observables.principal_frame)")
    _add(f"short_axis_{_c}", f"{_c} component of the shortest axis of the equivalent ellipsoid", "1",
         f"{_c} component of the unit vector along the semi-axis ellipsoid_c: the symmetry axis of a disk "
         "(oblate spheroid, biconcave red cell), which the motion classifier follows for such a rest shape; a "
         "line has no sign: its sign is chosen as long_axis's (continuous from row to row)")
    _add(f"director_{_c}", f"{_c} component of the material director", "1",
         f"{_c} component of the rest shape's symmetry axis carried by the membrane: F a/|F a|, a the axis at "
         "rest (initial_axis), F the rest-area-weighted least-squares affine map of the rest surface onto the "
         "current one (exactly R a for a rigid rotation R; capsim.solve.observables.MaterialDirector)")
_add("director_polar_angle", "polar angle of the director", "rad",
     "angle from the vorticity axis z to the material director, arccos(director_z) ∈ [0, π] (Jeffery's θ)")
_add("director_azimuth", "azimuth of the director", "rad",
     "angle in the shear plane from the gradient axis y towards the flow axis x of the director's projection, "
     "atan2(director_x, director_y) ∈ (−π, π] (Jeffery's φ); undefined while the director is along z")
_add("min_element_quality", "smallest element quality", "1",
     "minimum over the elements of 4√3·area / Σ edge² of the vertex triangle (1 equilateral, 0 degenerate)")
_add("max_principal_stretch", "largest principal stretch", "1",
     "maximum over the vertices of the larger principal stretch of the membrane against the rest shape")
_add("min_tension", "smallest principal membrane tension", "1",
     "minimum over the vertices of the smaller principal tension divided by G = μka/E_s: the tension in "
     "units of μ k a", "mu k a")
_add("compressed_fraction", "fraction of the membrane in compression", "1",
     "share of vertices whose smaller principal tension is negative; a membrane without bending "
     "stiffness would wrinkle there")
_add("Sxy_star", "normalised particle shear stress", "1", f"S_xy / ((5/2) μ k V), {_STRESSLET}", "5/2 mu k V",
     "particle stresslet S_xy")
_add("N1_star", "normalised first normal stress difference", "1",
     f"(S_xx − S_yy) / ((5/2) μ k V), {_STRESSLET}", "5/2 mu k V", "stresslet difference S_xx − S_yy")
_add("N2_star", "normalised second normal stress difference", "1",
     f"(S_yy − S_zz) / ((5/2) μ k V), {_STRESSLET}", "5/2 mu k V", "stresslet difference S_yy − S_zz")
_add("ttf_ratio", "normalised tank-treading frequency", "1",
     "f / f_s, f the frequency at which the material nodes starting in z = 0 circle the centroid in the "
     "xy-plane and f_s = k/(4π) that of a rigid sphere: per step from their mean angular velocity; in a "
     "summary from their whole revolutions (tt_angle) when there is at least one. A rest shape turned off the "
     "plane (initial_axis) has no mesh line on z = 0: the nodes of the band |z| < max|z|/4 (away from the "
     "z-axis) are followed instead. It is the nodes' rate in the lab frame: the membrane's tank-treading when "
     "the body does not turn, the body's turn (plus any tank-treading) when it does; the summary says which "
     "(ttf_ratio_kind) and gives both apart (body_rotation_ratio, tank_treading_ratio)", "k/(4 pi)",
     "tank-treading frequency")
_add("tt_angle", "tank-treading angle", "rad",
     "unwrapped mean angle about the centroid, in the xy-plane, of the tracked nodes (those starting in z = 0, "
     "or for a rest shape turned off the plane those of the band |z| < max|z|/4 away from the z-axis; "
     "ttf_ratio)")
_add("solver_iterations", "iterations of the velocity solve", "1",
     "iterations of the velocity solve at this state: the λ ≠ 1 double-layer solve (GMRES or substitution), or "
     "with a viscous membrane the GMRES solve of docs/viscous_membrane.md (V4) at any λ; 0 when the velocity is "
     "explicit (λ = 1, no membrane viscosity)")
_add("solver_residual", "relative residual of the velocity solve", "1",
     "relative residual of the λ ≠ 1 linear solve at this state; 0 when λ = 1")
# cost counters of the time stepping and the solver
_add("velocity_evaluations", "velocity evaluations", "1",
     "cumulative number of velocity evaluations since t = 0, rejected attempts and spectral-radius probes "
     "included")
_add("stages", "stages of the step", "1", "velocity evaluations (stages) of the accepted step")
_add("layer_applications", "single- and double-layer applications", "1",
     "cumulative number of single- and double-layer operator applications since t = 0, every iteration of "
     "the linear solve included")
_add("linear_iterations", "iterations of the stage solves", "1",
     "cumulative GMRES iterations of the linearly implicit scheme's stage solves since t = 0, rejected "
     "steps included; 0 for the explicit schemes (the λ ≠ 1 velocity solves are solver_iterations)")
_add("layer_matrices", "layer matrices assembled", "1",
     "cumulative dense single- and double-layer matrices assembled by the linearly implicit scheme's dense "
     "preconditioner since t = 0 (each evaluates the layer kernel at every node and rule point, the "
     "work of about four layer applications under quarter symmetry); 0 otherwise")

# ---------------------------------------------------------------- run/ (the state at the end) and records

_add("steps", "accepted time steps", "1",
     "number of accepted time steps; -1 in a summary or study record of a run that left no readable file")
_add("rejected_steps", "rejected time steps", "1", "number of step attempts rejected by the error control")
_add("wall_time_s", "wall-clock time of the run", "s",
     "elapsed time of run_case, mesh set-up included (a resumed run adds the time before its interruption); "
     "the study warms the JIT kernels up first")
_add("area_change", "relative area change", "1", "(S − S0)/S0, S0 the area at t = 0")
_add("largest_area_change", "largest relative area change", "1",
     "max over the run's rows of |S/S0 − 1| (several capsules: the capsule whose area moved most)")
_add("area_tolerance", "area tolerance of skalak_c auto", "1",
     "membrane.area_tolerance of a Skalak membrane whose C was chosen by skalak_c auto (the run says whether its "
     "largest area change stayed within it)")
_add("status", "final status of the run", "",
     "completed, unstable, interrupted or failed as recorded in the run file; missing when the run has no "
     "readable file")
_add("status_reason", "why the run stopped", "", "one line from the run")
_add("end_state", "state of the run at its t_end", "1",
     "bytes of a capsim restart checkpoint (.npz: integrator, model, observer, snapshot schedule and the case) "
     "at the last step of a run that reached time.t_end; `capsim run --resume --t-end T` extends the run from it")
_add("end_state_byte", "byte of the end state", "1", "zero-based index of a byte of end_state (its dimension)")
_add("n_nodes", "mesh nodes", "1", "number of nodes (vertices and mid-side nodes) of the mesh")

# ---------------------------------------------------------------- summary/ (statistics over the averaging window)

_add("motion", "class of motion", "",
     "as classified by the run (capsim.solve.observables.classify_orbit; the decision procedure and its thresholds: "
     "docs/method.md, \"Motion classes\"): steady (tank-treading in the shear plane, shape steady), swinging "
     "(tank-treading in the plane, shape and inclination oscillating; `oscillating` in files written before "
     "issue 39), tumbling (the body turning over in the plane), rolling (the body's symmetry axis along z, the "
     "membrane spinning), kayaking (the axis turning about z off the plane on an orbit whose constant holds), "
     "off_plane_tank_treading (the axis still off the plane and off z, the membrane tank-treading), "
     "drifting_to_rolling or drifting_to_plane (a transition in progress: the orbit constant changing by 5 % or "
     "more per orbit, or a still axis tilting), transient (none of these yet) or unstable (elongating when, in "
     "an extensional flow above its critical rate, the shape kept elongating until a guard stopped it); "
     "relaxing when the "
     "flow stopped during the run (flow.history kind stop); mixed for several capsules whose classes differ "
     "(each capsule's in the summary's capsule group); empty when the run did not classify it. The body's "
     "symmetry axis is the shape's own (short_axis of a disk, long_axis of a prolate), not the material director. "
     "Whether the motion has settled is `settled`")
_add("settled", "whether the motion has settled", "1",
     "1 when the classified motion has settled: a steady state (D_xy and θ within 1 % and 0.01 rad over the "
     "window), swinging whose last two cycles agree (period and peak-to-peak within 5 %), or an orbit whose last "
     "two whole orbits agree (period and mean orbit constant within 1 %); 0 otherwise, always for a transition "
     "in progress or a run too short to tell. time.stop_when_settled stops on the same rule")
_add("orbit_period", "period of the body's orbit", "1",
     "time for the body's symmetry axis to go once round (its azimuth through 2π: from one passage through the "
     "yz-plane to the next but one; p and −p are the same axis), the last whole orbit (twice its second half when "
     "it begins at the run's start, whose first half holds the start-up): 2π(r + 1/r) for Jeffery's rigid "
     "spheroid; NaN when the body does not turn or under one whole orbit", "1/k")
_add("orbit_period_change", "change of the orbit period", "1",
     "|T_last − T_before| / T_last over the last two whole orbits; NaN under two")
_add("orbit_periods", "whole orbits of the body", "1", "number of whole orbits of the body's symmetry axis in the run")
_add("orbits_averaged", "whole orbits averaged", "1",
     "whole orbits in the averaging window of a turning body (2 once settled, else the last 1); 0 when the "
     "window is not whole orbits")
_add("orbit_constant", "Jeffery orbit constant over the last orbit", "1",
     "time mean over the last whole orbit of C = |tan θ| (r² cos²φ + sin²φ)^½ / r (θ, φ the polar angle from z "
     "and the azimuth from y of the body's symmetry axis, r jeffery_aspect_ratio): constant for a rigid "
     "spheroid, 0 rolling, ∞ in the shear plane; NaN under one whole orbit")
_add("orbit_constant_change", "change of the orbit constant per orbit now", "1",
     "C over the last whole orbit over C over the one before, less 1; with under two whole orbits, from the last "
     "two half orbits (C repeats every half orbit), squared to one orbit: < 0 towards rolling, > 0 towards the "
     "plane; |change| ≥ 5 % is a transition in progress (drifting_to_rolling, drifting_to_plane), under 1 % "
     "(with the period's) settled; NaN in the plane (C = ∞) or under two half orbits")
_add("orbit_constant_first", "Jeffery orbit constant over the first orbit", "1",
     "time mean of C over the first whole orbit of the body's symmetry axis")
_add("orbit_constant_drift", "drift of the orbit constant per orbit", "1",
     "(C_last − C_first) / (n C_first), n the orbits between the first whole orbit and the last: the mean "
     "relative change per orbit over the run (> 0 towards the shear plane, < 0 towards rolling; the change now "
     "is orbit_constant_change); NaN under two whole orbits")
_add("final_polar_angle", "final angle of the body's axis from the vorticity axis", "rad",
     "angle from z of the body's symmetry axis (a line) at the last row, in [0, π/2]: 0 rolling along z, π/2 in "
     "the shear plane")
_add("shape_period", "period of the shape's oscillation", "1",
     "period of the oscillation of (a − c)/(a + c) of the equivalent ellipsoid (ellipsoid_a, ellipsoid_c) over "
     "the last two thirds of the run: half the orbit period for a deformable body turning over, the swing's "
     "period when swinging; NaN when the shape does not oscillate (a steady state, a rigid turn)", "1/k")
_add("body_rotation_ratio", "rotation rate of the body over k/2", "1",
     "the turn of the shape's axes about z over the averaging window, clockwise positive, over the rigid "
     "sphere's k/2: of the body's symmetry axis's azimuth (off z), else of its in-plane long axis θ; 2/(r + 1/r) "
     "for Jeffery's spheroid, 0 for a body that tank-treads in place; NaN where θ is undefined", "k/(4 pi)",
     "rotation frequency of the body")
_add("tank_treading_ratio", "tank-treading rate of the membrane relative to the body over k/2", "1",
     "the tracked material nodes' mean turn about z (tt_angle) less the body's (body_rotation_ratio), over "
     "the averaging window, clockwise positive, over k/2: the membrane's motion on the shape (a spin about the "
     "body's own symmetry axis counts: on a shape of revolution it is tank-treading); ~0 for a rigid turn",
     "k/(4 pi)", "tank-treading frequency relative to the body")
_add("rigid_turn", "whether the body turns nearly rigidly", "1",
     "1 when the body turns (|body_rotation_ratio| ≥ 0.05) and the membrane moves on it at under 10 % of the "
     "body's rate: ttf_ratio is then the body's rotation, not tank-treading; 0 otherwise; NaN when not measured")
_add("ttf_ratio_kind", "what ttf_ratio measures in this run", "1",
     "flag: 0 the membrane's tank-treading (the body does not turn), 1 the body's turn plus the membrane's "
     "tank-treading, 2 the body's turn alone (a nearly rigid rotation, rigid_turn); NaN when not measured "
     "(TTF_RATIO_KINDS)")
_add("jeffery_aspect_ratio", "aspect ratio r of the rest shape", "1",
     "axis / equatorial diameter of the rest shape's equivalent ellipsoid, sqrt of the ratio of its second "
     "moments along and across the axis: the r of Jeffery's orbit (b/a of a spheroid)")
_add("jeffery_period", "Jeffery period of the rest shape", "1",
     "2π(r + 1/r), r = jeffery_aspect_ratio: the orbit period of a rigid spheroid of that aspect ratio", "1/k")
_add("Sxy_viscous_star", "viscous membrane share of S*_xy", "1",
     "the part of S*_xy due to the membrane's viscous traction, (1/(2.5 V)) ∫ Δf_v x dS = ∫ T_v dA/(2.5 V) "
     "(docs/viscous_membrane.md, eq. V12); included in Sxy_star, N1_star, N2_star; only with membrane.viscosity")
_add("viscous_dissipation", "membrane viscous dissipation rate", "1",
     "∫ T_v:D dA, the power the membrane's viscosity dissipates, in units of μ k² a³; in simple shear the power "
     "the flow spends on the particle is S:E = 2.5 V S*_xy in the same units, and their ratio the viscous "
     "share of the dissipation (the elastic energy is stored, not dissipated); only with membrane.viscosity",
     "mu k^2 a^3")
_add("relaxation_time", "shape relaxation time at rest", "1",
     "kτ of the capsule relaxing at rest after the flow stopped: −1/slope of ln D_xy over the last two thirds "
     "of the rest (the slow mode of docs/viscous_membrane.md), in units of 1/k of the flow before the stop", "1/k")
_add("flow_stop_time", "time the flow stopped", "1", "kt at which the shear flow stopped (flow.history)", "1/k")
_add("period", "period of the motion", "1",
     "the period of the motion's cycle, in units of 1/k: orbit_period when the body turns (tumbling, kayaking, "
     "drifting: the time for its axis to go once round, θ through 2π in the plane), the swing's period when "
     "swinging (of θ, or of D_xy when θ does not swing; shape_period is the same cycle seen in the shape); NaN "
     "for steady, rolling and a still off-plane body, and when the run is too short to show one cycle", "1/k")
_add("averaging_t_from", "start of the averaging window", "1",
     "kt at which the averaging window of the summary starts (whole cycles when swinging, whole orbits when the "
     "body turns, else the last quarter of the run)", "1/k")
_add("averaging_t_to", "end of the averaging window", "1", "kt at which the averaging window ends", "1/k")
for _name, _what in (("D_xy", "Taylor deformation parameter"), ("theta", "inclination")):
    _add(f"{_name}_mean", f"cycle mean of the {_what}", TABLE[_name].units,
         f"mean of {_name} over the motion classifier's window (whole cycles when swinging, the steady "
         f"window when steady{', whole orbits when the body turns' if _name == 'D_xy' else ''}); NaN where the "
         f"classifier sets none{' (a turning body: θ turns through every angle)' if _name == 'theta' else ''}")
    _add(f"{_name}_amplitude", f"oscillation amplitude of the {_what}", TABLE[_name].units,
         f"half the peak-to-peak of {_name} over the last cycle (for a turning body, D_xy's over its last whole "
         f"orbit; θ turns through every angle and has none); NaN unless swinging or turning")
for _name in ("D_xy", "theta", "ttf_ratio", "Sxy_star", "N1_star", "N2_star", "centroid_velocity_y",
              "slip_velocity_x", "dissipation_ratio", "centroid_velocity_x", "extra_pressure_drop", "axis_offset",
              "length_along", "width_across"):
    _base = TABLE[_name]
    _add(f"{_name}_std", f"standard deviation of the {_base.long_name}", _base.units,
         f"standard deviation of {_name} over the averaging window; NaN when not reported", _base.scale,
         _base.physical_name and f"standard deviation of the {_base.physical_name}")

# ---------------------------------------------------------------- membrane_law/ and rest_shape/

_add("membrane_law/name", "membrane constitutive law", "",
     "thin_shell, neo_hookean, mooney_rivlin, skalak or surface_tension (docs/laws.md)")
_add("G_s", "small-strain shear modulus of the law", "1", "G_s in units of E_s", "E_s")
_add("K_s", "small-strain area-dilation modulus of the law", "1", "K_s in units of E_s", "E_s")
_add("poisson_ratio", "surface Poisson ratio", "1", "(K_s − G_s)/(K_s + G_s); NaN for a drop")
_add("ca_over_G", "capillary number over G", "1",
     "E_s/G_s: converts G = μka/E_s to the capillary number Ca = μka/G_s; 1 for a drop")
_add("equal_volume_radius", "equal-volume radius", "1",
     "(3V/4π)^(1/3) of the discretised shape, in units of a (1 up to the discretisation)", "a")
_add("sphericity", "sphericity", "1", "(36πV²)^(1/3)/S: area of the equal-volume sphere over the area, ≤ 1")

# ---------------------------------------------------------------- case fields (coordinates, parameters)

_add("shear_rate_G", "dimensionless shear rate G", "1",
     "G = μ k a / E_s, μ the outer viscosity, k the shear rate, a the equal-volume radius, E_s the membrane "
     "elastic modulus (the capillary number when the law is surface_tension)")
_add("viscosity_ratio", "viscosity ratio λ", "1", "λ = μ_inside / μ_outside")
_add("initial_tilt_deg", "initial tilt of the rest shape", "degree",
     "rotation of the rest shape about the z-axis at t = 0")
_add("aspect_ratio", "rest-shape aspect ratio", "1", "polar / equatorial axis of the rest spheroid")
_add("level", "mesh subdivision level", "1", "subdivisions of the base polyhedron")
_add("law", "membrane constitutive law", "", TABLE["membrane_law/name"].definition)
_add("skalak_c", "Skalak area-dilation parameter C", "1", "C of the Skalak law; K_s/G_s = 1 + 2C")
_add("psi", "Mooney-Rivlin parameter ψ'", "1", "weight of the second invariant in the Mooney-Rivlin law")
_add("bending_modulus", "bending modulus", "1",
     "κ/(E_s a²) of the dihedral-hinge bending energy relative to the rest shape (0: none)", "E_s a^2")
_add("rtol", "relative tolerance of the time step control", "1",
     "rtol of the embedded error estimate of the time scheme")
_add("regular_order", "regular Gauss rule", "1", "points of the Gauss rule on triangles away from the singularity")
_add("run_id", "run identifier", "",
     "readable swept values and a hash of the resolved case; the run file is <run_id>.h5")

# ---------------------------------------------------------------- campaign summary (netCDF)

_add("intrinsic_viscosity", "intrinsic viscosity of a dilute suspension", "1",
     "[μ] = (5/2) Sxy_star: the effective viscosity of a dilute suspension of volume fraction φ is "
     "μ_eff = μ (1 + φ [μ]) (2.5 for rigid spheres, Einstein); from the window mean of Sxy_star")
_add("intrinsic_viscosity_std", "standard deviation of the intrinsic viscosity", "1",
     "(5/2) Sxy_star_std over the averaging window")
_add("mesh_base", "base polyhedron of the mesh", "1",
     "flag: 0 octahedron, 1 icosahedron (flag_values, flag_meanings); the mesh is the base subdivided "
     "`level` times")
_add("time_scheme", "time-stepping scheme", "1",
     "flag: 0 rkf23 (Runge-Kutta-Fehlberg 2(3)), 1 rkc (Runge-Kutta-Chebyshev), 2 linearly_implicit "
     "(Rosenbrock-W) (flag_values, flag_meanings)")
_add("accuracy_target_met", "whether the run's measured accuracy target was met", "1",
     "1: the ladder's kept level meets the target (accuracy/met), 0: not met (max_level reached, or the ladder "
     "stopped: interrupted, failed, a full disk; accuracy/verdict says which), NaN: no measured target")
_add("steady_average", "whether the values are averages over a settled motion", "1",
     "flag: 1 when the run completed and its motion has settled (the run's `settled`; a run file written "
     "before issue 39 has none, and its class alone decides: steady, rolling, kayaking, oscillating or tumbling), "
     "so that the observables are means over whole cycles or orbits (or the steady window; a periodic run's "
     "spread is then its *_amplitude, and a turning body has no mean theta: NaN); 0 when the run ended "
     "transient, drifting or unstable, had not settled, or did not classify its motion: the observables are "
     "then means over the last quarter of the run, its last orbit (or its last row), not a settled value — do "
     "not average them with the others")

_STEADY = "at the end of the run (mean over the averaging window when the run reports one)"
for _name in ("D_xy", "theta", "ttf_ratio", "Sxy_star", "N1_star", "N2_star"):
    _base = TABLE[_name]
    _turning = ("; NaN for a turning body (tumbling, kayaking, drifting: its long axis turns through every angle)"
                if _name == "theta" else "")
    _add(f"campaign/{_name}", _base.long_name, _base.units, f"{_base.definition}; {_STEADY}{_turning}", _base.scale,
         _base.physical_name)
for _name in ("D_xy", "theta", "ttf_ratio", "Sxy_star"):
    _base = TABLE[_name]
    _add(f"{_name}_error_estimate", f"error estimate of the {_base.long_name}", _base.units,
         f"|Δ_mesh| + |Δ_time| of the window mean of {_name} (the run's error_estimate group, "
         f"capsim run --error-estimate: one level coarser, rtol × 10); NaN when not computed", _base.scale)

# ---------------------------------------------------------------- study file (netCDF)

#: observables of the study and of the error estimate (capsim.campaigns.study.QUANTITIES), and the orbit's
#: numbers a study compares with quantity "orbit" (capsim.campaigns.study.ORBIT_QUANTITIES)
_STUDIED = ("D_xy", "theta", "ttf_ratio", "Sxy_star")
_STUDIED_ORBIT = ("orbit_period", "orbit_constant", "body_rotation_ratio")
for _name in (*_STUDIED, *_STUDIED_ORBIT):
    _base = TABLE[_name]
    if _name in _STUDIED:
        _add(f"study/{_name}", f"{_base.long_name} at t_end", _base.units,
             f"{_base.definition}; at t = t_end (last row of the trajectory, theta unwrapped)", _base.scale)
    else:
        _add(f"study/{_name}", f"{_base.long_name} of the run's summary", _base.units,
             f"{_base.definition}; the run summary's window value (its last whole orbits)", _base.scale)
    _add(f"{_name}_error", f"error of the {_base.long_name}", _base.units,
         f"{_name} at t_end minus its reference value", _base.scale)
    _add(f"{_name}_relative_error", f"relative error of the {_base.long_name}", "1",
         f"|{_name}_error| / |{_name}_reference|")
    _add(f"{_name}_order", f"observed order of the {_base.long_name} in h", "1",
         "log2(|e_l| / |e_(l+1)|), e the error against the reference; the mesh spacing h halves with every level")
    _add(f"{_name}_order3", f"three-level observed order of the {_base.long_name} in h", "1",
         "log2(|f_l − f_(l+1)| / |f_(l+1) − f_(l+2)|), independent of the reference")
    _add(f"{_name}_reference", f"reference value of the {_base.long_name}", _base.units,
         f"{_name} of the finest run, or its Richardson extrapolation in the mesh level", _base.scale)

# ---------------------------------------------------------------- error_estimate/ (capsim run --error-estimate)

_add("coarse_level", "mesh level of the coarser rerun", "1", "level − 1; -1 at level 0 (no coarser mesh)")
_add("loose_rtol", "rtol of the looser rerun", "1", "min(10 rtol, 0.5)")
_add("error_estimate/wall_time_s", "wall-clock time of the reruns", "s", "sum of the reruns' wall times")
for _name in _STUDIED:
    _base = TABLE[_name]
    for _sfx, _of in (("", "at t_end"), ("_mean", "time mean over the run's averaging window")):
        _key = f"{_name}{_sfx}"
        _add(f"error_estimate/{_key}", f"error estimate of the {_base.long_name} ({_of})", _base.units,
             f"|Δ_mesh| + |Δ_time| of {_name} {_of}: the sum of the two differences {_key}_mesh and "
             f"{_key}_time that are finite", _base.scale)
        _add(f"error_estimate/{_key}_value", f"{_base.long_name} ({_of})", _base.units,
             f"{_name} of the run {_of}, the value the estimate is for", _base.scale)
        _add(f"error_estimate/{_key}_mesh", f"mesh part of the error estimate of the {_base.long_name}",
             _base.units, f"{_name} {_of} of the run minus that of the run one level coarser; NaN at level 0",
             _base.scale)
        _add(f"error_estimate/{_key}_time", f"time-step part of the error estimate of the {_base.long_name}",
             _base.units, f"{_name} {_of} of the run minus that of the run at loose_rtol", _base.scale)
        _add(f"error_estimate/{_key}_mesh2", f"{_base.long_name} two levels coarser, as a difference",
             _base.units, f"{_name} {_of} of the run minus that of the run two levels coarser (the third level "
             "that measures the Richardson order); NaN below level 2", _base.scale)

# ---------------------------------------------------------------- accuracy/ (a measured accuracy target: capsim.runs.ladder)

_add("accuracy/quantity", "quantity of the accuracy target", "", "D_xy, theta or Sxy_star at t_end, or a scene quantity's column (centroid_velocity_y for lift, slip_velocity_x, wall_gap_final, separation_y_final, migration_y)")
_add("accuracy/target", "accuracy target", "1", "the largest error asked for: relative for D_xy and Sxy_star, "
     "in rad for theta")
_add("accuracy/rtol", "time tolerance of the ladder's runs", "1", "capsim.solve.accuracy.ladder_rtol: its predicted time "
     "error a tenth of the target")
_add("accuracy/met", "whether the kept run's error estimate meets the target", "1", "1: met, 0: not met")
_add("accuracy/verdict", "the ladder's verdict", "", "the level kept, its error estimate and how it was had, "
     "met or NOT met (the line capsim run prints)")
_add("accuracy/error_model", "the error model's training cases nearest the case", "",
     "capsim.solve.accuracy.nearest: the cases whose predicted time error is added")
_add("accuracy/level", "mesh level of each run", "1", "1, 2, ... up to the level kept (this file's run)")
_add("accuracy/values", "the target's quantity at t_end at each level", "1", "relative errors are of these; "
     "theta in rad")
_add("accuracy/errors", "error estimate of each level's run", "1", "|f_L − f_(L−1)| / (2^p − 1) (relative for D_xy, "
     "Sxy_star), p the observed order of the last two differences (at most 4; 1.5 from two levels), plus the "
     "predicted time error; where the levels do not converge, the larger difference; NaN at the first level")
_add("accuracy/absolute_errors", "absolute error estimate of each level's run", "1",
     "accuracy/errors times |the level's value| for a relative quantity (the same number for theta): the "
     "statement that stands where the value is within its error of 0; NaN at the first level")
_add("accuracy/orders", "order used for each level's estimate", "1", "log2(|d_(L−1)| / |d_L|) of the last two "
     "differences; 1.5 from two levels; NaN where not converging")
_add("accuracy/evaluations", "velocity evaluations of each level's run", "1", "its run's velocity_evaluations")
_add("accuracy/wall_time_s", "wall-clock time of each level's run", "s", "its run's wall_time_s")

# ---------------------------------------------------------------- groups

#: What each group of a run file holds (written as the group's ``definition`` attribute).
GROUPS: dict[str, str] = {
    "mesh": "the mesh: 6-node triangles, rest shape and position snapshots",
    "timeseries": "one row per accepted step (and the initial row at t = 0), t as dimension scale",
    "membrane_law": "the membrane law, its parameters and its small-strain moduli",
    "rest_shape": "measures of the discretised rest shape",
    "run": "the state at the end of the run (last accepted step) and the run's cost",
    "summary": "the motion and, for each observable q, q (time mean) and q_std over the averaging window "
               "[averaging_t_from, averaging_t_to]; several capsules: the mean over the capsules, each capsule's "
               "in the subgroup capsule",
    "accuracy": "a measured accuracy target (capsim.runs.ladder): the levels run at one rtol, the target's quantity and "
                "error estimate at each, the level kept (this file's run) and whether it meets the target",
    "error_estimate": "q: |q(run) − q(one level coarser)| + |q(run) − q(rtol × 10)| at t_end; q_mean: the same "
                      "for the time mean over the run's averaging window; q_mesh, q_time: the signed differences",
}

#: Entries for columns that other work is adding now: no writer writes them yet.
#: Remove a name here once a writer writes it (tests/test_quantities.py checks
#: that every entry outside this set is used and that nothing written is in it).
PLANNED: frozenset[str] = frozenset()

del _add, _base, _c, _key, _name, _of, _sfx, _turning, _what


#: Categorical quantities written as CF flag variables (integer codes, flag_values, flag_meanings).
FLAGS: dict[str, tuple[str, ...]] = {
    "mesh_base": ("octahedron", "icosahedron"),
    "time_scheme": ("rkf23", "rkc", "linearly_implicit", "auto"),  # the order of timestepping.SCHEMES
    "steady_average": ("no", "yes"),
}

#: The CF version the netCDF files (and the run file) follow.
CONVENTIONS = "CF-1.10"

#: The capsim scales named by the ``scale`` attribute of a dimensionless value (units "1"):
#: (what it measures, its SI unit, the unit shown with ``--units physical``). The one place a
#: scale and its physical unit are spelled: every writer (closing table, summary, figures,
#: export) takes the unit from here through :func:`physical_units`; both UDUNITS (CF) and pint
#: read these strings. Frequencies are revolutions per second, Hz.
_SCALE_TABLE: dict[str, tuple[str, str, str]] = {
    "a": ("length: the equal-volume radius of the capsule, (3V/4π)^(1/3)", "m", "um"),
    "1/k": ("time: the inverse shear rate of the simple shear v = (k y, 0, 0)", "s", "s"),
    "E_s": ("membrane elastic modulus (surface tension for a drop), N/m; G = μka/E_s", "N/m", "uN/m"),
    "mu": ("viscosity of the outer fluid", "Pa*s", "mPa*s"),
    "mu k a": ("membrane tension (N/m) of the flow: G × E_s", "N/m", "uN/m"),
    "5/2 mu k V": ("particle stresslet of a rigid sphere of the capsule's volume V", "N*m", "pN*um"),
    "E_s a^2": ("bending energy (κ)", "J", "J"),
    "a^2": ("area", "m^2", "um^2"),
    "a^3": ("volume", "m^3", "um^3"),
    "mu k^2 a^3": ("power (W): a rate of dissipation or of work of the flow", "W", "fW"),
    "k/(4 pi)": ("frequency: f_s = k/(4π), the revolutions per unit time of a rigid sphere's surface", "Hz", "Hz"),
    "a k": ("velocity", "m/s", "um/s"),
    "E_s/a": ("traction (force per area): a membrane load Δf", "Pa", "Pa"),
}
#: capsim scale → what it measures (the rows of _SCALE_TABLE)
SCALES: dict[str, str] = {k: v[0] for k, v in _SCALE_TABLE.items()}
#: capsim scale → (its SI unit, the unit shown) (the rows of _SCALE_TABLE)
SCALE_UNITS: dict[str, tuple[str, str]] = {k: (v[1], v[2]) for k, v in _SCALE_TABLE.items()}

#: The fields of `capsim export` (ParaView files, not netCDF): name → (what it is, its capsim
#: scale; "" for a pure number). Their units, in either system, are SCALE_UNITS' and SCALES'.
EXPORT_FIELDS: dict[str, tuple[str, str]] = {
    "geometry": ("node positions", "a"),
    "time": ("time of the snapshot", "1/k"),
    "displacement": ("x − X from the rest shape", "a"),
    "velocity": ("membrane velocity u(x)", "a k"),
    "traction_jump": ("nodal traction jump Δf", "E_s/a"),
    "tension": ("tension tensor T, 9 components row-major", "E_s"),
    "principal_tension_1": ("larger principal tension", "E_s"),
    "principal_tension_2": ("smaller principal tension", "E_s"),
    "principal_stretch_1": ("larger principal stretch", ""),
    "principal_stretch_2": ("smaller principal stretch", ""),
    "traction": ("element average of Δf", "E_s/a"),
}
#: The motion classes of a run summary (capsim.solve.observables.classify_orbit; the decision
#: procedure and its thresholds: docs/method.md, "Motion classes"), in the order they are told apart
MOTIONS = ("unstable", "rolling", "tumbling", "kayaking", "drifting_to_rolling", "drifting_to_plane",
           "steady", "swinging", "off_plane_tank_treading", "transient", "relaxing", "elongating", "mixed")
#: what each class means, one line each (the quantity table and the docs say the same)
MOTION_MEANINGS: dict[str, str] = {
    "steady": "tank-treading in the shear plane with a steady shape",
    "swinging": "tank-treading in the shear plane while the shape and its inclination oscillate",
    "tumbling": "the body turns over in the shear plane (its symmetry axis there)",
    "rolling": "the body's symmetry axis along the vorticity axis z, the membrane spinning about it",
    "kayaking": "the body's symmetry axis turns about z off the plane on an orbit whose constant holds",
    "off_plane_tank_treading": "the body's symmetry axis still, off the plane and off z, the membrane "
                               "tank-treading (its shape steady or oscillating)",
    "drifting_to_rolling": "a transition in progress: the body turns about z while its orbit constant "
                           "falls by 5 % or more per orbit (or, not turning, its axis "
                           "tilts towards z)",
    "drifting_to_plane": "a transition in progress: the orbit constant rises by 5 % or more per orbit (or, "
                         "not turning, the axis tilts towards the shear plane)",
    "transient": "none of these yet (still evolving, or too short to tell)",
    "unstable": "the run went unstable (a non-finite value or a stability guard)",
    "relaxing": "the flow stopped during the run (flow.history kind stop): the shape relaxes at rest",
    "elongating": "in an extensional flow above its critical rate: the shape kept elongating, with no steady "
                  "state, until a stability guard stopped the run (status unstable)",
    "mixed": "several capsules whose motions differ (each capsule's in the summary's capsule group)",
}
#: old names, as run files written before issue 39 hold them: read as the new ones
MOTION_ALIASES: dict[str, str] = {"oscillating": "swinging"}
#: classes that are a settled motion when the summary's `settled` flag says so (a run file
#: written before issue 39 has no flag: its class alone, old names included, says it)
SETTLED_MOTIONS = ("steady", "swinging", "tumbling", "rolling", "kayaking", "off_plane_tank_treading", "oscillating")
#: Settled motions that are cycles, not states: their values are means over whole periods and
#: their spread the half peak-to-peak of the last cycle (``<q>_amplitude``)
PERIODIC_MOTIONS = ("swinging", "tumbling", "kayaking", "oscillating")
#: motions whose in-plane long axis turns round and round: no mean θ (NaN)
TURNING_MOTIONS = ("tumbling", "kayaking", "drifting_to_rolling", "drifting_to_plane")


#: what the summary's ttf_ratio measures, by its flag ttf_ratio_kind
TTF_RATIO_KINDS = ("the membrane's tank-treading (the body does not turn)",
                   "the body's turn plus the membrane's tank-treading",
                   "the body's turn (a nearly rigid rotation: the membrane hardly moves on it)")


def canonical_motion(name: str) -> str:
    """The class `name` means today (an old run file's ``oscillating`` is ``swinging``)."""
    return MOTION_ALIASES.get(name, name)


#: how values are shown and written: capsim's scales (dimensionless, the default) or physical
#: units from the run's ``physical:`` block
UNIT_SYSTEMS = ("capsim", "physical")


def global_attrs(title: str) -> dict[str, str]:
    """The CF global attributes every capsim file carries: Conventions, title, and the
    scale definitions (``capsim_scales``) that the ``scale`` attributes refer to."""
    return {
        "Conventions": CONVENTIONS,
        "title": title,
        "institution": "capsim",
        "source": "capsim boundary-integral simulation of a capsule in simple shear Stokes flow",
        "capsim_scales": "; ".join(f"{k}: {v}" for k, v in SCALES.items()),
        "comment": "dimensionless values have units \"1\" and name their scale in the attribute `scale` "
                   "(a, 1/k, E_s, mu k a ...; defined in capsim_scales): kt = 2 is units \"1\", scale \"1/k\"; "
                   "G = mu k a / E_s, and Ca = mu k a / G_s = ca_over_G × G (= 3 G: every elastic law has "
                   "G_s = E_s / 3)",
    }


# ---------------------------------------------------------------- look-up


def key_for(name: str, where: str | None = None) -> str:
    """The table key of `name` written in `where` (a run-file group, ``"campaign"``
    or ``"study"``): ``"<where>/<name>"`` when the table has it, else `name`.
    Raises KeyError when neither is in the table."""
    if where is not None and f"{where}/{name}" in TABLE:
        return f"{where}/{name}"
    if name in TABLE:
        return name
    raise KeyError(f"{name!r}{f' (in {where})' if where else ''} has no entry in capsim.quantities.TABLE")


def attrs_for(name: str, where: str | None = None) -> dict[str, str]:
    """The attributes (long_name, units, definition and scale when there is one) of `name`."""
    return TABLE[key_for(name, where)].attrs()


def physical_units(name: str, where: str | None = None) -> tuple[str, str]:
    """(unit shown, scale) of `name` in physical units: its scale's unit from
    :data:`SCALE_UNITS`, or its own units ("1", "rad", "s") and "" when it has no scale."""
    q = TABLE[key_for(name, where)]
    if q.scale in SCALE_UNITS:
        return SCALE_UNITS[q.scale][1], q.scale
    return q.units, ""


def physical_attrs(name: str, where: str | None = None) -> dict[str, str]:
    """The attributes of `name` converted to physical units: units from :data:`SCALE_UNITS`,
    no ``scale``, the long name of the value times its scale, and the definition saying so."""
    q = TABLE[key_for(name, where)]
    attrs = q.attrs()
    if q.scale not in SCALE_UNITS:
        return attrs
    attrs.pop("scale", None)
    attrs["units"] = SCALE_UNITS[q.scale][1]
    attrs["long_name"] = q.physical_name or q.long_name
    attrs["definition"] = f"{q.definition}; times its scale {q.scale} of the run's physical block, in {attrs['units']}"
    return attrs


def case_field_attrs(dotted: str) -> dict[str, str]:
    """Attributes of a swept case field (``flow.shear_rate_G``) used as a coordinate:
    the entry of its last component, plus ``case_field``; a field without an entry
    gets its dotted name as long_name and no units (tell the table about it)."""
    short = dotted.rsplit(".", 1)[-1]
    if short in TABLE:
        return dict(TABLE[short].attrs(), case_field=dotted)
    return {"long_name": dotted, "definition": f"case field {dotted} (capsim/config.py)", "case_field": dotted}
