"""Figures of the seed's kinds, as PNG, without a display.

``capsim plot PATH --kind KIND [-o FILE.png]``; PATH is a run file (.h5) for
every kind but ``steady``, which takes a campaign summary (netCDF from
``capsim summarize``). Every ``*_figure`` function returns a
:class:`matplotlib.figure.Figure` (no pyplot, no global state);
:func:`plot` draws one and saves it.

First-order small-deformation theory (docs/theory.md), drawn for
initially spherical capsules: D_xy → D∞ = (25/4) G (ν_s = 1/2: thin shell and
neo-Hookean), D(t) ≈ D∞ (1 − e^{−t/τ}) with kτ = τ̂(λ)·3G, τ̂ = 4.03 (λ = 1),
2.63 (λ = 0.2), 11.0 (λ = 5) (interpolated in log λ between these, not drawn
outside); θ = π/4; S*_xy = 1, N1* = 19 G, N2* = −N1*/2.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from capsim.membrane import linear_subtriangles

__all__ = [
    "DPI", "FIGSIZE", "KINDS", "contour_figure", "deformation_figure", "inclination_figure",
    "plot", "relaxation_time", "rheology_figure", "steady_figure", "tensions_figure",
    "trajectory_figure", "xy_section",
]

FIGSIZE = (6.4, 4.8)  # inches
DPI = 100             # → 640 × 480 pixels

# τ̂ = kτ / Ca of the impulsive-start relaxation (docs/theory.md), Ca = 3G.
_TAU_HAT = {0.2: 2.63, 1.0: 4.03, 5.0: 11.0}
_SPHERICAL_LAWS_NU_HALF = {"thin_shell", "neo_hookean", "mooney_rivlin"}


def relaxation_time(G: float, viscosity_ratio: float) -> float | None:
    """kτ of the first-order transient, or None outside the tabulated λ range."""
    lam = sorted(_TAU_HAT)
    if not lam[0] <= viscosity_ratio <= lam[-1]:
        return None
    tau_hat = float(np.interp(math.log(viscosity_ratio), np.log(lam), [_TAU_HAT[v] for v in lam]))
    return tau_hat * 3.0 * G


def _figure(figsize=FIGSIZE, **kwargs):
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, dpi=DPI, layout="constrained", **kwargs)


def _load_run(source: str | os.PathLike | dict) -> dict[str, Any]:
    if isinstance(source, dict):
        return source
    from capsim.store import read_trajectory

    return read_trajectory(source)


def _case_info(data: dict[str, Any]) -> dict[str, Any]:
    """G, λ, law, shape and name from the stored case; {} when it cannot be read."""
    try:
        from capsim.export import case_of

        case = case_of(data)
    except Exception:  # noqa: BLE001 - a figure without theory is still a figure
        return {}
    return {
        "G": float(case.flow.shear_rate_G),
        "lam": float(case.flow.viscosity_ratio),
        "law": str(case.membrane.law),
        "shape": str(case.shape.kind),
        "aspect_ratio": float(case.shape.aspect_ratio),
        "tilt": float(case.initial_tilt_deg),
        "name": str(case.name),
    }


def _title(info: dict[str, Any]) -> str:
    if not info:
        return ""
    return f"{info['name']}: {info['shape']}, {info['law']}, G = {info['G']:g}, λ = {info['lam']:g}"


def _theory_applies(info: dict[str, Any]) -> bool:
    return bool(info) and info["shape"] == "sphere" and info["law"] in _SPHERICAL_LAWS_NU_HALF


def _series(data: dict[str, Any], name: str) -> np.ndarray:
    ts = data["timeseries"]
    if name not in ts:
        raise ValueError(f"the run has no time series '{name}'")
    return np.asarray(ts[name], dtype=np.float64)


def _snapshot_index(data: dict[str, Any], t: float | None) -> int:
    times = np.asarray(data["snapshot_t"])
    if len(times) == 0:
        raise ValueError("the run has no snapshots")
    if t is None:
        return len(times) - 1
    return int(np.argmin(np.abs(times - t)))


# ------------------------------------------------------------ time series


def _sources(source) -> list:
    """One run, or several to overlay (a list or tuple of paths or loaded runs)."""
    return list(source) if isinstance(source, (list, tuple)) else [source]


def _run_label(info: dict[str, Any]) -> str:
    if not info:
        return "capsim"
    shape = {"sphere": "", "biconcave": "biconcave, "}.get(
        info["shape"], f"{info['shape']} b/a = {info.get('aspect_ratio', float('nan')):g}, "
    )
    return f"{shape}G = {info['G']:g}, λ = {info['lam']:g}"


def _plot_runs(ax, source, name: str, scale: float = 1.0) -> list[tuple[dict, np.ndarray, np.ndarray, str]]:
    """Series ``name`` (divided by ``scale``) against kt: one run in black under its
    title, several in colours labelled by their parameters. Returns (case info, t,
    values, colour for its theory curves) per run."""
    runs = _sources(source)
    single = len(runs) == 1
    drawn = []
    for i, run in enumerate(runs):
        data = _load_run(run)
        info = _case_info(data)
        t, values = _series(data, "t"), _series(data, name) / scale
        color = "k" if single else f"C{i % 10}"
        ax.plot(t, values, "-", color=color, label="capsim" if single else _run_label(info))
        if single:
            ax.set_title(_title(info), fontsize="small")
        drawn.append((info, t, values, "C0" if single else color))
    return drawn


def deformation_figure(source, theory: bool = True):
    """D_xy(t) with the first-order transient D∞(1 − e^{−t/τ}) and D∞.

    Several runs (a list) are overlaid in colours, each with its own theory curve
    (seed figs 4–6).
    """
    fig = _figure()
    ax = fig.add_subplot()
    drawn = _plot_runs(ax, source, "D_xy")
    single = len(drawn) == 1
    for i, (info, t, D, color) in enumerate(drawn):
        if not (theory and _theory_applies(info)):
            continue
        D_inf = 25.0 / 4.0 * info["G"]
        ax.axhline(D_inf, color=color, ls=":", lw=1, label=r"$D_\infty = 25G/4$" if i == 0 else None)
        tau = relaxation_time(info["G"], info["lam"])
        if tau is not None:
            tt = np.linspace(0.0, max(float(t[-1]), 0.0), 200)
            label = rf"first order, $k\tau$ = {tau:.3g}" if single else ("first order" if i == 0 else None)
            ax.plot(tt, D_inf * (1.0 - np.exp(-tt / tau)), "--", color=color, lw=1, label=label)
    if not single:
        # first-order curves of the larger G run far above the data (D∞ = 25G/4 > 1): keep the data in view
        ax.set_ylim(0.0, 1.15 * max(float(np.nanmax(D)) for _, _, D, _ in drawn))
    ax.set_xlabel(r"$kt$")
    ax.set_ylabel(r"$D_{xy}$")
    ax.legend(fontsize="small")
    return fig


def inclination_figure(source, theory: bool = True):
    """θ/π against kt with the first-order π/4 (several runs overlaid when given a list)."""
    fig = _figure()
    ax = fig.add_subplot()
    drawn = _plot_runs(ax, source, "theta", math.pi)
    if theory:
        ax.axhline(0.25, color="C0" if len(drawn) == 1 else "k", ls="--", lw=1,
                   label=r"first order, $\theta = \pi/4$")
    ax.set_xlabel(r"$kt$")
    ax.set_ylabel(r"$\theta/\pi$")
    ax.legend(fontsize="small")
    return fig


def rheology_figure(source, theory: bool = True):
    """S*_xy, N1*, N2* against kt (first-order values as dotted lines)."""
    data = _load_run(source)
    info = _case_info(data)
    t = _series(data, "t")
    fig = _figure()
    ax = fig.add_subplot()
    first = {}
    if theory and _theory_applies(info):
        # no N2* line: the old derived −N1*/2 was not borne out (REPRODUCTION.md, "N2*"); docs/theory.md now gives −(29/7)G
        first = {"Sxy_star": 1.0, "N1_star": 19.0 * info["G"]}
    labels = {"Sxy_star": r"$S^*_{xy}$", "N1_star": r"$N_1^*$", "N2_star": r"$N_2^*$"}
    for i, (name, label) in enumerate(labels.items()):
        ax.plot(t, _series(data, name), color=f"C{i}", label=label)
        if name in first:
            ax.axhline(first[name], color=f"C{i}", ls=":", lw=1)
    if first:
        ax.plot([], [], "k:", lw=1, label="first order")
    ax.set_xlabel(r"$kt$")
    ax.set_ylabel(r"$S^*_{xy}$, $N_1^*$, $N_2^*$")
    ax.set_title(_title(info), fontsize="small")
    ax.legend(fontsize="small")
    return fig


# ------------------------------------------------------------ xy-plane section


def xy_section(
    x: np.ndarray, elements: np.ndarray, z0: float = 0.0, values: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Points where the surface meets the plane z = z0, ordered by angle about their mean.

    The quadratic triangles are split into four straight ones and each edge that
    crosses the plane contributes one point (nodes exactly on the plane count as
    above it, so every crossing is found once). ``values`` (N_p, ...) are
    interpolated linearly to the points. Returns (points (n, 3), values (n, ...)).
    """
    x = np.asarray(x, dtype=np.float64)
    tri = linear_subtriangles(elements)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    phi = x[:, 2] - z0
    a, b = edges[:, 0], edges[:, 1]
    above_a, above_b = phi[a] >= 0.0, phi[b] >= 0.0
    cross = above_a != above_b
    a, b = a[cross], b[cross]
    s = phi[a] / (phi[a] - phi[b])
    pts = x[a] + s[:, None] * (x[b] - x[a])
    vals = None
    if values is not None:
        v = np.asarray(values, dtype=np.float64)
        shape = (-1,) + (1,) * (v.ndim - 1)
        vals = v[a] + s.reshape(shape) * (v[b] - v[a])
    if len(pts) == 0:
        raise ValueError(f"the surface does not meet the plane z = {z0:g}")
    # Crossings at a node shared by several edges appear once per edge: merge them.
    key = np.round(pts / 1e-10).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)
    pts = pts[first]
    vals = vals[first] if vals is not None else None
    c = pts.mean(axis=0)
    order = np.argsort(np.arctan2(pts[:, 1] - c[1], pts[:, 0] - c[0]))
    return pts[order], (vals[order] if vals is not None else None)


