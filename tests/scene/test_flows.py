"""Flows beyond simple shear (issue 41): the registry of capsim.scene.flows, what the schema takes
and refuses, the symmetries each flow keeps, and the known answers of docs/known_answers.md,
"Flows beyond simple shear": the first-order deformation in planar and uniaxial extension
against simple shear's, and a stiff capsule on the axis of Poiseuille flow translating at
Faxén's speed."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from capsim.config import ConfigError, case_from_dict
from capsim.scene.flows import FLOWS, far_field_of, symmetries_kept
from capsim.runs.runner import run_case
from capsim.solve.solver import build_model


def _case(tmp_path=None, name="f", **flow):
    d = {"name": name, "flow": flow, "mesh": {"level": 0}}
    if tmp_path is not None:
        d["output"] = {"path": str(tmp_path / f"{name}.h5"), "snapshot_every": 0.5}
    return d


def test_the_default_flow_is_todays_simple_shear_to_the_bit():
    plain = build_model(case_from_dict(_case()))
    named = build_model(case_from_dict(_case(kind="simple_shear")))
    x = plain[1] * np.array([1.1, 0.9, 1.0])  # a deformed shape
    u_plain = plain[0].velocity(x, plain[0].membrane(x))
    u_named = named[0].velocity(x, named[0].membrane(x))
    assert np.array_equal(u_plain, u_named)
    assert plain[0].disc.symmetry == "mirror_z+rotation_z"


@pytest.mark.parametrize("kind", sorted(FLOWS))
def test_every_flow_is_divergence_free_and_keeps_the_symmetries_it_claims(kind):
    extra = {"linear": {"velocity_gradient": [[0.2, 1.0, 0.0], [0.0, -0.2, 0.0], [0.0, 0.0, 0.0]]},
             "poiseuille": {"poiseuille_radius": 4.0}}.get(kind, {})
    case = _case(kind=kind, **extra)
    if kind == "conduit":  # the flow of the case's conduit (a tube: x stays inside it)
        case["conduit"] = {"kind": "tube", "radius": 4.0}
    from capsim.scene import Scene

    field = Scene.of(case_from_dict(case)).far_field  # the flow as the scene's boundaries admit it
    rng = np.random.default_rng(0)
    x = rng.standard_normal((50, 3))
    h = 1e-6
    div = sum((field(x + h * np.eye(3)[i]) - field(x - h * np.eye(3)[i]))[:, i] for i in range(3)) / (2 * h)
    assert np.abs(div).max() < 1e-8
    from capsim.scene.flows import SYMMETRY_GROUPS

    for name in symmetries_kept(field):
        for S in SYMMETRY_GROUPS[name]:
            np.testing.assert_allclose(field(x * S), field(x) * S, atol=1e-12)


def test_the_schema_takes_each_flows_fields_and_refuses_the_others_in_one_line():
    with pytest.raises(ConfigError, match="poiseuille_radius: required field|poiseuille_radius = None: is required"):
        case_from_dict(_case(kind="poiseuille"))
    with pytest.raises(ConfigError, match="applies only to kind: poiseuille"):
        case_from_dict(_case(kind="planar_extension", poiseuille_radius=4.0))
    with pytest.raises(ConfigError, match="traceless"):
        case_from_dict(_case(kind="linear", velocity_gradient=[[1, 0, 0], [0, 0, 0], [0, 0, 0]]))
    with pytest.raises(ConfigError, match="flow.kind"):
        case_from_dict(_case(kind="couette"))
    with pytest.raises(ConfigError, match="does not keep it"):
        case_from_dict({**_case(kind="poiseuille", poiseuille_radius=4.0), "mesh": {"level": 0, "symmetry": "quarter"}})
    with pytest.raises(ConfigError, match="cannot run flow.kind poiseuille"):
        case_from_dict({**_case(kind="poiseuille", poiseuille_radius=4.0), "time": {"scheme": "linearly_implicit"}})


def test_auto_symmetry_is_the_largest_group_the_flow_and_the_placed_shape_keep():
    def used(**case):
        return build_model(case_from_dict({"name": "s", "mesh": {"level": 0}, **case}))[0].disc.symmetry

    assert used(flow={"kind": "planar_extension"}) == "mirror_z+rotation_z"
    assert used(flow={"kind": "poiseuille", "poiseuille_radius": 4.0}) == "mirror_z"
    assert used(flow={"kind": "poiseuille", "poiseuille_radius": 4.0}, initial_center=[0.0, 1.0, 0.0]) == "mirror_z"
    assert used(flow={"kind": "poiseuille", "poiseuille_radius": 4.0}, initial_center=[0.0, 1.0, 0.5]) == "none"
    # a linear flow with a z-coupling keeps only the inversion
    L = [[0.0, 1.0, 0.5], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    assert used(flow={"kind": "linear", "velocity_gradient": L}) == "inversion"


def _D_over_G(tmp_path, kind: str, G: float, lam: float = 1.0) -> float:
    case = case_from_dict({**_case(tmp_path, name=f"{kind}-{G}-{lam}", kind=kind, shear_rate_G=G, viscosity_ratio=lam),
                           "membrane": {"bending_modulus": 1e-3}, "mesh": {"level": 1}, "time": {"t_end": 2.0}})
    result = run_case(case)
    assert result.status == "completed"
    return result.final_D_xy / G


def test_extension_against_simple_shear_at_first_order(tmp_path):
    """First-order theory (docs/known_answers.md, "Flows beyond simple shear"): the steady
    deformation of a capsule is linear in the rate-of-strain tensor E, so at equal G = μ·rate·a/E_s
    D(planar extension) = 2 D(shear) (E_xx − E_yy = 2ε against k) and D(uniaxial) = 3/4
    D(planar) (E_xx − E_yy = 3ε/2 against 2ε). The uniaxial flow's second-order term lies along
    E itself (E² less its trace is ∝ E), so its D/G moves at first order in G (0.644, 0.694,
    0.722 of the planar value at G = 0.01, 0.005, 0.0025): compared after Richardson
    extrapolation in G. A bending modulus of 1e-3 in all three stops the slow creep of the
    compressed membrane in extension (without it D grows ~10 % over kt 4 at G = 0.005); it
    stiffens the l = 2 mode alike in every flow. Level 1: the ratios move by 0.4 % to level 3."""
    shear = _D_over_G(tmp_path, "simple_shear", 0.005)
    planar = {G: _D_over_G(tmp_path, "planar_extension", G) for G in (0.005, 0.0025)}
    uniaxial = {G: _D_over_G(tmp_path, "uniaxial_extension", G) for G in (0.005, 0.0025)}
    assert planar[0.005] / shear == pytest.approx(2.0, rel=0.02)
    assert planar[0.0025] == pytest.approx(planar[0.005], rel=0.01)  # planar: no first-order drift in G
    ratio = {G: uniaxial[G] / planar[G] for G in planar}
    limit = 2 * ratio[0.0025] - ratio[0.005]
    assert limit == pytest.approx(0.75, rel=0.015)
    assert ratio[0.0025] < 0.75 and ratio[0.005] < ratio[0.0025]  # the second-order term's sign


def test_extension_against_simple_shear_at_first_order_at_another_viscosity_ratio(tmp_path):
    """The first-order steady shape does not depend on λ (only the way to it does): at λ = 5
    planar extension against shear is 2 as at λ = 1 (2.03 measured, level 1, G = 0.005)."""
    planar = _D_over_G(tmp_path, "planar_extension", 0.0025, 5.0)
    ratio = planar / _D_over_G(tmp_path, "simple_shear", 0.0025, 5.0)
    assert ratio == pytest.approx(2.0, rel=0.03)
    assert _D_over_G(tmp_path, "uniaxial_extension", 0.0025, 5.0) / planar == pytest.approx(0.75, rel=0.05)


def test_a_stiff_capsule_on_the_axis_of_poiseuille_flow_moves_at_faxens_speed(tmp_path):
    """Faxén's law for a rigid sphere, V = u∞(0) + (a²/6)∇²u∞ = R − 2/(3R) in units of (U/R)a,
    which a capsule approaches as G → 0; at t = 0 (no tension yet, λ = 1) the membrane moves
    with the fluid and the centroid at the volume mean of u∞, R − 2/(5R)."""
    R = 5.0
    case = case_from_dict({**_case(tmp_path, kind="poiseuille", poiseuille_radius=R, shear_rate_G=0.005),
                           "mesh": {"level": 2}, "time": {"t_end": 1.0}})
    assert run_case(case).status == "completed"
    with h5py.File(case.output.path, "r") as f:
        t, cx, cy = f["timeseries/t"][()], f["timeseries/centroid_x"][()], f["timeseries/centroid_y"][()]
        assert f.attrs["symmetry"] == "mirror_z"
        u = f["timeseries/centroid_velocity_x"][()]  # Reynolds transport, against the finite difference
    v = np.gradient(cx, t)
    assert u[-1] == pytest.approx(v[-1], rel=1e-5)
    assert v[0] == pytest.approx(R - 2 / (5 * R), rel=2e-3)
    assert v[-1] == pytest.approx(R - 2 / (3 * R), rel=2e-4)
    assert np.abs(cy).max() < 1e-10  # on the axis it stays there


def _poiseuille_run(tmp_path, G: float, y0: float, level: int = 1, t_end: float = 2.0):
    case = case_from_dict({**_case(tmp_path, name=f"p-{G}-{y0}", kind="poiseuille", poiseuille_radius=5.0,
                                   shear_rate_G=G),
                           "initial_center": [0.0, y0, 0.0], "mesh": {"level": level}, "time": {"t_end": t_end}})
    assert run_case(case).status == "completed"
    with h5py.File(case.output.path, "r") as f:
        return {k: f[f"timeseries/{k}"][()] for k in ("t", "centroid_x", "centroid_y", "centroid_z")}


def test_off_the_axis_a_stiff_capsule_moves_at_faxens_speed_and_a_soft_one_migrates_to_the_axis(tmp_path):
    """Faxén at r_c = R/2 (R = 5): V = R (1 − r_c²/R²) − 2/(3R) within 0.5 % (measured 9e-6 at
    G = 0.002, level 2); no migration in the rigid limit (Stokes flow is reversible: a rigid
    sphere does not cross streamlines), and a deformable capsule migrates towards the axis,
    the faster the softer (level 1: mean v_y over kt 1-2 of −4.8e-4, −2.4e-3, −4.4e-3 at
    G = 0.002, 0.02, 0.05)."""
    R, rc = 5.0, 2.5
    stiff = _poiseuille_run(tmp_path, 0.002, rc)
    t, cx, cy = stiff["t"], stiff["centroid_x"], stiff["centroid_y"]
    i = np.searchsorted(t, 1.0)
    vx = (cx[-1] - cx[i]) / (t[-1] - t[i])
    r_mean = 0.5 * (cy[-1] + cy[i])
    assert vx == pytest.approx(R * (1 - r_mean**2 / R**2) - 2 / (3 * R), rel=5e-3)
    assert np.abs(stiff["centroid_z"]).max() < 1e-10  # the mirror z -> -z keeps it in its plane
    migration = {}
    for G, run in ((0.002, stiff), (0.02, _poiseuille_run(tmp_path, 0.02, rc)), (0.05, _poiseuille_run(tmp_path, 0.05, rc))):
        t, cy = run["t"], run["centroid_y"]
        i = np.searchsorted(t, 1.0)
        migration[G] = (cy[-1] - cy[i]) / (t[-1] - t[i])
    assert abs(migration[0.002]) < 2e-4 * R  # a small fraction of the flow speed, ~1e-4
    assert migration[0.05] < migration[0.02] < 0.0  # towards the axis, faster when softer


def test_a_pre_inflated_capsule_at_rest_keeps_its_shape_under_the_laws_isotropic_tension(tmp_path):
    """shape.inflation α (issue 41, item 5): the stress-free shape is the initial sphere shrunk by
    1 + α, so at t = 0 the membrane is stretched by s = 1 + α in every direction; with no flow
    (a rate factor 0) the Laplace pressure Δf = 2τ/R n of the isotropic tension
    τ = e^{−Λ1}(W_1 + W_2 s²) (Λ1 = ln s², Λ2 = s² − 1) drives no motion: the sphere stays, and
    the smallest principal tension is τ (in units of E_s)."""
    from capsim.numerics.membrane import get_law

    alpha = 0.05
    case = case_from_dict({**_case(tmp_path, name="inflated", history={"kind": "table", "table": [[0, 0], [1, 0]]}),
                           "shape": {"kind": "sphere", "inflation": alpha}, "membrane": {"law": "neo_hookean"},
                           "mesh": {"level": 2}, "time": {"t_end": 0.5}})
    assert run_case(case).status == "completed"
    s = 1.0 + alpha
    w1, w2 = get_law("neo_hookean").derivatives(np.array([np.log(s * s)]), np.array([s * s - 1.0]))
    tau = float(np.exp(-np.log(s * s)) * (w1[0] + w2[0] * s * s))
    with h5py.File(case.output.path, "r") as f:
        D, volume, min_tension = (f[f"timeseries/{k}"][()] for k in ("D_xy", "volume", "min_tension"))
    assert tau > 0
    assert min_tension[0] * case.flow.shear_rate_G == pytest.approx(tau, rel=1e-2)  # stored in μka = E_s/G
    assert np.abs(D).max() < 1e-6 and abs(volume[-1] / volume[0] - 1) < 1e-6
    with pytest.raises(ConfigError, match="shape.inflation"):
        case_from_dict({"name": "x", "shape": {"inflation": -1.0}})


def test_above_the_critical_rate_of_extension_the_run_says_the_capsule_kept_elongating(tmp_path):
    """Issue 41, item 4: a neo-Hookean capsule in planar extension at G = 0.3 finds no steady shape
    (Lac et al. 2004: no steady state above a critical rate in planar extension); the run ends
    with motion 'elongating' and a reason that says so first, not a bare guard message."""
    case = case_from_dict({**_case(tmp_path, name="runaway", kind="planar_extension", shear_rate_G=0.3),
                           "membrane": {"law": "neo_hookean"}, "mesh": {"level": 1}, "time": {"t_end": 10.0}})
    result = run_case(case)
    assert result.status == "unstable"
    assert result.status_reason.startswith("no steady shape: the capsule kept elongating in planar_extension")
    assert "guard" in result.status_reason  # and which guard stopped it
    assert result.summary["motion"] == "elongating"
    # in shear at the same G the capsule tank-treads: a guard there is no 'elongating'
    assert run_case(case_from_dict({**_case(tmp_path, name="shear", shear_rate_G=0.3), "mesh": {"level": 1},
                                    "time": {"t_end": 1.0}})).summary["motion"] != "elongating"


def test_a_campaign_sweeps_the_flow_and_every_flow_summarises_plots_and_exports(tmp_path):
    """Issue 41, item 6: flow.kind is a field a campaign can sweep; the summary has it as a
    dimension; a run of each kind plots and exports (ParaView)."""
    import xarray as xr
    from typer.testing import CliRunner

    from capsim.campaigns.campaign import campaign_from_dict, run_campaign
    from capsim.face.cli import app
    from capsim.campaigns.summary import summarize_campaign

    campaign = campaign_from_dict({
        "name": "flows", "base": {"mesh": {"level": 0}, "time": {"t_end": 0.2}, "flow": {"shear_rate_G": 0.05}},
        "sweep": {"flow.kind": ["simple_shear", "planar_extension", "uniaxial_extension"]},
        "output": {"dir": str(tmp_path / "runs")}})
    assert run_campaign(campaign, workers=1)["completed"] == 3
    ds = summarize_campaign(tmp_path / "runs")
    assert "kind" in ds.dims and set(ds["kind"].values) == {"simple_shear", "planar_extension", "uniaxial_extension"}
    assert set(ds["status"].values.ravel()) == {"completed"}
    ext = float(ds["D_xy"].sel(kind="planar_extension"))
    shear = float(ds["D_xy"].sel(kind="simple_shear"))
    assert ext > shear > 0  # at kt 0.2 the extension has stretched it more
    run = next((tmp_path / "runs").glob("*planar*.h5"))
    cli = CliRunner()
    out = cli.invoke(app, ["plot", str(run), "--kind", "deformation", "-o", str(tmp_path / "d.png")])
    assert out.exit_code == 0, out.output
    out = cli.invoke(app, ["export", str(run), "--format", "vtu", "-o", str(tmp_path / "vtu")])
    assert out.exit_code == 0, out.output


def test_flow_G_is_the_dimensionless_rate_of_every_flow_by_its_short_name(tmp_path):
    """Issue 41, item 1: flow.G = μ·rate·a/E_s for every kind, stored as flow.shear_rate_G (which
    keeps working); in a case, with --set and as a swept field whose summary dimension is G."""
    from capsim.campaigns.campaign import campaign_from_dict, run_campaign
    from capsim.config import apply_overrides
    from capsim.campaigns.summary import summarize_campaign

    case = case_from_dict({"name": "g", "flow": {"kind": "uniaxial_extension", "G": 0.02}})
    assert case.flow.shear_rate_G == 0.02
    assert apply_overrides(case, **{"flow.G": 0.03}).flow.shear_rate_G == 0.03
    with pytest.raises(ConfigError, match="flow.G = 0.02: and shear_rate_G = 0.05 name one value"):
        case_from_dict({"name": "g", "flow": {"G": 0.02, "shear_rate_G": 0.05}})
    campaign = campaign_from_dict({"name": "g", "base": {"mesh": {"level": 0}, "time": {"t_end": 0.1},
                                                         "flow": {"kind": "planar_extension"}},
                                   "sweep": {"flow.G": [0.01, 0.02]}, "output": {"dir": str(tmp_path / "runs")}})
    assert run_campaign(campaign, workers=1)["completed"] == 2
    ds = summarize_campaign(tmp_path / "runs")
    # the dimension is the field's full name whichever name swept it (the same cases, the same
    # summary); case_field says which
    assert list(ds["shear_rate_G"].values) == [0.01, 0.02] and ds["shear_rate_G"].attrs["case_field"] == "flow.G"
    assert float(ds["D_xy"].sel(shear_rate_G=0.02)) > float(ds["D_xy"].sel(shear_rate_G=0.01)) > 0


def test_the_extra_dissipation_of_a_stiff_capsule_is_a_rigid_spheres_in_every_linear_flow(tmp_path):
    """Issue 41, item 4: dissipation_ratio = S:E/(5μV E:E) is 1 for a rigid sphere in any linear
    flow (Batchelor 1970: S = (20/3)πμa³E); a stiff capsule (G → 0, λ = 1) approaches it in shear,
    planar and uniaxial extension alike, and in shear it is S*_xy."""
    for kind in ("simple_shear", "planar_extension", "uniaxial_extension"):
        case = case_from_dict({**_case(tmp_path, name=f"d-{kind}", kind=kind, shear_rate_G=0.0005),
                               "mesh": {"level": 2}, "time": {"t_end": 0.1}})
        assert run_case(case).status == "completed"
        with h5py.File(case.output.path, "r") as f:
            ratio, sxy = f["timeseries/dissipation_ratio"][-1], f["timeseries/Sxy_star"][-1]
        assert ratio == pytest.approx(1.0, abs=0.02), kind
        if kind == "simple_shear":
            assert ratio == pytest.approx(sxy, rel=1e-6)