def _closed(p: np.ndarray) -> np.ndarray:
    return np.concatenate([p, p[:1]])


def contour_figure(source, times: Sequence[float] | None = None, z0: float = 0.0):
    """xy-plane sections of the surface at the snapshots nearest to `times`
    (default: up to four snapshots spread over the run)."""
    data = _load_run(source)
    info = _case_info(data)
    snap_t = np.asarray(data["snapshot_t"])
    if len(snap_t) == 0:
        raise ValueError("the run has no snapshots")
    if times is None:
        idx = np.unique(np.linspace(0, len(snap_t) - 1, min(4, len(snap_t))).round().astype(int))
    else:
        idx = np.array(sorted({_snapshot_index(data, t) for t in times}))
    fig = _figure()
    ax = fig.add_subplot()
    for j, k in enumerate(idx):
        p, _ = xy_section(data["positions"][k], data["elements"], z0)
        p = _closed(p)
        ax.plot(p[:, 0], p[:, 1], color=f"C{j % 10}", label=f"kt = {snap_t[k]:.3g}")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(r"$x/a$")
    ax.set_ylabel(r"$y/a$")
    ax.set_title(_title(info), fontsize="small")
    ax.legend(fontsize="small")
    return fig


def trajectory_figure(source, node: int | None = None, direction: Sequence[float] = (1.0, 0.0, 0.0)):
    """Path in the xy-plane of one material (node) point, from the snapshots.

    Default node: the rest-shape node in the plane z = 0 farthest along `direction`.
    """
    data = _load_run(source)
    info = _case_info(data)
    X = np.asarray(data["rest_positions"])
    pos = np.asarray(data["positions"])
    if len(pos) == 0:
        raise ValueError("the run has no snapshots")
    if node is None:
        d = np.asarray(direction, dtype=np.float64)
        in_plane = np.abs(X[:, 2]) <= 1e-8 * np.abs(X).max()
        candidates = np.flatnonzero(in_plane) if in_plane.any() else np.arange(len(X))
        node = int(candidates[np.argmax(X[candidates] @ d)])
    if not 0 <= node < X.shape[0]:
        raise ValueError(f"node must be in [0, {X.shape[0] - 1}], got {node}")
    path = pos[:, node, :]
    fig = _figure()
    ax = fig.add_subplot()
    for k, style, label in ((0, "0.6", "surface, first snapshot"), (len(pos) - 1, "0.3", "surface, last snapshot")):
        try:
            p, _ = xy_section(pos[k], data["elements"])
        except ValueError:
            continue
        p = _closed(p)
        ax.plot(p[:, 0], p[:, 1], color=style, lw=0.8, ls="--", label=label)
    ax.plot(path[:, 0], path[:, 1], "C3.-", label=f"node {node}")
    ax.plot(path[:1, 0], path[:1, 1], "C3o", mfc="none", ms=9, label=f"kt = {data['snapshot_t'][0]:.3g}")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(r"$x/a$")
    ax.set_ylabel(r"$y/a$")
    ax.set_title(_title(info), fontsize="small")
    ax.legend(fontsize="small")
    fig.path_node = node  # the chosen node, for callers and tests
    return fig


def tensions_figure(source, t: float | None = None, z0: float = 0.0):
    """Principal tensions τ1 ≥ τ2 (units E_s) along the xy-plane section at the
    snapshot nearest `t` (default: the last), against the polar angle φ/π."""
    from capsim.export import membrane_fields, model_for

    data = _load_run(source)
    info = _case_info(data)
    k = _snapshot_index(data, t)
    x = np.asarray(data["positions"][k], dtype=np.float64)
    fields = membrane_fields(model_for(data), x)
    values = np.stack([fields["principal_tension_1"], fields["principal_tension_2"]], axis=1)
    p, v = xy_section(x, data["elements"], z0, values)
    c = p.mean(axis=0)
    phi = np.mod(np.arctan2(p[:, 1] - c[1], p[:, 0] - c[0]), 2.0 * math.pi)
    order = np.argsort(phi)
    phi, v = phi[order], v[order]
    fig = _figure()
    ax = fig.add_subplot()
    ax.plot(phi / math.pi, v[:, 0], "C0.-", label=r"$\tau_1$")
    ax.plot(phi / math.pi, v[:, 1], "C1.-", label=r"$\tau_2$")
    ax.axhline(0.0, color="0.7", lw=0.8)
    ax.set_xlim(0.0, 2.0)
    ax.set_xlabel(r"polar angle in the $xy$-plane, $\varphi/\pi$")
    ax.set_ylabel(r"principal tension $/E_s$")
    ax.set_title(f"{_title(info)}, kt = {data['snapshot_t'][k]:.3g}", fontsize="small")
    ax.legend(fontsize="small")
    return fig


# ------------------------------------------------------------ campaign summary


RHEOLOGY_SUMMARY = ("ttf_ratio", "Sxy_star", "N1_star", "N2_star")


def steady_figure(source, theory: bool = True):
    """Steady D_xy and θ/π against G from a campaign summary (netCDF or Dataset).

    When the summary holds the tank-treading frequency and the stresslet (as
    `capsim summarize` writes them), a second column shows TTF/f_s (seed fig. 11)
    and S*_xy, N1*, N2* (fig. 13) against G, with their G → 0 limits.
    """
    import xarray as xr

    if isinstance(source, xr.Dataset):
        ds = source
    else:
        ds = xr.load_dataset(source)
    for name in ("D_xy", "theta", "shear_rate_G"):
        if name not in ds.variables:
            raise ValueError(f"the summary has no '{name}' (is it a capsim summarize output?)")
    rheology = all(name in ds.variables for name in RHEOLOGY_SUMMARY) and bool(
        np.isfinite(np.asarray(ds["Sxy_star"].values, dtype=np.float64)).any()
    )
    if rheology:
        fig = _figure(figsize=(1.8 * FIGSIZE[0], FIGSIZE[1]))
        (ax_d, ax_f), (ax_t, ax_s) = fig.subplots(2, 2, sharex=True)
    else:
        fig = _figure(figsize=(FIGSIZE[0], FIGSIZE[1]))
        ax_d, ax_t = fig.subplots(2, 1, sharex=True)
    groups = _steady_groups(ds, ("D_xy", "theta") + (RHEOLOGY_SUMMARY if rheology else ()))
    for j, (label, G, values) in enumerate(groups):
        order = np.argsort(G)
        color = f"C{j % 10}"
        ax_d.plot(G[order], values["D_xy"][order], "o-", color=color, label=label or "capsim")
        ax_t.plot(G[order], values["theta"][order] / math.pi, "o-", color=color, label=label or "capsim")
        if rheology:
            ax_f.plot(G[order], values["ttf_ratio"][order], "o-", color=color, label=label or "capsim")
            ax_s.plot(G[order], values["Sxy_star"][order], "o-", color=color,
                      label=r"$S^*_{xy}$" if j == 0 else None)
            ax_s.plot(G[order], values["N1_star"][order], "s--", color=color,
                      label=r"$N_1^*$" if j == 0 else None)
            ax_s.plot(G[order], values["N2_star"][order], "^:", color=color,
                      label=r"$N_2^*$" if j == 0 else None)
    G_all = np.asarray(ds["shear_rate_G"].values, dtype=np.float64).ravel()
    if theory and G_all.size:
        g = np.linspace(0.0, float(np.nanmax(G_all)), 50)
        small = g[g <= 0.12]  # first order: D_xy ≪ 1; further out it only squashes the data
        ax_d.plot(small, 25.0 / 4.0 * small, "k--", lw=1, label=r"first order, $25G/4$")
        ax_t.axhline(0.25, color="k", ls="--", lw=1, label=r"first order, $\pi/4$")
        if rheology:
            ax_f.axhline(1.0, color="k", ls="--", lw=1, label="rigid sphere")
            ax_s.axhline(1.0, color="k", ls="--", lw=1)
            ax_s.plot(small, 19.0 * small, "k:", lw=1, label=r"$N_1^* \approx 19G$")
    ax_d.set_ylabel(r"$D_{xy}$")
    ax_t.set_ylabel(r"$\theta/\pi$")
    ax_t.set_xlabel(r"$G = \mu k a / E_s$")
    ax_d.legend(fontsize="small")
    ax_d.set_title(str(ds.attrs.get("title", "")), fontsize="small")
    if rheology:
        ax_f.set_ylabel(r"TTF $/ f_s$")
        ax_s.set_ylabel(r"$S^*_{xy}$, $N_1^*$, $N_2^*$")
        ax_s.set_xlabel(r"$G = \mu k a / E_s$")
        ax_f.legend(fontsize="small")
        ax_s.legend(fontsize="small")
    return fig


def _steady_groups(ds, names: tuple[str, ...] = ("D_xy", "theta")) -> list[tuple[str, np.ndarray, dict]]:
    """One (label, G, {name: values}) series per combination of the other swept values."""
    first = ds[names[0]]
    if "shear_rate_G" in first.dims:
        others = [d for d in first.dims if d != "shear_rate_G"]
        arrays = {n: ds[n].transpose(*others, "shear_rate_G") for n in names}
        G = np.asarray(ds["shear_rate_G"].values, dtype=np.float64)
        out = []
        for index in np.ndindex(*(ds.sizes[d] for d in others)):
            sel = dict(zip(others, index))
            label = ", ".join(f"{_short(d)} = {_value(ds, d, i)}" for d, i in sel.items())
            out.append((label, G, {n: np.asarray(a.isel(sel).values, float) for n, a in arrays.items()}))
        return out
    # 'run' dimension: group by the other coordinates on it.
    dim = first.dims[0]
    G = np.asarray(ds["shear_rate_G"].values, dtype=np.float64)
    others = [name for name, c in ds.coords.items() if c.dims == (dim,) and name not in (dim, "shear_rate_G", "run_id")]
    keys = [tuple(np.asarray(ds[name].values)[i] for name in others) for i in range(ds.sizes[dim])]
    out = []
    for key in dict.fromkeys(keys):
        mask = np.array([k == key for k in keys])
        label = ", ".join(f"{_short(n)} = {v}" for n, v in zip(others, key))
        out.append((label, G[mask], {n: np.asarray(ds[n].values, float)[mask] for n in names}))
    return out


def _short(name: str) -> str:
    return {"viscosity_ratio": "λ", "shear_rate_G": "G", "initial_tilt_deg": "tilt"}.get(name, name)


def _value(ds, dim: str, i: int) -> str:
    if dim in ds.coords:
        v = np.asarray(ds[dim].values)[i]
        return f"{v:g}" if isinstance(v, (float, np.floating)) else str(v)
    return str(i)


# ------------------------------------------------------------ dispatcher

# kinds that overlay several runs when given a list of them
OVERLAY_KINDS = ("deformation", "inclination")

KINDS: dict[str, Callable[..., Any]] = {
    "deformation": deformation_figure,
    "inclination": inclination_figure,
    "contour": contour_figure,
    "trajectory": trajectory_figure,
    "tensions": tensions_figure,
    "rheology": rheology_figure,
    "steady": steady_figure,
}


def plot(source, kind: str, output: str | os.PathLike | None = None, **options: Any):
    """Draw figure `kind` of a run (or, for 'steady', a campaign summary); save it
    as PNG when `output` is given. Returns the Figure."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    fig = KINDS[kind](source, **options)
    if output is not None:
        output = Path(output)
        output.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(output, format="png", dpi=DPI)
    return fig


def default_output(source: str | os.PathLike, kind: str) -> Path:
    """RUN.h5 → RUN_<kind>.png beside it."""
    source = Path(source)
    return source.with_name(f"{source.stem}_{kind}.png")
