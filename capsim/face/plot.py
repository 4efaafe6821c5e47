"""Figures of the seed's kinds, as PNG, PDF or SVG, without a display.

``capsim plot PATH --kind KIND [-o FILE.png|.pdf|.svg] [--dpi N]``; PATH is a
run file (.h5) for every kind but ``steady``, ``orbit_map`` and ``conduit``, which take a
campaign summary (netCDF from ``capsim summarize``), and ``lift``, which takes either (a summary
over the wall's distance, or several wall runs). The scenes' kinds ``lift``, ``migration`` and
``separation`` are the scenes' (issue 54; their section below). Every ``*_figure`` function returns a
:class:`matplotlib.figure.Figure` (no pyplot, no global state);
:func:`plot` draws one and saves it in the format its file suffix names.

Every figure carries a caption line (shape, law, λ, G, mesh) under its axes and
keeps its legend outside the data. θ is drawn only where it is defined (D_xy
above :data:`THETA_MIN_D`; a sphere at kt = 0 has none) and its line is broken
where θ wraps from −π/2 to π/2 (a tumbling capsule), or unwrapped on request.
Sections of the surface are cut from the curved 6-node elements (each element's
quadratic map, sampled :data:`SECTION_SUBDIVISIONS` times along an edge, the
crossing solved on the quadratic), not from its four flat sub-triangles.

A run of several capsules (``capsules:``; per-capsule columns (t, capsule)): the
time-series kinds (deformation, inclination, rheology) draw one line per capsule, labelled
capsule 0, 1, ...; contour and trajectory draw every capsule's outline in the section (contour
numbers them); tensions draws each capsule along its own section; ``separation`` draws a pair's
relative trajectory (``separation_y`` against ``separation_x``: capsule 1 less capsule 0) or,
for more capsules, each one's centroid path in the xy-plane. ``orbit`` draws one capsule and
refuses a scene of several, in one line; a one-capsule run's figures are as they were.

First-order small-deformation theory (docs/known_answers.md), drawn only where its
assumptions hold (:func:`first_order_theory` asks the scene: one initially
spherical, stress-free capsule with a ν_s = 1/2 law and no bending stiffness, no boundary, a
steady flow) and its D∞ is small (at most 25/4 :data:`FIRST_ORDER_G_MAX`), each flow kind's
line with its source in the legend (capsim.scene.flows ``Flow.first_order``): simple shear
D∞ = (25/4) G, θ = π/4, S*_xy = 1, N1* = 19 G and D(t) ≈ D∞ (1 − e^{−t/τ}) with kτ = τ̂(λ)·3G,
τ̂ = 4.03 (λ = 1), 2.63 (λ = 0.2), 11.0 (λ = 5) (interpolated in log λ between these, not drawn
outside); planar extension D∞ = (25/2) G; uniaxial extension (75/8) G; no line where none is
derived (Poiseuille, a general linear flow, a history, a wall, several capsules, a pre-inflated
or non-spherical capsule). The steady summary figure draws the panels of the quantities its
flow kind defines (``Flow.steady_quantities``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from capsim.numerics.mesh import linear_subtriangles  # numba-free: figures need no kernels
from capsim.scene import run_bodies, run_capsule_count
from capsim.quantities import PERIODIC_MOTIONS, canonical_motion
from capsim.scene.flows import FLOWS

__all__ = [
    "DPI", "FIGSIZE", "FIGURE_FORMATS", "FIRST_ORDER_G_MAX", "KINDS", "contour_figure", "orbit_figure", "orbit_map_figure", "deformation_figure", "inclination_figure",
    "plot", "relaxation_time", "rheology_figure", "steady_figure", "tensions_figure",
    "section_loops", "trajectory_figure", "xy_section", "separation_figure", "capsule_count", "scene_bodies",
    "capsule_sections", "first_order_theory", "lift_figure", "migration_figure", "OVERLAY_KINDS", "lift_law",
    "slip_law", "stresslet_yy",
]

FIGSIZE = (6.4, 4.8)  # inches
DPI = 100             # → 640 × 480 pixels (``--dpi`` changes it)
#: output formats, from the file suffix
FIGURE_FORMATS = ("png", "pdf", "svg")
#: first-order theory lines only up to this G (D∞ = 25G/4 ≤ 0.63; beyond, O(G²) terms are not small)
FIRST_ORDER_G_MAX = 0.1
#: θ is not drawn where D_xy is below this share of the run's largest D_xy (or below 1e-9):
#: the equivalent ellipsoid of a sphere has no long axis
THETA_MIN_D = 1e-3
#: sub-edges per element edge when cutting the curved surface with a plane
SECTION_SUBDIVISIONS = 6

# τ̂ = kτ / Ca of the impulsive-start relaxation (docs/known_answers.md), Ca = 3G.
_TAU_HAT = {0.2: 2.63, 1.0: 4.03, 5.0: 11.0}


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
    from capsim.storage.store import read_trajectory

    return read_trajectory(source)


def _case_info(data: dict[str, Any]) -> dict[str, Any]:
    """G, λ, law, shape and name from the stored case; {} when it cannot be read."""
    try:
        from capsim.face.export import case_of

        case = case_of(data)
    except Exception:  # noqa: BLE001 - a figure without theory is still a figure
        return {}
    from capsim.scene import Scene

    scene = Scene.of(case)
    info = {
        "G": float(case.flow.shear_rate_G),
        "lam": float(case.flow.viscosity_ratio),
        "law": str(case.membrane.law),
        "shape": str(case.shape.kind),
        "aspect_ratio": float(case.shape.aspect_ratio),
        "tilt": float(case.initial_tilt_deg),
        "name": str(case.name),
        "mesh": f"{case.mesh.base} level {case.mesh.level} ({np.asarray(data['rest_positions']).shape[0]} nodes)",
        "bending": float(getattr(case.membrane, "bending_modulus", 0.0) or 0.0),
        # the scene's boundaries (capsim.scene: a wall; none: unbounded), drawn by _draw_wall
        "boundaries": scene.boundaries,
        # the scene's first-order theory where its assumptions hold (None: no theory line)
        "first_order": first_order_theory(case, scene),
    }
    if scene.several:  # several capsules (issue 43): the scene's
        shapes = [spec.shape for spec in scene.specs]
        n = np.asarray(data["rest_positions"]).shape[0]
        info["capsules"] = len(shapes)
        info["mesh"] = f"{case.mesh.base} level {case.mesh.level} ({n // len(shapes)} nodes a capsule)"
        texts = list(dict.fromkeys(_shape_text({"shape": str(s.kind), "aspect_ratio": float(s.aspect_ratio)})
                                   for s in shapes))
        if len(texts) == 1:
            info["shape"], info["aspect_ratio"] = str(shapes[0].kind), float(shapes[0].aspect_ratio)
        else:  # capsules of different shapes: each named in the caption, no one-capsule theory
            info["shapes"], info["shape"], info["aspect_ratio"] = texts, "mixed", float("nan")
    return info


def _draw_wall(ax, info: dict[str, Any]) -> None:
    """The scene's boundaries (a wall, issue 42) as a line with a hatched band on the solid side,
    in the xy-plane figures: each boundary says where (capsim.scene.Boundary.outline_xy)."""
    for boundary in info.get("boundaries", ()):
        lo, hi = ax.get_xlim()
        line, band = boundary.outline_xy(lo, hi)
        ax.plot(line[:, 0], line[:, 1], color="0.2", lw=1.2, label=boundary.label)
        ax.fill(band[:, 0], band[:, 1], color="0.85", hatch="////", edgecolor="0.5", lw=0)
        ax.set_xlim(lo, hi)


def _shape_text(info: dict[str, Any]) -> str:
    if info.get("shapes"):  # several capsules of different shapes
        return "capsules " + " and ".join(info["shapes"])
    if info["shape"] in ("oblate", "prolate"):
        return f"{info['shape']} b/a = {info['aspect_ratio']:g}"
    return info["shape"]


def _caption_parts(info: dict[str, Any]) -> list[tuple[str, str]]:
    """(key, text) of what a caption says about one run."""
    law = info["law"] + (f", κ = {info['bending']:g}" if info.get("bending") else "")
    scene = [("capsules", f"{info['capsules']} capsules")] if info.get("capsules") else []
    return [("shape", _shape_text(info)), ("law", law), ("lam", f"λ = {info['lam']:g}"),
            ("G", f"G = {info['G']:g}")] + scene + [("mesh", f"mesh {info['mesh']}")]


def _caption(fig, infos: Sequence[dict[str, Any]], extra: str = "") -> str:
    """One caption line under the axes: shape, law, λ, G and mesh (of every run when they
    agree; what differs between overlaid runs is in the legend)."""
    infos = [i for i in infos if i]
    if not infos:
        text = extra
    else:
        per_run = [dict(_caption_parts(i)) for i in infos]
        parts = [v for k, v in per_run[0].items() if all(p.get(k) == v for p in per_run)]
        # not the case's name: a name such as 'sphere-G0.1' says nothing true after --set G=0.05;
        # the caption is the resolved case's values
        text = ", ".join(parts) + (f"; {extra}" if extra and parts else extra)
    if text:
        _supxlabel(fig, text)
    return text


def _supxlabel(fig, text: str) -> None:
    """The caption under the axes, wrapped to the figure's width (its lines kept)."""
    import textwrap

    fig.caption = text  # unwrapped, for a change of size
    width = max(40, int(fig.get_figwidth() * 15))  # characters of 'small' text per line
    fig.supxlabel("\n".join(textwrap.fill(line, width) for line in text.split("\n")), fontsize="small", color="0.25")


def _legend(ax, **kwargs):
    """A legend for `ax`; :func:`place_legends` puts it where it covers no data."""
    handles, _ = ax.get_legend_handles_labels()
    if not handles:
        return None
    return ax.legend(loc=_INSIDE[0], fontsize="small", **kwargs)


#: where a legend may sit inside its axes, tried in this order
_INSIDE = ("upper right", "upper left", "lower right", "lower left", "upper center", "lower center",
           "center right", "center left")
#: a legend keeps this many pixels (at the figure's dpi) from any drawn data
_LEGEND_CLEARANCE_PX = 3.0


def place_legends(fig) -> None:
    """Put each legend inside its axes at the first spot where it covers no drawn data
    (no line vertex, no point between vertices, no marker, no error bar); only where no
    spot is free, outside on the right, which narrows the axes by the legend's width and
    no more. Done at the figure's final size (after ``--size``)."""
    fig.draw_without_rendering()  # the final limits
    for ax in fig.axes:
        legend = ax.get_legend()
        if legend is None:
            continue
        _unlabel_out_of_view(ax)
        if not ax.get_legend_handles_labels()[0]:
            legend.remove()
            continue
        kwargs = {"fontsize": "small"}
        for loc in _INSIDE:
            legend.remove()
            legend = ax.legend(loc=loc, **kwargs)
            fig.draw_without_rendering()
            if not legend_covers_data(ax, legend):
                break
        else:
            legend.remove()
            ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, **kwargs)
    fig.draw_without_rendering()


def _unlabel_out_of_view(ax) -> None:
    """A line with no point inside the axes' view (a theory curve above the data's range)
    leaves the legend: an entry for what the reader cannot see misleads."""
    (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
    for line in ax.get_lines():
        label = line.get_label()
        if label.startswith("_"):
            continue
        x, y = np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)
        if line.get_transform() != ax.transData:  # axhline: x in axes units
            x = np.full_like(y, x0)
        if x.size and not np.any((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)):
            line.set_label("_" + label)


def legend_covers_data(ax, legend) -> bool:
    """Whether the legend's box (grown by :data:`_LEGEND_CLEARANCE_PX`) holds any point of
    the drawn data of `ax`, its lines sampled between vertices as well."""
    box = legend.get_window_extent().padded(_LEGEND_CLEARANCE_PX)
    for xy in _drawn_paths(ax):
        if len(xy) and np.any((xy[:, 0] >= box.x0) & (xy[:, 0] <= box.x1) & (xy[:, 1] >= box.y0) & (xy[:, 1] <= box.y1)):
            return True
    return False


def _drawn_paths(ax):
    """Display coordinates of every line of `ax` (densely sampled) and of its collections."""
    for line in ax.get_lines():
        xy = line.get_transform().transform(np.column_stack([line.get_xdata(), line.get_ydata()]).astype(float))
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if line.get_linestyle() not in ("None", "", " ") and len(xy) > 1:
            s = np.linspace(0.0, 1.0, 25)[:, None, None]
            xy = (xy[:-1][None] * (1 - s) + xy[1:][None] * s).reshape(-1, 2)
        yield xy
    for collection in ax.collections:
        for path in collection.get_paths():
            v = collection.get_transform().transform(path.vertices)
            if len(v) > 1:
                s = np.linspace(0.0, 1.0, 25)[:, None, None]
                v = (v[:-1][None] * (1 - s) + v[1:][None] * s).reshape(-1, 2)
            yield v[np.all(np.isfinite(v), axis=1)]


def first_order_theory(case, scene=None) -> Any:
    """The first-order theory of a case's scene where its assumptions hold, else None: the scene's
    own verdict (capsim.scene.Scene.first_order_theory; built here if not given)."""
    if scene is None:
        from capsim.scene import Scene

        scene = Scene.of(case)
    return scene.first_order_theory(case)


def _theory_applies(info: dict[str, Any]) -> bool:
    """First-order small-deformation theory: the scene meets its assumptions (``first_order``,
    chosen by its flow kind) and D∞ is small (the shear's at G ≤ FIRST_ORDER_G_MAX)."""
    first = info.get("first_order") if info else None
    return first is not None and first.D_over_G * info["G"] <= 25.0 / 4.0 * FIRST_ORDER_G_MAX


def _series(data: dict[str, Any], name: str) -> np.ndarray:
    ts = data["timeseries"]
    if name not in ts:
        raise ValueError(f"the run has no time series '{name}'")
    return np.asarray(ts[name], dtype=np.float64)


# ------------------------------------------------------------ several capsules (issue 43)

#: up to this many capsules each has its own colour and legend entry; more are shaded along a
#: colour map, the first and the last named
CAPSULE_LEGEND_MAX = 10
#: the line styles that tell capsules apart where colour names something else (rheology, overlays)
_CAPSULE_STYLES = ("-", "--", ":", "-.")


# the layout of a run file's capsules (capsim.scene.bodies owns it; export reads it there too)
capsule_count, scene_bodies = run_capsule_count, run_bodies


def _capsule_looks(k: int) -> list[tuple[Any, str | None]]:
    """(colour, legend label or None) of each of k capsules drawn in one axes."""
    if k <= CAPSULE_LEGEND_MAX:
        return [(f"C{j}", f"capsule {j}") for j in range(k)]
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    return [(cmap(j / (k - 1)), f"capsule {j}" if j in (0, k - 1) else None) for j in range(k)]


def _refuse_scene(data: dict[str, Any], kind: str, what: str, hint: str = "") -> None:
    """ValueError (one line) for a kind that draws one capsule, given a run of several."""
    k = capsule_count(data)
    if k > 1:
        raise ValueError(f"--kind {kind} draws {what} and the run holds {k} capsules" + (f" ({hint})" if hint else ""))


def _snapshot_index(data: dict[str, Any], t: float | None) -> int:
    """The snapshot nearest kt = t (the last for None); a t outside the run's snapshots
    (by more than half their spacing) is refused rather than snapped to the end."""
    times = np.asarray(data["snapshot_t"], dtype=np.float64)
    if len(times) == 0:
        raise ValueError("the run has no snapshots")
    if t is None:
        return len(times) - 1
    if not math.isfinite(t):
        raise ValueError(f"--time kt = {t}: must be a finite number")
    gap = 0.5 * float(np.max(np.diff(times))) if len(times) > 1 else 0.0
    tol = max(gap, 1e-9 * max(1.0, abs(float(times[-1]))))
    if t < times[0] - tol or t > times[-1] + tol:
        raise ValueError(
            f"--time kt = {t:g} is outside the run's snapshots (kt = {times[0]:g} to {times[-1]:g}, "
            f"{len(times)} snapshots)"
        )
    return int(np.argmin(np.abs(times - t)))


# ------------------------------------------------------------ time series


def _sources(source) -> list:
    """One run, or several to overlay (a list or tuple of paths or loaded runs)."""
    return list(source) if isinstance(source, (list, tuple)) else [source]


def _run_label(info: dict[str, Any], shape_in_caption: bool = False) -> str:
    """G and λ of an overlaid run, after its shape unless every run has it (the caption says it)."""
    if not info:
        return "capsim"
    shape = "" if shape_in_caption else {"sphere": "", "biconcave": "biconcave, "}.get(
        info["shape"], f"{info['shape']} b/a = {info.get('aspect_ratio', float('nan')):g}, "
    )
    bending = f", κ = {info['bending']:g}" if info.get("bending") else ""
    return f"{shape}G = {info['G']:g}, λ = {info['lam']:g}{bending}"


def _distinct(labels: list[str], infos: list[dict], runs: list) -> list[str]:
    """Labels that tell overlaid runs apart: where two are equal, what else differs between
    the runs (law, mesh, from the caption's parts), else the file's name."""
    if len(set(labels)) == len(labels):
        return labels
    parts = [dict(_caption_parts(i)) if i else {} for i in infos]
    # a run of several capsules differs by them, not by its mesh's 'a capsule'
    same = [{**p, "mesh": p["mesh"].replace(" a capsule)", ")")} if "mesh" in p else p for p in parts]
    keys = [k for k in ("capsules", "law", "mesh", "shape") if len({p.get(k) for p in same}) > 1]
    out = [", ".join([label] + [p[k] for k in keys if k in p]) for label, p in zip(labels, parts)]
    if len(set(out)) < len(out):
        out = [f"{label} ({Path(str(run)).stem})" if not isinstance(run, dict) else label for label, run in zip(out, runs)]
    return out


def theta_for_plot(t: np.ndarray, theta: np.ndarray, D: np.ndarray, unwrap: bool = False) -> np.ndarray:
    """θ with NaN where it is not defined (D_xy below THETA_MIN_D of the run's largest,
    e.g. a sphere at kt = 0) and, unless ``unwrap``, NaN inserted where θ wraps
    between ±π/2 so that no vertical line joins the two sides. With ``unwrap`` θ is
    continued through ±π/2 (a tumbling capsule's angle keeps falling). Returns
    (t, θ) of equal length (a wrap adds one point)."""
    theta = np.asarray(theta, dtype=np.float64).copy()
    D = np.asarray(D, dtype=np.float64)
    finite = D[np.isfinite(D)]
    d_max = float(np.max(np.abs(finite))) if finite.size else 0.0
    undefined = ~(np.abs(D) > max(1e-9, THETA_MIN_D * d_max))
    theta[undefined] = np.nan
    t = np.asarray(t, dtype=np.float64)
    if unwrap:
        ok = np.isfinite(theta)
        if ok.any():
            theta[ok] = np.unwrap(theta[ok], period=math.pi)
        return t, theta
    jumps = np.flatnonzero(np.abs(np.diff(theta)) > 0.5 * math.pi)
    if jumps.size:
        t = np.insert(t, jumps + 1, np.nan)
        theta = np.insert(theta, jumps + 1, np.nan)
    return t, theta


def _plot_runs(ax, source, name: str, scale: float = 1.0, unwrap: bool = False,
               labels: Sequence[str] | None = None) -> list[tuple[dict, np.ndarray, np.ndarray, str]]:
    """Series ``name`` (divided by ``scale``) against kt: one run in black, several
    in colours labelled by what differs between them. θ is drawn only where
    defined and broken (or unwrapped) at ±π/2. Returns (case info, t, values,
    colour for its theory curves) per run."""
    runs = _sources(source)
    single = len(runs) == 1
    loaded = [_load_run(run) for run in runs]
    infos = [_case_info(data) for data in loaded]
    same_shape = all(i and infos[0] and _shape_text(i) == _shape_text(infos[0]) for i in infos)
    # runs that differ only in their shape are labelled by it (G, λ, κ are in the caption)
    only_shape = not same_shape and all(i for i in infos) and all(
        (i["G"], i["lam"], i.get("bending")) == (infos[0]["G"], infos[0]["lam"], infos[0].get("bending"))
        for i in infos)
    if labels is not None and len(labels) != len(runs):
        raise ValueError(f"--label given {len(labels)} times for {len(runs)} runs: give one per PATH, in order")
    auto = ["capsim"] if single else [_shape_text(i) if only_shape else _run_label(i, same_shape) for i in infos]
    given = labels is not None
    labels = list(labels) if labels is not None else _distinct(auto, infos, runs)
    drawn = []
    for i, (data, info) in enumerate(zip(loaded, infos)):
        t, values = _series(data, "t"), _series(data, name)
        color = "k" if single else f"C{i % 10}"
        if values.ndim == 2:  # several capsules (issue 43): one line per capsule
            prefix = labels[i] if given or not single else None  # one run: 'capsule j' alone
            drawn.append((info,) + _plot_capsules(ax, data, t, values, name, scale, unwrap, prefix,
                                                  None if single else color))
            continue
        if name == "theta":
            t, values = theta_for_plot(t, values, _series(data, "D_xy"), unwrap=unwrap)
        values = values / scale
        ax.plot(t, values, "-", color=color, label=labels[i])
        drawn.append((info, t, values, "C0" if single else color))
    _caption(ax.figure, [info for info, *_ in drawn])
    return drawn


def _plot_capsules(ax, data, t, values, name, scale, unwrap, prefix, color):
    """A run of several capsules in a time-series figure: each capsule's column (θ drawn where
    defined), in its own colour and labelled 'capsule j' (``color`` given: in that colour, the
    run's among overlaid runs, each capsule in its own line style). Returns (t, every drawn
    value, the colour of its theory curves)."""
    D = _series(data, "D_xy") if name == "theta" else None
    looks = _capsule_looks(values.shape[1])
    shown = []
    for j in range(values.shape[1]):
        tj, vj = t, values[:, j]
        if name == "theta":
            tj, vj = theta_for_plot(t, vj, D[:, j], unwrap=unwrap)
        vj = vj / scale
        look, label = looks[j]
        if color is None:
            ax.plot(tj, vj, "-", color=look, label=label if prefix is None or label is None else f"{prefix}, {label}")
        else:
            ax.plot(tj, vj, _CAPSULE_STYLES[j % len(_CAPSULE_STYLES)], color=color,
                    label=f"{prefix}, capsule {j}" if label is not None else None)
        shown.append(vj)
    return t, np.concatenate(shown), "k" if color is None else color


def deformation_figure(source, theory: bool = True, labels: Sequence[str] | None = None):
    """D_xy(t) with the first-order transient D∞(1 − e^{−t/τ}) and D∞.

    Several runs (a list) are overlaid in colours, each with its own theory curve
    (seed figs 4–6).
    """
    fig = _figure()
    ax = fig.add_subplot()
    drawn = _plot_runs(ax, source, "D_xy", labels=labels)
    single = len(drawn) == 1
    for i, (info, t, D, color) in enumerate(drawn):
        if not (theory and _theory_applies(info)):
            continue
        first = info["first_order"]
        D_inf = first.D_over_G * info["G"]
        ax.axhline(D_inf, color=color, ls=":", lw=1,
                   label=rf"$D_\infty = {first.label}$ ({first.source})" if i == 0 else None)
        tau = relaxation_time(info["G"], info["lam"]) if first.transient else None
        if tau is not None:
            tt = np.linspace(0.0, max(float(t[-1]), 0.0), 200)
            label = rf"first order, $k\tau$ = {tau:.3g}" if single else ("first order" if i == 0 else None)
            ax.plot(tt, D_inf * (1.0 - np.exp(-tt / tau)), "--", color=color, lw=1, label=label)
    if not single:
        # first-order curves of the larger G run far above the data (D∞ = 25G/4 > 1): keep the data in view
        ax.set_ylim(0.0, 1.15 * max(float(np.nanmax(D)) for _, _, D, _ in drawn))
    ax.set_xlabel(r"$kt$")
    ax.set_ylabel(r"$D_{xy}$")
    _tag(ax, x=("t", "$t$"))
    _legend(ax)
    return fig


def inclination_figure(source, theory: bool = True, unwrap: bool = False, labels: Sequence[str] | None = None):
    """θ/π against kt (several runs overlaid when given a list), with the first-order
    π/4 when one of the runs is a small-deformation sphere. θ is left out where it
    is undefined and broken where it wraps at ±π/2 (``unwrap``: continued instead)."""
    fig = _figure()
    ax = fig.add_subplot()
    drawn = _plot_runs(ax, source, "theta", math.pi, unwrap=unwrap, labels=labels)
    angles = {info["first_order"].theta for info, *_ in drawn if _theory_applies(info)} - {None}
    if theory and len(angles) == 1:  # the flow kind's first-order θ (shear: π/4; extension: none)
        first = next(info["first_order"] for info, *_ in drawn if _theory_applies(info))
        ax.axhline(first.theta / math.pi, color=drawn[0][3] if len(drawn) == 1 else "k", ls="--", lw=1,
                   label=rf"first order, $\theta = \pi/4$ ({first.source})" if first.theta == math.pi / 4
                   else rf"first order, $\theta/\pi = {first.theta / math.pi:.3g}$ ({first.source})")
    ax.set_xlabel(r"$kt$")
    ax.set_ylabel(r"$\theta/\pi$")
    _tag(ax, x=("t", "$t$"))
    if not unwrap and any(np.nanmin(v) < -0.1 for _, _, v, _ in drawn if np.isfinite(v).any()):
        ax.set_ylim(-0.52, 0.52)  # a tumbling run: the whole range of θ, broken at ±π/2
    _legend(ax)
    return fig


_RHEOLOGY_PHYSICAL = {"Sxy_star": r"$S_{xy}$", "N1_star": r"$S_{xx} - S_{yy}$", "N2_star": r"$S_{yy} - S_{zz}$"}


def rheology_figure(source, theory: bool = True):
    """S*_xy, N1*, N2* against kt (first-order values as dotted lines)."""
    data = _load_run(source)
    info = _case_info(data)
    t = _series(data, "t")
    fig = _figure()
    ax = fig.add_subplot()
    first = {}
    if theory and _theory_applies(info):
        # no N2* line: the old derived −N1*/2 was not borne out (REPRODUCTION.md, "N2*"); docs/known_answers.md now gives −(29/7)G
        fo = info["first_order"]  # S*_xy and N1* only where the flow kind derives them (shear)
        first = {k: v for k, v in (("Sxy_star", fo.Sxy_star),
                                   ("N1_star", None if fo.N1_over_G is None else fo.N1_over_G * info["G"]))
                 if v is not None}
    labels = {"Sxy_star": r"$S^*_{xy}$", "N1_star": r"$N_1^*$", "N2_star": r"$N_2^*$"}
    k = capsule_count(data)
    for i, (name, label) in enumerate(labels.items()):
        values = _series(data, name)
        if values.ndim == 2:  # several capsules (issue 43): the quantity's colour, each capsule's line style
            _rheology_capsules(ax, data, t, values, name, label, f"C{i}")
        else:
            line, = ax.plot(t, values, color=f"C{i}", label=label)
            line.physical_label = _RHEOLOGY_PHYSICAL[name]
        if name in first:
            ax.axhline(first[name], color=f"C{i}", ls=":", lw=1)
    if k > 1:  # which line is which capsule
        if k <= len(_CAPSULE_STYLES):
            for j in range(k):
                ax.plot([], [], _CAPSULE_STYLES[j], color="0.35", label=f"capsule {j}")
        else:
            ax.plot([], [], "-", color="0.35", lw=0.6, label=f"capsules 0 to {k - 1}")
            ax.plot([], [], "-", color="0.35", lw=2.0, label="mean over the capsules")
    if first:
        ax.plot([], [], "k:", lw=1, label="first order (one capsule)" if k > 1 else "first order")
    ax.set_xlabel(r"$kt$")
    ax.set_ylabel(r"$S^*_{xy}$, $N_1^*$, $N_2^*$")
    _tag(ax, x=("t", "$t$"), y=("Sxy_star", r"stresslet $S_{xy}$, $S_{xx} - S_{yy}$, $S_{yy} - S_{zz}$"))
    _caption(fig, [info])
    _legend(ax)
    return fig


def _rheology_capsules(ax, data, t, values, name, label, color) -> None:
    """One quantity of the rheology figure for several capsules: up to four capsules in line
    styles of its colour; more as thin lines with the mean over the capsules (the suspension's
    column where the run has it) drawn thick."""
    k = values.shape[1]
    if k <= len(_CAPSULE_STYLES):
        for j in range(k):
            line, = ax.plot(t, values[:, j], _CAPSULE_STYLES[j], color=color, label=label if j == 0 else None)
            line.physical_label = _RHEOLOGY_PHYSICAL[name]
        return
    for j in range(k):
        ax.plot(t, values[:, j], "-", color=color, lw=0.6, alpha=0.5)
    mean = data["timeseries"].get(f"suspension_{name}")
    mean = np.asarray(mean, dtype=np.float64) if mean is not None else values.mean(axis=1)
    line, = ax.plot(t, mean, "-", color=color, lw=2.0, label=label)
    line.physical_label = _RHEOLOGY_PHYSICAL[name]


# ------------------------------------------------------------ xy-plane section


def _quadratic_shape(xi: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """The six quadratic shape functions (..., 6) at (ξ, η): corners (0,0), (1,0), (0,1),
    then the mid-sides of edges 01, 12, 20 (capsim's node order)."""
    l0 = 1.0 - xi - eta
    return np.stack([l0 * (2 * l0 - 1), xi * (2 * xi - 1), eta * (2 * eta - 1),
                     4 * l0 * xi, 4 * xi * eta, 4 * eta * l0], axis=-1)


def _parameter_grid(m: int):
    """The m² small triangles of the parameter triangle: grid points (P, 2) in (ξ, η), their
    edges (L, 2), each small triangle's three edges (T, 3), and for each edge where it lies
    on the element's boundary: (element edge 0/1/2 or −1 inside, its index along that edge
    counted from the edge's first corner)."""
    grid = [(i, j) for j in range(m + 1) for i in range(m + 1 - j)]
    index = {ij: k for k, ij in enumerate(grid)}
    edge_index: dict[tuple[int, int], int] = {}
    edges: list[tuple[int, int]] = []

    def edge(p, q):
        key = (min(p, q), max(p, q))
        if key not in edge_index:
            edge_index[key] = len(edges)
            edges.append(key)
        return edge_index[key]

    triangles = []
    for (i, j) in grid:
        if (i + 1, j) in index and (i, j + 1) in index:
            a, b, c = index[(i, j)], index[(i + 1, j)], index[(i, j + 1)]
            triangles.append((edge(a, b), edge(b, c), edge(c, a)))
        if (i + 1, j + 1) in index:
            a, b, c = index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]
            triangles.append((edge(a, b), edge(b, c), edge(c, a)))
    on_side = []
    for a, b in edges:
        (ia, ja), (ib, jb) = grid[a], grid[b]
        if ja == jb == 0:                       # side 0 → 1 (η = 0), counted from corner 0
            on_side.append((0, min(ia, ib)))
        elif ia + ja == ib + jb == m:           # side 1 → 2, counted from corner 1
            on_side.append((1, min(ja, jb)))
        elif ia == ib == 0:                     # side 2 → 0, counted from corner 2
            on_side.append((2, min(m - ja, m - jb)))
        else:
            on_side.append((-1, 0))
    return np.array(grid, dtype=np.float64) / m, np.array(edges), np.array(triangles), on_side


_SIDE_CORNERS = ((0, 1), (1, 2), (2, 0))


def section_loops(x: np.ndarray, elements: np.ndarray, z0: float = 0.0, values=None,
                  m: int = SECTION_SUBDIVISIONS) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """The closed curves where the curved surface meets the plane z = z0, traced along the mesh.

    Each quadratic element's parameter triangle is cut into m² small triangles; z is
    evaluated on the curved element at their corners; a small triangle whose corners lie
    on both sides of the plane holds one piece of the cut, from one of its edges to
    another (marching triangles). The crossing on an edge is the root of z along it (a
    quadratic in the edge parameter, the map being quadratic), mapped to the surface. An
    edge on an element's side is named by its side's two corner nodes and its place along
    the side, so the pieces of neighbouring elements join exactly; the pieces are then
    chained into closed loops. Nothing is ordered by angle, so a cut that is not
    star-shaped (a deformed red cell's S) is drawn as it is. Points with z within
    1e-12 × the size of the plane count as on it, and on-plane counts as above, so every
    crossing is seen the same way from both sides.

    Returns [(points (n, 3), values (n, ...) or None)], each loop counter-clockwise seen
    from +z, not repeating its first point, longest loop first.
    """
    x = np.asarray(x, dtype=np.float64)
    e = np.asarray(elements)
    uv, edges, triangles, on_side = _parameter_grid(m)
    xe = x[e]                                              # (E, 6, 3)
    N = _quadratic_shape(uv[:, 0], uv[:, 1])               # (P, 6)
    z = np.einsum("pk,ek->ep", N, xe[:, :, 2]) - z0        # (E, P)
    z[np.abs(z) <= 1e-12 * max(1.0, float(np.abs(x).max()))] = 0.0
    above = z >= 0.0
    edge_cross = above[:, edges[:, 0]] != above[:, edges[:, 1]]          # (E, L)
    tri_cross = edge_cross[:, triangles]                                  # (E, T, 3)
    el, tr = np.nonzero(tri_cross.any(axis=2))
    if el.size == 0:
        raise ValueError(f"the surface does not meet the plane z = {z0:g}")

    def name(element: int, local_edge: int) -> tuple[int, int, int]:
        side, k = on_side[local_edge]
        if side < 0:
            return (-1 - element, local_edge, 0)
        c0, c1 = (int(e[element, c]) for c in _SIDE_CORNERS[side])
        return (c0, c1, k) if c0 < c1 else (c1, c0, m - 1 - k)

    neighbours: dict[tuple, list[tuple]] = {}
    where: dict[tuple, tuple[int, int]] = {}
    for element, t in zip(el.tolist(), tr.tolist()):
        ends = [triangles[t, j] for j in range(3) if tri_cross[element, t, j]]
        a, b = (name(element, int(le)) for le in ends)
        where.setdefault(a, (element, int(ends[0])))
        where.setdefault(b, (element, int(ends[1])))
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    bad = [k for k, v in neighbours.items() if len(v) != 2]
    if bad:
        raise ValueError(f"the cut z = {z0:g} is not a set of closed curves ({len(bad)} open ends): "
                         "is the surface closed?")
    keys = list(where)
    at_el = np.array([where[k][0] for k in keys])
    at_ed = np.array([where[k][1] for k in keys])
    pts, vals = _edge_crossings(xe, e, z, z0, uv, edges, at_el, at_ed, values)
    position = {k: i for i, k in enumerate(keys)}

    loops = []
    seen: set = set()
    for start in keys:
        if start in seen:
            continue
        chain, previous, here = [], None, start
        while here not in seen:
            seen.add(here)
            chain.append(position[here])
            a, b = neighbours[here]
            previous, here = here, (b if a == previous else a)
        idx = np.array(chain)
        # a crossing exactly at a grid point is found on several edges: keep it once
        step = np.linalg.norm(np.diff(pts[idx], axis=0, append=pts[idx[:1]]), axis=1)
        idx = idx[step > 1e-12 * max(1.0, float(np.abs(x).max()))] if (step > 0).any() else idx
        p = pts[idx]
        if _shoelace(p) < 0.0:
            idx = idx[::-1]
        loops.append((pts[idx], vals[idx] if vals is not None else None))
    loops.sort(key=lambda loop: -_perimeter(loop[0]))
    return loops


def _edge_crossings(xe, e, z, z0, uv, edges, el, ed, values):
    """Points (and values) where z = 0 on the small edges `ed` of elements `el`."""
    a, b = edges[ed, 0], edges[ed, 1]
    uva, uvb = uv[a], uv[b]
    z0e, z1e = z[el, a], z[el, b]
    mid = 0.5 * (uva + uvb)
    zm = np.einsum("ck,ck->c", _quadratic_shape(mid[:, 0], mid[:, 1]), xe[el, :, 2]) - z0
    # z(s) = z0 + B s + A s², through z(0), z(1/2), z(1)
    B = -3.0 * z0e + 4.0 * zm - z1e
    A = 2.0 * z0e - 4.0 * zm + 2.0 * z1e
    with np.errstate(invalid="ignore", divide="ignore"):
        s_lin = np.where(z0e == z1e, 0.0, z0e / (z0e - z1e))
        disc = np.sqrt(np.maximum(B * B - 4.0 * A * z0e, 0.0))
        roots = np.stack([(-B + disc) / (2.0 * A), (-B - disc) / (2.0 * A)], 1)
    ok = np.isfinite(roots) & (roots >= -1e-12) & (roots <= 1 + 1e-12)
    dist = np.where(ok, np.abs(roots - s_lin[:, None]), np.inf)
    best = np.take_along_axis(roots, np.argmin(dist, 1)[:, None], 1)[:, 0]
    straight = np.abs(A) <= 1e-12 * (np.abs(B) + np.abs(z0e) + np.abs(z1e))
    s = np.clip(np.where(straight | ~np.isfinite(np.min(dist, 1)), s_lin, best), 0.0, 1.0)
    at = uva + s[:, None] * (uvb - uva)
    Nc = _quadratic_shape(at[:, 0], at[:, 1])
    pts = np.einsum("ck,ckd->cd", Nc, xe[el])
    pts[:, 2] = z0
    vals = None
    if values is not None:
        v = np.asarray(values, dtype=np.float64)
        vals = np.einsum("ck,ck...->c...", Nc, v[e[el]])
    return pts, vals


def _shoelace(p: np.ndarray) -> float:
    """Signed area enclosed by the closed polygon p (n, ≥2) in the xy-plane (> 0 counter-clockwise)."""
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _perimeter(p: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(p, axis=0, append=p[:1]), axis=1).sum())


def xy_section(
    x: np.ndarray, elements: np.ndarray, z0: float = 0.0, values: np.ndarray | None = None,
    curved: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Points where the surface meets the plane z = z0.

    ``curved=True`` (what the figures use): the longest closed curve of
    :func:`section_loops`, traced along the curved elements in order (right for
    any shape, convex or not), values interpolated with the quadratic shape
    functions; the figures draw every loop.
    Default (``curved=False``, a coarse check): the quadratic triangles are split into four
    straight ones and each edge that crosses the plane contributes one point
    (nodes exactly on the plane count as above it, so every crossing is found
    once), ordered by angle about their mean, which is right only for a star-shaped
    cut; ``values`` (N_p, ...) are interpolated linearly to the points.
    Returns (points (n, 3), values (n, ...)).
    """
    x = np.asarray(x, dtype=np.float64)
    if curved:
        return section_loops(x, elements, z0, values)[0]
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
    return _merge_and_order(pts, vals)


def _merge_and_order(pts: np.ndarray, vals):
    # Crossings at a node shared by several edges appear once per edge: merge them.
    key = np.round(pts / 1e-10).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)
    pts = pts[first]
    vals = vals[first] if vals is not None else None
    c = pts.mean(axis=0)
    order = np.argsort(np.arctan2(pts[:, 1] - c[1], pts[:, 0] - c[0]))
    return pts[order], (vals[order] if vals is not None else None)


def _arc_length_from_largest_x(p: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """s/L along a closed loop (counter-clockwise, from its point of largest x, ending where it
    began) and the values there: a coordinate that stays monotone on any cut, unlike the
    polar angle, which doubles back on a cut that is not star-shaped."""
    start = int(np.argmax(p[:, 0]))
    p, v = np.roll(p, -start, axis=0), np.roll(v, -start, axis=0)
    p, v = _closed(p), _closed(v)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    return s / s[-1], v


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
    several = capsule_count(data) > 1
    if several:  # several capsules (issue 43): every capsule's outline, each numbered
        _contour_capsules(ax, data, idx, z0)
    else:
        for j, k in enumerate(idx):
            for n, (p, _) in enumerate(section_loops(data["positions"][k], data["elements"], z0)):
                p = _closed(p)
                ax.plot(p[:, 0], p[:, 1], color=f"C{j % 10}", label=f"kt = {snap_t[k]:.3g}" if n == 0 else None)
    _draw_wall(ax, info)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(r"$x/a$")
    ax.set_ylabel(r"$y/a$")
    _tag(ax, x=("centroid_x", "$x$"), y=("centroid_y", "$y$"))
    extra = [f"section z = {z0:g}"] if z0 else []
    if several:
        extra.append("numbers: capsule index")
    _caption(fig, [info], extra="; ".join(extra))
    _legend(ax)
    return fig


def capsule_sections(x: np.ndarray, elements: np.ndarray, bodies, z0: float = 0.0, values=None
                     ) -> list[list[tuple[np.ndarray, np.ndarray | None]]]:
    """Each capsule's :func:`section_loops` at z = z0 (its block of the union's elements), []
    for a capsule the plane misses; ValueError when it misses every capsule."""
    out = []
    for i in range(bodies.count):
        try:
            out.append(section_loops(x, elements[bodies.elements(i)], z0, values))
        except ValueError as exc:
            if "does not meet" not in str(exc):
                raise
            out.append([])
    if not any(out):
        raise ValueError(f"the surface does not meet the plane z = {z0:g}")
    return out


def _contour_capsules(ax, data: dict[str, Any], idx: np.ndarray, z0: float) -> None:
    """The sections of every capsule at the chosen snapshots (one colour per time) and each
    capsule's index at the centre of its last section."""
    bodies = scene_bodies(data)
    elements = np.asarray(data["elements"])
    snap_t = np.asarray(data["snapshot_t"])
    last = []
    for j, k in enumerate(idx):
        labelled = False
        last = capsule_sections(np.asarray(data["positions"][k], dtype=np.float64), elements, bodies, z0)
        for loops in last:
            for p, _ in loops:
                p = _closed(p)
                ax.plot(p[:, 0], p[:, 1], color=f"C{j % 10}", label=None if labelled else f"kt = {snap_t[k]:.3g}")
                labelled = True
    for i, loops in enumerate(last):
        if loops:
            c = loops[0][0].mean(axis=0)
            ax.text(c[0], c[1], str(i), ha="center", va="center", fontsize="small", color="0.3")


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
            loops = section_loops(pos[k], data["elements"])
        except ValueError:
            continue
        for n, (p, _) in enumerate(loops):
            p = _closed(p)
            ax.plot(p[:, 0], p[:, 1], color=style, lw=0.8, ls="--", label=label if n == 0 else None)
    label = f"node {node}"
    if capsule_count(data) > 1:  # several capsules (issue 43): whose node it is
        label += f" (capsule {int(scene_bodies(data).node_body[node])})"
    ax.plot(path[:, 0], path[:, 1], "C3.-", label=label)
    ax.plot(path[:1, 0], path[:1, 1], "C3o", mfc="none", ms=9, label=f"kt = {data['snapshot_t'][0]:.3g}")
    _draw_wall(ax, info)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(r"$x/a$")
    ax.set_ylabel(r"$y/a$")
    _tag(ax, x=("centroid_x", "$x$"), y=("centroid_y", "$y$"))
    _caption(fig, [info])
    _legend(ax)
    fig.path_node = node  # the chosen node, for callers and tests
    return fig


# ------------------------------------------------------------ scenes (issue 54): lift, migration, separation
#
# lift: a capsule near a plane wall, its lift V_y and its slip against the wall distance h (log-log),
# one curve per G, from a campaign summary or from several run files, with the far-field laws of the
# run's own stresslet S beside them (docs/known_answers.md, "A capsule near a wall"; Blake's image of
# the force dipole at the capsule's centre, S in units μka³): V_y = −(9/64π) S_yy/h² (Smart &
# Leighton 1991) and V_x − u∞ = −(3/32π) S_xy/h² (for a rigid sphere, S_xy = (10π/3) μka³, Goldman,
# Cox & Brenner 1967's −(5/16) k a³/h²), with S_yy = (5/2) V (N2* − N1*)/3 of the traceless stresslet
# and S_xy = (5/2) V S*_xy. migration: the cross-stream position against kt, several runs overlaid
# (near a wall the height above it with the far-field law integrated along the run's own stresslet,
# h³(t) = h³(0) + 3 ∫ −(9/64π) S_yy dt; in Poiseuille flow the distance from the centreline; in a
# conduit axis_offset; else centroid_y). separation: a pair's Δy against Δx and against kt, several
# pairs overlaid; more than two capsules: each centroid's path.

#: where the far-field laws come from (legend text)
LIFT_SOURCE = "Smart & Leighton 1991"
#: the slip's coefficient is the image system's (checked against capsim's kernel); for a rigid sphere
#: it is Goldman, Cox & Brenner's far field
SLIP_SOURCE = "Goldman, Cox & Brenner 1967"
#: the volume of every rest shape in units of a³ (a is the equal-volume radius)
REST_VOLUME = 4.0 * math.pi / 3.0


def stresslet_yy(N1_star, N2_star, volume=REST_VOLUME):
    """S_yy of the traceless stresslet in units μka³, from N1* = (S_xx − S_yy)/((5/2)μkV) and N2*."""
    return 2.5 * np.asarray(volume) * (np.asarray(N2_star) - np.asarray(N1_star)) / 3.0


def lift_law(h, N1_star, N2_star, volume=REST_VOLUME):
    """The far-field lift V_y/(ka) = −(9/64π) S_yy/h² of a capsule h above the wall."""
    return -9.0 / (64.0 * math.pi) * stresslet_yy(N1_star, N2_star, volume) / np.asarray(h, float) ** 2


def slip_law(h, Sxy_star, volume=REST_VOLUME):
    """The far-field slip (V_x − u∞)/(ka) = −(3/32π) S_xy/h², S_xy = (5/2) V S*_xy."""
    return -3.0 / (32.0 * math.pi) * 2.5 * np.asarray(volume) * np.asarray(Sxy_star) / np.asarray(h, float) ** 2


# ------------------------------------------------------------ lift


def _plane_wall(info: dict[str, Any]):
    """The scene's boundary of kind plane_wall (its ``height`` along y), or None: the far-field laws are a plane's."""
    return next((b for b in info.get("boundaries", ()) if getattr(b, "name", "") == "plane_wall"), None)


def _is_summary(source) -> bool:
    try:
        import xarray as xr

        if isinstance(source, xr.Dataset):
            return True
    except ImportError:  # pragma: no cover - xarray is a dependency
        pass
    if isinstance(source, (str, os.PathLike)):
        from capsim.storage.store import is_run_file

        return not is_run_file(source)
    return False


def _lift_records_from_summary(ds) -> tuple[list[dict], str, list[str]]:
    """(one record per completed run, the caption, what was left out) of a summary."""
    if "centroid_velocity_y" not in ds.variables:
        raise ValueError("the summary has no 'centroid_velocity_y' (is it a capsim summarize output?)")
    swept = _swept_fields(ds)
    # the swept coordinate of the wall's distance (wall: {distance: h}), named by its last part
    h_field = next((f for f in swept if f == "distance" or str(ds[f].attrs.get("case_field", f)).split(".")[-1]
                    == "distance"), None)
    if h_field is None:
        raise ValueError(f"--kind lift draws against the wall distance, and the summary sweeps none (wall: {{distance: h}}) "
                         f"(swept: {', '.join(swept) or 'none'})")
    names = ("centroid_velocity_y", "slip_velocity_x", "N1_star", "N2_star", "Sxy_star", "volume_drift",
             "centroid_velocity_y_std", "slip_velocity_x_std")
    names = tuple(n for n in names if n in ds.variables)
    others = [f for f in swept if f != h_field]
    records, left = [], []
    for cell in _summary_cells(ds, names, swept):
        status = cell["why"] if cell["why"] and not cell["why"].endswith(" motion") else "completed"
        if status != "completed":
            left.append(status)
            continue
        v = cell["values"]
        drift = v.get("volume_drift", float("nan"))
        records.append({
            "h": float(cell["swept"][h_field]),
            "group": ", ".join(f"{_short(f)} = {_shown(cell['swept'][f])}" for f in others) or "capsim",
            "lift": v["centroid_velocity_y"], "slip": v.get("slip_velocity_x", float("nan")),
            "lift_std": v.get("centroid_velocity_y_std", float("nan")),
            "slip_std": v.get("slip_velocity_x_std", float("nan")),
            "N1": v["N1_star"], "N2": v["N2_star"], "Sxy": v["Sxy_star"],
            "V": REST_VOLUME * (1.0 + (drift if math.isfinite(drift) else 0.0)),
        })
    context = _summary_context(ds)
    title = str(ds.attrs.get("title", ""))
    parts = [context[k] for k in ("shape", "law", "lam", "mesh") if context.get(k)]
    return records, (f"{title}: " if title else "") + ", ".join(parts), left


def _lift_records_from_runs(sources) -> tuple[list[dict], list[dict], list[str]]:
    """(one record per run, their case infos, nothing left out) of run files beside a wall."""
    from capsim.face.export import case_of

    records, infos = [], []
    for run in _sources(sources):
        data = _load_run(run)
        case = case_of(data)
        name = Path(str(run)).name if not isinstance(run, dict) else "the run"
        wall = _plane_wall(info := _case_info(data))
        if wall is None:
            raise ValueError(f"--kind lift draws a capsule near a wall, and {name} has none (wall: {{distance: h}})")
        if capsule_count(data) > 1:
            raise ValueError(f"--kind lift draws one capsule near a wall, and {name} holds {capsule_count(data)}")
        summary = data.get("summary") or {}
        ts = data["timeseries"]

        def value(key):
            v = summary.get(key)
            if isinstance(v, (int, float)) and math.isfinite(v):
                return float(v)
            return float(np.asarray(ts[key])[-1]) if key in ts else float("nan")

        infos.append(info)
        volume = np.asarray(ts.get("volume", [REST_VOLUME]), float)
        records.append({
            "h": float(case.center[1]) - wall.height, "group": _run_label(info, shape_in_caption=True),
            "lift": value("centroid_velocity_y"), "slip": value("slip_velocity_x"),
            "lift_std": float(summary.get("centroid_velocity_y_std", float("nan")) or float("nan")),
            "slip_std": float(summary.get("slip_velocity_x_std", float("nan")) or float("nan")),
            "N1": value("N1_star"), "N2": value("N2_star"), "Sxy": value("Sxy_star"), "V": float(volume[-1]),
        })
    return records, infos, []


def lift_figure(source, theory: bool = True, labels: Sequence[str] | None = None):
    """Lift V_y/(ka) (top) and slip −(V_x − u∞)/(ka) (bottom) against h/a, the wall's distance
    below the capsule's initial centre, one curve per G (per combination of the other swept
    values), from a campaign summary or from run files (a list); the far-field laws of each
    run's own stresslet dashed beside them. Log axes where every drawn value is positive.
    ``fig.lift_curves``: {group: {"h", "lift", "slip", "lift_law", "slip_law"}} for callers."""
    if _is_summary(source) and not isinstance(source, (list, tuple)):
        import xarray as xr

        ds = source if isinstance(source, xr.Dataset) else xr.load_dataset(source)
        records, caption, left = _lift_records_from_summary(ds)
        infos = None
    else:
        records, infos, left = _lift_records_from_runs(source)
        caption = ""
    if not records:
        raise ValueError("--kind lift: no completed run to draw" + (f" ({len(left)} not completed)" if left else ""))
    groups: dict[str, list[dict]] = {}
    for r in records:
        groups.setdefault(r["group"], []).append(r)
    if labels is not None:
        if len(labels) != len(groups):
            raise ValueError(f"--label given {len(labels)} times for {len(groups)} curves (one per G): give one each")
        groups = dict(zip(labels, groups.values()))
    fig = _figure(figsize=(FIGSIZE[0], 1.25 * FIGSIZE[1]))
    ax_l, ax_s = fig.subplots(2, 1, sharex=True)
    curves = {}
    for j, (label, members) in enumerate(groups.items()):
        members = sorted(members, key=lambda r: r["h"])
        h = np.array([r["h"] for r in members])
        lift = np.array([r["lift"] for r in members])
        lag = -np.array([r["slip"] for r in members])  # the slip is negative: the capsule lags the shear
        color = f"C{j % 10}"
        ax_l.plot(h, lift, "o-", color=color, ms=4, label=label)
        ax_s.plot(h, lag, "s-", color=color, ms=4)  # the top panel's legend names the curves
        for ax, key, sign in ((ax_l, "lift_std", 1.0), (ax_s, "slip_std", -1.0)):
            err = np.array([r[key] for r in members])
            if np.isfinite(err).any():
                y = lift if ax is ax_l else lag
                ax.errorbar(h, y, yerr=np.where(np.isfinite(err), err, 0.0), fmt="none", ecolor=color,
                            elinewidth=0.8, capsize=2)
        law_l = lift_law(h, [r["N1"] for r in members], [r["N2"] for r in members], [r["V"] for r in members])
        law_s = slip_law(h, [r["Sxy"] for r in members], [r["V"] for r in members])
        curves[label] = {"h": h, "lift": lift, "slip": -lag, "lift_law": law_l, "slip_law": law_s}
    if theory:  # after the data: the legend lists the curves first
        for j, c in enumerate(curves.values()):
            color = f"C{j % 10}"
            ax_l.plot(c["h"], c["lift_law"], "--", color=color, lw=1,
                      label=f"far field ({LIFT_SOURCE})" if j == 0 else None)
            ax_s.plot(c["h"], -c["slip_law"], "--", color=color, lw=1,
                      label=f"far field ({SLIP_SOURCE})" if j == 0 else None)
    for ax, key in ((ax_l, "lift"), (ax_s, "slip")):
        drawn = np.concatenate([np.concatenate([c[key] * (1 if key == "lift" else -1),
                                                (c[f"{key}_law"] * (1 if key == "lift" else -1)) if theory else []])
                                for c in curves.values()])
        if drawn.size and np.all(np.isfinite(drawn) & (drawn > 0)):
            ax.set_yscale("log")
    hs = np.concatenate([c["h"] for c in curves.values()])
    if np.all(hs > 0) and len(np.unique(hs)) > 1:  # log-log: the laws are straight lines of slope −2
        ax_s.set_xscale("log")
        from matplotlib.ticker import NullFormatter, ScalarFormatter

        ax_s.set_xticks(np.unique(hs))
        ax_s.xaxis.set_major_formatter(ScalarFormatter())
        ax_s.xaxis.set_minor_formatter(NullFormatter())
    ax_l.set_ylabel(r"lift $V_y/(ka)$")
    ax_s.set_ylabel(r"slip $-(V_x - u^\infty)/(ka)$")
    ax_s.set_xlabel(r"$h/a$ (wall to the capsule's initial centre)")
    _legend(ax_l)
    _legend(ax_s)
    note = ("points: each run's window mean ± its standard deviation; dashed: the far-field laws of each run's own "
            "stresslet S (units μka³), lift −(9/64π) S_yy/h², slip −(3/32π) S_xy/h²")
    if left:
        note += f"; {len(left)} run(s) not completed left out ({', '.join(sorted(set(left)))})"
    if infos is not None:
        _caption(fig, infos, extra=note)
    else:
        _supxlabel(fig, "\n".join(t for t in (caption, note) if t))
    fig.lift_curves = curves
    return fig


# ------------------------------------------------------------ migration


def _cross_stream(data: dict[str, Any], case) -> tuple[np.ndarray, str, str]:
    """(the cross-stream position at every row, its kind, the axis label) of one run."""
    ts = data["timeseries"]
    cy = np.asarray(ts["centroid_y"], float)
    if "axis_offset" in ts:
        return np.asarray(ts["axis_offset"], float), "conduit", r"distance from the axis $r_c/a$"
    wall = _plane_wall(_case_info(data))
    if wall is not None:
        return cy - wall.height, "wall", r"height above the wall $(y_c - y_w)/a$"
    if case.flow.kind == "poiseuille":
        cz = np.asarray(ts["centroid_z"], float)
        return np.hypot(cy, cz), "poiseuille", r"distance from the centreline $r_c/a$"
    return cy, "other", r"$y_c/a$"


def _wall_law_height(data: dict[str, Any], height: np.ndarray) -> np.ndarray:
    """h(t) from the far-field lift of the run's own stresslet at every row, integrated from h(0):
    dh/dt = c(t)/h², c = −(9/64π) S_yy, so h³ = h(0)³ + 3 ∫ c dt (trapezoids)."""
    ts = data["timeseries"]
    t = np.asarray(ts["t"], float)
    volume = np.asarray(ts.get("volume", np.full(t.shape, REST_VOLUME)), float)
    c = lift_law(1.0, np.asarray(ts["N1_star"], float), np.asarray(ts["N2_star"], float), volume)
    integral = np.concatenate([[0.0], np.cumsum(0.5 * (c[1:] + c[:-1]) * np.diff(t))])
    return np.cbrt(height[0] ** 3 + 3.0 * integral)


def migration_figure(source, theory: bool = True, labels: Sequence[str] | None = None):
    """The capsule's cross-stream position against kt, several runs (a list) overlaid: near a
    wall the centroid's height above it (with the far-field lift of the run's own stresslet,
    integrated, dashed), in Poiseuille flow its distance from the centreline, in a conduit from
    the axis, else centroid_y. A run of several capsules: one line per capsule."""
    from capsim.face.export import case_of

    runs = _sources(source)
    loaded = [_load_run(run) for run in runs]
    infos = [_case_info(data) for data in loaded]
    single = len(runs) == 1
    names = _overlay_names(labels, loaded, infos, runs, "capsim")
    fig = _figure()
    ax = fig.add_subplot()
    kinds, ylabels = set(), set()
    laws = []
    for i, (data, info) in enumerate(zip(loaded, infos)):
        case = case_of(data)
        t = _series(data, "t")
        y, kind, ylabel = _cross_stream(data, case)
        kinds.add(kind)
        ylabels.add(ylabel)
        color = "k" if single else f"C{i % 10}"
        if y.ndim == 2:  # several capsules: one line each
            for j, (look, name) in enumerate(_capsule_looks(y.shape[1])):
                ax.plot(t, y[:, j], _CAPSULE_STYLES[j % 4] if not single else "-",
                        color=color if not single else look,
                        label=None if name is None else (name if single else f"{names[i]}, {name}"))
            continue
        ax.plot(t, y, "-", color=color, label=names[i])
        if theory and kind == "wall" and "N1_star" in data["timeseries"]:
            laws.append((t, _wall_law_height(data, y), color))
    for k, (t, h, color) in enumerate(laws):  # after the data: the legend lists the runs first
        ax.plot(t, h, "--", color=color, lw=1, label=f"far field ({LIFT_SOURCE})" if k == 0 else None)
    ax.set_xlabel(r"$kt$")
    ax.set_ylabel(ylabels.pop() if len(ylabels) == 1 else r"cross-stream position $/a$")
    _tag(ax, x=("t", "$t$"), y=("centroid_y", "cross-stream position"))
    extra = "dashed: dh/dt = −(9/64π) S_yy/h² of the run's own stresslet, integrated from h(0)" if laws else ""
    if len(kinds) > 1:
        extra = "; ".join(e for e in (extra, "cross-stream position: near a wall the height above it, in "
                                      "Poiseuille flow or a conduit the distance from the axis") if e)
    _caption(fig, infos, extra=extra)
    _legend(ax)
    return fig


def _overlay_names(labels: Sequence[str] | None, loaded: list[dict], infos: list[dict], runs: list,
                   alone: str) -> list[str]:
    """The legend's names of the runs drawn: the --label texts (one per run), else `alone` for one run
    and :func:`_overlay_labels` for several."""
    if labels is not None and len(labels) != len(runs):
        raise ValueError(f"--label given {len(labels)} times for {len(runs)} runs: give one per PATH, in order")
    if labels is not None:
        return list(labels)
    return [alone] if len(runs) == 1 else _overlay_labels(loaded, infos, runs)


def _overlay_labels(loaded: list[dict], infos: list[dict], runs: list) -> list[str]:
    """Labels of overlaid runs: G and λ (and what else differs: the wall distance, the initial offset
    of a pair, the law, the mesh), else the file's name."""
    from capsim.face.export import case_of

    parts = []
    for data, info in zip(loaded, infos):
        case = case_of(data)
        p = {"G": f"G = {info['G']:g}" if info else "", "lam": f"λ = {info['lam']:g}" if info else ""}
        wall = _plane_wall(info)
        if wall is not None:
            p["h"] = f"h = {float(case.center[1]) - wall.height:g} a"
        p["flow"] = str(case.flow.kind).replace("_", " ")
        ts = data["timeseries"]
        if "separation_y" in ts and len(np.asarray(ts["separation_y"])):
            p["dy0"] = f"Δy₀ = {float(np.asarray(ts['separation_y'])[0]):.3g} a"
        p["center"] = "centre (" + ", ".join(f"{v:g}" for v in case.center) + ")"
        if info:
            p.update({k: v for k, v in _caption_parts(info) if k in ("law", "mesh", "shape")})
        parts.append(p)
    def differ(names):
        return [k for k in names if len({p.get(k, "") for p in parts}) > 1]

    # the initial centre only where nothing else tells the runs apart (a pair's is in its Δy₀)
    keys = differ(("G", "lam", "h", "dy0", "flow", "law", "shape", "mesh")) or differ(("center",))
    out = [", ".join(p[k] for k in keys if p.get(k)) or "capsim" for p in parts]
    if len(set(out)) < len(out):
        out = [f"{o} ({Path(str(r)).stem})" if not isinstance(r, dict) else o for o, r in zip(out, runs)]
    return out


# ------------------------------------------------------------ separation


def separation_figure(source, labels: Sequence[str] | None = None):
    """A pair's separation (issue 43; issue 54): the cross-stream Δy against the streamwise Δx
    (left: the relative trajectory, capsule 1's centroid less capsule 0's, at every step, from its
    start, open circle, to its end, square) and against kt (right), several runs (a list) overlaid
    with labels that tell them apart. One run of more than two capsules: each capsule's centroid
    path in the xy-plane. A run of one capsule is refused (a material point's path: trajectory)."""
    runs = _sources(source)
    loaded = [_load_run(run) for run in runs]
    for run, data in zip(runs, loaded):
        if capsule_count(data) < 2:
            raise ValueError("--kind separation draws the paths of several capsules, and the run holds one "
                             "(a material point's path: --kind trajectory)")
        if len(_series(data, "t")) == 0:
            raise ValueError("the run has no time series")
    if len(loaded) == 1 and not _is_pair(loaded[0]):
        return _centroid_paths(loaded[0])
    if not all(_is_pair(d) for d in loaded):
        raise ValueError("--kind separation overlays pairs (runs of two capsules) only; draw a run of more "
                         "capsules alone (its centroid paths)")
    infos = [_case_info(data) for data in loaded]
    single = len(runs) == 1
    names = _overlay_names(labels, loaded, infos, runs, "relative trajectory")
    fig = _figure(figsize=(1.7 * FIGSIZE[0], FIGSIZE[1]))
    ax, ax_t = fig.subplots(1, 2)
    for i, data in enumerate(loaded):
        t = _series(data, "t")
        dx, dy = _series(data, "separation_x"), _series(data, "separation_y")
        color = "C3" if single else f"C{i % 10}"
        ax.plot(dx, dy, "-", color=color, label=names[i])
        ax.plot(dx[:1], dy[:1], "o", color=color, mfc="none", ms=8,
                label=f"kt = {t[0]:.3g}" if single else None)
        ax.plot(dx[-1:], dy[-1:], "s", color=color, ms=4, label=f"kt = {t[-1]:.3g}" if single else None)
        ax_t.plot(t, dy, "-", color=color, label=names[i] if not single else None)
    ax.set_xlabel(r"$\Delta x/a$")
    ax.set_ylabel(r"$\Delta y/a$")
    _tag(ax, x=("separation_x", r"$\Delta x$"), y=("separation_y", r"$\Delta y$"))
    ax_t.set_xlabel(r"$kt$")
    ax_t.set_ylabel(r"$\Delta y/a$")
    _tag(ax_t, x=("t", "$t$"), y=("separation_y", r"$\Delta y$"))
    extra = "Δx, Δy: capsule 1's centroid less capsule 0's"
    if not single:
        extra += "; circles: the start, squares: the end"
    _caption(fig, infos, extra=extra)
    _legend(ax)
    _legend(ax_t)
    return fig


def _is_pair(data: dict[str, Any]) -> bool:
    ts = data["timeseries"]
    return capsule_count(data) == 2 and "separation_x" in ts and "separation_y" in ts


def _centroid_paths(data: dict[str, Any]):
    """More than two capsules: each capsule's centroid path in the xy-plane, in its colour."""
    info = _case_info(data)
    t = _series(data, "t")
    fig = _figure()
    ax = fig.add_subplot()
    cx, cy = _series(data, "centroid_x"), _series(data, "centroid_y")
    for j, (color, label) in enumerate(_capsule_looks(capsule_count(data))):
        ax.plot(cx[:, j], cy[:, j], "-", color=color, label=label)
        ax.plot(cx[:1, j], cy[:1, j], "o", color=color, mfc="none", ms=7)
        ax.plot(cx[-1:, j], cy[-1:, j], "s", color=color, ms=4)
    _draw_wall(ax, info)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(r"$x/a$")
    ax.set_ylabel(r"$y/a$")
    _tag(ax, x=("centroid_x", "$x$"), y=("centroid_y", "$y$"))
    _caption(fig, [info], extra=f"centroid paths from kt = {t[0]:.3g} (circle) to {t[-1]:.3g} (square)")
    _legend(ax)
    return fig


def tensions_figure(source, t: float | None = None, z0: float = 0.0):
    """Principal tensions τ1 ≥ τ2 (units E_s) along the xy-plane section at the
    snapshot nearest `t` (default: the last), against the arc length along the section
    (the polar angle doubles back on a cut that is not star-shaped)."""
    from capsim.face.export import membrane_fields, model_for

    data = _load_run(source)
    info = _case_info(data)
    k = _snapshot_index(data, t)
    x = np.asarray(data["positions"][k], dtype=np.float64)
    fields = membrane_fields(model_for(data), x)
    values = np.stack([fields["principal_tension_1"], fields["principal_tension_2"]], axis=1)
    fig = _figure()
    ax = fig.add_subplot()
    several = capsule_count(data) > 1
    if several:  # several capsules (issue 43): each capsule along its own section, in its colour
        sections = capsule_sections(x, np.asarray(data["elements"]), scene_bodies(data), z0, values)
        looks = _capsule_looks(len(sections))
        for i, loops in enumerate(sections):
            if not loops:
                continue
            s, v = _arc_length_from_largest_x(*loops[0])
            color, name = looks[i]
            ax.plot(s, v[:, 0], ".-", color=color, label=rf"$\tau_1$, {name}" if name else None)
            ax.plot(s, v[:, 1], ".--", color=color, label=rf"$\tau_2$, {name}" if name else None)
    else:
        p, v = xy_section(x, data["elements"], z0, values, curved=True)
        s, v = _arc_length_from_largest_x(p, v)
        ax.plot(s, v[:, 0], "C0.-", label=r"$\tau_1$")
        ax.plot(s, v[:, 1], "C1.-", label=r"$\tau_2$")
    ax.axhline(0.0, color="0.7", lw=0.8)
    ax.set_xlim(0.0, 1.0)
    ax.set_xlabel(r"arc length along the section, $s/L$")  # from its largest x, counter-clockwise (caption)
    ax.set_ylabel(r"principal tension $/E_s$")
    _tag(ax, y=("G_s", "principal tension"))  # tensions in E_s, the scale of G_s
    where = "each capsule's section" if several else "the section"
    _caption(fig, [info], extra=f"kt = {data['snapshot_t'][k]:.3g}; s from {where}'s largest x, counter-clockwise")
    _legend(ax)
    return fig


# ------------------------------------------------------------ campaign summary


RHEOLOGY_SUMMARY = ("ttf_ratio", "Sxy_star", "N1_star", "N2_star")


#: axis labels of swept fields (others: the field's name)
SWEPT_LABELS = {"shear_rate_G": r"$G = \mu k a / E_s$", "viscosity_ratio": r"viscosity ratio $\lambda$",
                "initial_tilt_deg": "initial tilt (deg)", "bending_modulus": r"bending modulus $\kappa/(E_s a^2)$",
                "capillary_number": r"$\mathrm{Ca} = \mu k a / G_s$", "shear_rate": "shear rate $k$ (1/s)",
                "viscosity": r"viscosity $\mu$ (Pa s)", "radius": "radius $a$ (m)",
                "shear_modulus": "shear modulus $G_s$ (N/m)", "surface_modulus": "modulus $E_s$ (N/m)"}
#: not swept fields, though they are coordinates of a summary
_NOT_SWEPT = ("run", "run_id")


def steady_figure(source, theory: bool = True, x: str | None = None):
    """Steady D_xy and θ/π against a swept field (default G, else the first numeric one)
    from a campaign summary (netCDF or Dataset), grid or zip.

    Only settled runs (``steady_average`` = 1) are points, joined per combination of the
    other swept values, with the window's standard deviation as error bars; the others
    (transient, unstable, not completed) are drawn as grey × without a line and counted in
    the caption, which says what was left out. When the summary holds the tank-treading
    frequency and the stresslet (as `capsim summarize` writes them), a second column shows
    TTF/f_s (seed fig. 11) and S*_xy, N1*, N2* (fig. 13), with their G → 0 limits.
    """
    import xarray as xr

    ds = source if isinstance(source, xr.Dataset) else xr.load_dataset(source)
    for name in ("D_xy", "theta"):
        if name not in ds.variables:
            raise ValueError(f"the summary has no '{name}' (is it a capsim summarize output?)")
    swept = _swept_fields(ds)
    x = _summary_x(ds, swept, x)
    # the quantities the campaign's flow kinds define (Flow.steady_quantities: no θ, S*_xy or
    # tank-treading panel in extension, where symmetry fixes them or they mean nothing)
    kinds, first = _summary_scene(ds)
    defined = {q for kind in kinds for q in FLOWS[kind].steady_quantities}
    stresses = [q for q in ("Sxy_star", "N1_star", "N2_star") if q in defined]
    rheology = all(name in ds.variables for name in RHEOLOGY_SUMMARY) and bool(stresses) and bool(
        np.isfinite(np.asarray(ds[stresses[0]].values, dtype=np.float64)).any()
    )
    has_theta, has_ttf = "theta" in defined, rheology and "ttf_ratio" in defined
    names = ("D_xy", "theta") + (RHEOLOGY_SUMMARY if rheology else ())
    cells = _summary_cells(ds, names, swept)
    # left column D_xy (and θ), right column TTF/f_s (and the stresses); a 2 x 2 grid as before
    # where all four are drawn, else one column
    left = ["D_xy"] + (["theta"] if has_theta else [])
    right = (["ttf_ratio"] if has_ttf else []) + (["stress"] if rheology else [])
    if len(left) == 2 and len(right) == 2:
        fig = _figure(figsize=(1.8 * FIGSIZE[0], FIGSIZE[1]))
        (ax_d, ax_f), (ax_t, ax_s) = fig.subplots(2, 2, sharex=True)
        axes = {"D_xy": ax_d, "theta": ax_t, "ttf_ratio": ax_f, "stress": ax_s}
    else:
        fig = _figure(figsize=(FIGSIZE[0], FIGSIZE[1]))
        made = np.atleast_1d(fig.subplots(len(left + right), 1, sharex=True))
        axes = dict(zip(left + right, made))
        ax_d = axes["D_xy"]
    ax_t, ax_f, ax_s = axes.get("theta"), axes.get("ttf_ratio"), axes.get("stress")
    styles = {"Sxy_star": ("o-", r"$S^*_{xy}$"), "N1_star": ("s--", r"$N_1^*$"), "N2_star": ("^:", r"$N_2^*$")}
    panels = [(ax_d, "D_xy", 1.0, "o-", None)] + ([(ax_t, "theta", math.pi, "o-", None)] if has_theta else [])
    if rheology:
        panels += ([(ax_f, "ttf_ratio", 1.0, "o-", None)] if has_ttf else []) + [
            (ax_s, q, 1.0, *styles[q]) for q in stresses]
    value_panels = panels[:2] if has_theta else panels[:1]  # where the not-settled runs are drawn
    others = [f for f in swept if f != x]
    groups: dict[tuple, list[dict]] = {}
    for cell in cells:
        groups.setdefault(tuple(cell["swept"][f] for f in others), []).append(cell)
    unsettled = [c for c in cells if not c["settled"]]
    for j, (key, members) in enumerate(groups.items()):
        label = ", ".join(f"{_short(f)} = {_shown(v)}" for f, v in zip(others, key)) or "capsim"
        settled = sorted((c for c in members if c["settled"]), key=lambda c: c["swept"][x])
        if not settled:
            continue  # nothing of this group is a result: its runs are the grey ×
        xs = np.array([float(c["swept"][x]) for c in settled])
        color = f"C{j % 10}"
        for ax, name, scale, style, series in panels:
            y = np.array([c["values"][name] for c in settled], dtype=np.float64) / scale
            err = np.array([_spread(c, name) for c in settled], dtype=np.float64) / scale
            first_series = ax is not ax_s if rheology else True
            ax.plot(xs, y, style, color=color, ms=4,
                    label=(label if first_series else (series if j == 0 else None)))
            periodic = np.array([c["periodic"] for c in settled], dtype=bool)
            if series is not None:  # a panel of several series, each with its marker
                if periodic.any():  # open markers: means over whole periods, not a steady state
                    ax.plot(xs[periodic], y[periodic], style[0], color=color, mfc="white", ms=5, ls="none")
            else:  # the class's marker (issue 39), open where it is a cycle
                classes = [c["motion"] for c in settled]
                for motion in dict.fromkeys(classes):
                    sel = np.array([m == motion for m in classes])
                    if motion in CLASS_MARKERS or periodic[sel].any():
                        ax.plot(xs[sel], y[sel], CLASS_MARKERS.get(motion, style[0]), color=color,
                                mfc="white" if periodic[sel].any() else color, ms=5, ls="none")
            if np.isfinite(err).any():
                ax.errorbar(xs, y, yerr=np.where(np.isfinite(err), err, 0.0), fmt="none", ecolor=color,
                            elinewidth=0.8, capsize=2)
    shown = dict.fromkeys(c["motion"] for c in cells if c["settled"] and c["motion"] in CLASS_MARKERS)
    for motion in shown:  # what each marker means: a proxy per class drawn
        periodic = motion in PERIODIC_MOTIONS
        ax_d.plot([], [], CLASS_MARKERS[motion], color="0.3", mfc="white" if periodic else "0.3", ls="none", ms=5,
                  label=motion.replace("_", " ") + (" (mean over whole periods)" if periodic else ""))
    if unsettled:
        ux = np.array([float(c["swept"][x]) for c in unsettled])
        for ax, name, scale, _, _ in value_panels:
            uy = np.array([c["values"][name] for c in unsettled], dtype=np.float64) / scale
            ax.plot(ux, uy, "x", color="0.55", ms=5, label="not settled: not a steady value")
    x_all = np.array([float(c["swept"][x]) for c in cells])
    context = _summary_context(ds)
    if theory and x == "shear_rate_G" and x_all.size and first is not None:
        g = np.linspace(0.0, float(np.nanmax(x_all)), 50)
        # first order: D_xy ≪ 1 (the shear's up to G = 0.12); further out it only squashes the data
        small = g[first.D_over_G * g <= 25.0 / 4.0 * 0.12]
        ax_d.plot(small, first.D_over_G * small, "k--", lw=1, label=f"first order, ${first.label}$ ({first.source})")
        if ax_t is not None and first.theta is not None:
            ax_t.plot(small, np.full_like(small, first.theta / math.pi), "k--", lw=1,
                      label=r"first order, $\pi/4$" if first.theta == math.pi / 4
                      else rf"first order, ${first.theta / math.pi:.3g}\pi$")
        if ax_f is not None and first.ttf_ratio is not None:
            ax_f.plot(small, np.full_like(small, first.ttf_ratio), "k--", lw=1, label="rigid sphere")
        if ax_s is not None and first.Sxy_star is not None and "Sxy_star" in stresses:
            ax_s.plot(small, np.full_like(small, first.Sxy_star), "k--", lw=1)
        if ax_s is not None and first.N1_over_G is not None and "N1_star" in stresses:
            ax_s.plot(small, first.N1_over_G * small, "k:", lw=1, label=rf"$N_1^* \approx {first.N1_over_G:g}G$")
    ax_d.set_ylabel(r"$D_{xy}$")
    if ax_t is not None:
        ax_t.set_ylabel(r"$\theta/\pi$")
    for bottom in ((ax_t, ax_s) if len(left) == 2 and len(right) == 2 else (list(axes.values())[-1],)):
        bottom.set_xlabel(SWEPT_LABELS.get(x, x))
    if ax_t is not None and not any(np.isfinite(float(c["values"]["theta"])) for c in cells):
        # every run tumbles or has no long axis: say so rather than leave an empty panel
        ax_t.text(0.5, 0.5, "no mean inclination: every run tumbles\n(or has no long axis)",
                  transform=ax_t.transAxes, ha="center", va="center", color="0.35")
        ax_t.set_yticks([])
    _legend(ax_d)
    if ax_f is not None:
        ax_f.set_ylabel(r"TTF $/ f_s$")
        _legend(ax_f)
    if ax_s is not None:
        ax_s.set_ylabel(", ".join(styles[q][1] for q in stresses))
        _legend(ax_s)
    if ax_t is not None and not rheology:
        _legend(ax_t)
    title = str(ds.attrs.get("title", ""))
    parts = [context[k] for k in ("shape", "law", "lam", "mesh") if context.get(k)]
    text = (f"{title}: " if title else "") + ", ".join(parts)
    note = _left_out_note(cells, unsettled)
    _supxlabel(fig, "\n".join(t for t in (text, note) if t))
    fig.steady_note = note  # what the figure says it left out, for callers and tests
    return fig




#: the marker of a settled point by its motion class (a steady one keeps its group's circle)
CLASS_MARKERS = {"swinging": "s", "tumbling": "^", "kayaking": "D", "rolling": "v", "off_plane_tank_treading": "P"}


def _spread(cell: dict, name: str) -> float:
    """The error bar of a settled point: the half-amplitude of the last cycle for a periodic
    run (where the summary has it), else the window's standard deviation."""
    amplitude = cell["amplitude"].get(name, np.nan)
    if cell["periodic"] and math.isfinite(amplitude):
        return amplitude
    return cell["std"].get(name, np.nan)


def _left_out_note(cells: list[dict], unsettled: list[dict]) -> str:
    """Error bars: window std (steady) or half-amplitude (periodic); and which runs are no
    steady values, and why."""
    text = "points: settled runs, window mean ± its standard deviation"
    if any(c["periodic"] and c["settled"] for c in cells):
        text = ("filled points: steady runs, window mean ± its standard deviation; open points: periodic runs "
                "(swinging, tumbling, kayaking; the marker names the class), mean over whole periods ± half the "
                "peak-to-peak of the last cycle (a turning body has no mean θ)")
    if not unsettled:
        return text
    why: dict[str, int] = {}
    for c in unsettled:
        why[c["why"]] = why.get(c["why"], 0) + 1
    reasons = ", ".join(f"{n} {w}" for w, n in why.items())
    return f"{text}; ×: {len(unsettled)} of {len(cells)} runs not settled ({reasons}), no line through them"


def _swept_fields(ds) -> list[str]:
    """The swept fields of a summary: its dimensions with coordinates (a grid) or the
    coordinates along its run dimension (a zip campaign)."""
    dims = ds["D_xy"].dims
    out = [d for d in dims if d in ds.coords and d not in _NOT_SWEPT]
    out += [n for n, c in ds.coords.items() if n not in dims and n not in _NOT_SWEPT and c.dims
            and set(c.dims) <= set(dims) and n not in out]
    return out


def _summary_x(ds, swept: list[str], x: str | None) -> str:
    """The swept field a summary figure draws against: ``x`` (checked numeric), else G, else the first
    numeric one; ValueError in one line when there is none."""
    numeric = [f for f in swept if np.asarray(ds[f].values).dtype.kind in "iuf"]
    if x is None:
        x = "shear_rate_G" if "shear_rate_G" in numeric else (numeric[0] if numeric else None)
        if x is None:
            raise ValueError(f"the summary sweeps no numeric field to draw against (swept: {', '.join(swept) or 'none'})")
    elif x not in numeric:
        raise ValueError(f"--x {x!r}: not a numeric swept field of the summary (allowed: {', '.join(numeric) or 'none'})")
    return x


def _summary_cells(ds, names: tuple[str, ...], swept: list[str]) -> list[dict]:
    """One record per run of a summary: its swept values, values, window stds and whether
    it is a steady value (``steady_average`` = 1; a summary without that variable: status
    completed, or every run when it has no status either)."""
    dims = ds["D_xy"].dims

    def at(name: str, index: dict):
        var = ds[name]
        value = var.isel({d: index[d] for d in var.dims if d in index}).values
        return value.item() if np.ndim(value) == 0 else value

    cells = []
    for idx in np.ndindex(*(ds.sizes[d] for d in dims)):
        index = dict(zip(dims, idx))
        status = str(at("status", index)) if "status" in ds.variables else "completed"
        if "steady_average" in ds.variables:
            settled = bool(int(at("steady_average", index)))
        else:
            settled = status == "completed"
        motion = str(at("motion", index)) if "motion" in ds.variables else ""
        motion = canonical_motion(motion)  # a summary of old run files says oscillating for swinging
        why = "" if settled else (status if status != "completed" else (motion or "transient") + " motion")
        cells.append({
            "swept": {f: at(f, index) for f in swept},
            "values": {n: float(at(n, index)) for n in names},
            "std": {n: float(at(f"{n}_std", index)) for n in names if f"{n}_std" in ds.variables},
            "amplitude": {n: float(at(f"{n}_amplitude", index)) for n in names if f"{n}_amplitude" in ds.variables},
            "periodic": motion in PERIODIC_MOTIONS, "settled": settled, "why": why, "motion": motion,
        })
    return cells


def _shown(v) -> str:
    return f"{v:g}" if isinstance(v, (float, np.floating, int, np.integer)) else str(v)


def _summary_context(ds) -> dict[str, str]:
    """Shape, law, λ and mesh of a campaign summary, from its stored campaign and variables
    (what is swept is in the legend; {} for what it does not hold)."""
    out: dict[str, str] = {}
    try:
        import yaml

        campaign = yaml.safe_load(str(ds.attrs.get("campaign_yaml", ""))) or {}
        base = campaign.get("base", {}) if isinstance(campaign, dict) else {}
        shape = base.get("shape", {}) if isinstance(base.get("shape"), dict) else {}
        swept = set(campaign.get("sweep", {}) or {}) | set(campaign.get("zip", {}) or {})
        if "shape.kind" not in swept:
            kind = str(shape.get("kind", "sphere"))
            ratio = shape.get("aspect_ratio")
            out["shape"] = f"{kind} b/a = {ratio:g}" if kind in ("oblate", "prolate") and ratio else kind
        if "membrane.law" not in swept:
            out["law"] = str((base.get("membrane") or {}).get("law", "thin_shell"))
        if "flow.viscosity_ratio" not in swept and "viscosity_ratio" not in ds.dims:
            out["lam"] = f"λ = {float((base.get('flow') or {}).get('viscosity_ratio', 1.0)):g}"
    except Exception:  # noqa: BLE001 - a summary without its campaign still plots
        pass
    if "level" in ds.variables:
        levels = sorted({int(v) for v in np.asarray(ds["level"].values).ravel() if int(v) >= 0})
        if levels:
            out["mesh"] = "mesh level " + ", ".join(str(v) for v in levels)
    return out


def _summary_scene(ds) -> tuple[set[str], Any]:
    """(the flow kinds of a campaign summary's runs, the first-order theory they all share or
    None): from its stored campaign, the base alone and with each swept value and each zipped row
    in turn (:func:`first_order_theory` asks each case's scene). A summary
    without its campaign is of the default case (simple shear); a case that cannot be rebuilt
    leaves the kinds to the rest and draws no theory."""
    import copy

    import yaml

    from capsim.campaigns.campaign import _set_dotted
    from capsim.config import case_from_dict

    try:
        campaign = yaml.safe_load(str(ds.attrs.get("campaign_yaml", ""))) or {}
        base = campaign.get("base") or {}
        sweep, zipped = campaign.get("sweep") or {}, campaign.get("zip") or {}
    except Exception:  # noqa: BLE001 - a summary without its campaign still plots
        return {"simple_shear"}, None
    rows = [dict(zip(zipped, values)) for values in zip(*zipped.values())] or [{}]
    variants = [rows[0]] + rows[1:] + [{**rows[0], key: v} for key, values in sweep.items() for v in values]
    kinds, theories = set(), []
    for params in variants:
        data = copy.deepcopy(base)
        for key, value in params.items():
            _set_dotted(data, key, value)
        try:
            case = case_from_dict({**data, "name": "summary"}, source="campaign_yaml")
        except Exception:  # noqa: BLE001 - e.g. a field of a newer capsim: no theory drawn
            theories.append(None)
            continue
        kinds.add(case.flow.kind)
        theories.append(first_order_theory(case))
    shared = theories[0] if theories and all(t == theories[0] for t in theories) else None
    return kinds or {"simple_shear"}, shared


def _short(name: str) -> str:
    return {"viscosity_ratio": "λ", "shear_rate_G": "G", "initial_tilt_deg": "tilt"}.get(name, name)


#: the colour of each motion class in an orbit map (the other classes: grey)
CLASS_COLOURS = {"steady": "#4daf4a", "swinging": "#a6d854", "tumbling": "#e41a1c", "rolling": "#377eb8",
                 "kayaking": "#984ea3", "off_plane_tank_treading": "#ff7f00", "drifting_to_rolling": "#80b1d3",
                 "drifting_to_plane": "#fdb462", "transient": "#bdbdbd", "unstable": "#000000"}
#: swept fields the orbit map puts on its x axis before any other (the first one swept)
_MAP_X = ("shear_rate_G", "shear_rate", "capillary_number")
#: and on its y axis
_MAP_Y = ("viscosity_ratio", "viscosity", "initial_tilt_deg", "bending_modulus")


def _map_fields(cells: list[dict], swept: list[str], x: str | None, y: str | None) -> tuple[str, str | None, list[str]]:
    """(x, y, the other varying fields) of an orbit map. Default x: G (or the shear rate, or
    Ca) when swept, else the first swept field that varies; default y: λ (or the viscosity,
    the tilt, κ) when swept, else the next varying field not one-to-one with x. A field
    one-to-one with x or y (a zipped viscosity with its λ) is not a further split; the rest
    (a mesh level) split each cell side by side."""
    def values(f):  # the field's value of each run, in the runs' order
        return [_shown(c["swept"][f]) for c in cells]

    varying = [f for f in swept if len(set(values(f))) > 1] or list(swept)
    if not varying:
        raise ValueError("the summary sweeps no field to map the classes over")
    for name, given in (("--x", x), ("--y", y)):
        if given is not None and given not in swept:
            raise ValueError(f"{name} {given!r}: not a swept field of the summary (allowed: {', '.join(swept)})")

    def one_to_one(a, b):
        pairs = set(zip(values(a), values(b)))
        return len(pairs) == len({p[0] for p in pairs}) == len({p[1] for p in pairs})

    if x is None:
        x = next((f for f in _MAP_X if f in varying), varying[0])
    if y is None:
        rest = [f for f in varying if f != x and not one_to_one(f, x)]
        y = next((f for f in _MAP_Y if f in rest), rest[0] if rest else None)
    if y == x:
        raise ValueError(f"--y {y!r}: the same field as --x")
    others = [f for f in varying if f not in (x, y) and not one_to_one(f, x) and not (y and one_to_one(f, y))]
    return x, y, others


def orbit_map_figure(source, x: str | None = None, y: str | None = None):
    """A campaign's orbit-class map (issue 39): each run of a summary (`capsim summarize`
    netCDF or its Dataset) as a cell over two swept fields (``x``, ``y``; default the shear
    rate and λ where swept, see :func:`_map_fields`), coloured and labelled by its motion class
    (`motion`), filled where the run settled (`settled`/`steady_average` = 1) and hatched
    with "not settled" where it did not; a run that did not complete is grey with its
    status. Runs that differ in a further swept field (a mesh level) share the cell side by
    side, each labelled with that field's value. Returns the Figure (``fig.map_cells``: the
    drawn cells, for callers and tests)."""
    import textwrap

    import xarray as xr
    from matplotlib.patches import Patch, Rectangle

    ds = source if isinstance(source, xr.Dataset) else xr.load_dataset(source)
    if "motion" not in ds.variables or "D_xy" not in ds.variables:
        raise ValueError("the summary has no 'motion' (is it a capsim summarize output?)")
    swept = _swept_fields(ds)
    cells = _summary_cells(ds, ("D_xy",), swept)
    x, y, others = _map_fields(cells, swept, x, y)
    for cell in cells:
        cell["status"] = cell["why"] if cell["why"] and not cell["why"].endswith(" motion") else "completed"

    def order(f):
        vals = list(dict.fromkeys(c["swept"][f] for c in cells))
        try:
            return sorted(vals, key=float)
        except (TypeError, ValueError):
            return vals

    xs = order(x)
    ys = order(y) if y else [None]
    split = {}
    for cell in cells:
        split.setdefault((cell["swept"][x], cell["swept"][y] if y else None), []).append(cell)
    fig = _figure(figsize=(max(FIGSIZE[0], 1.6 * len(xs) + 1.6), max(FIGSIZE[1], 1.1 * len(ys) + 1.8)))
    ax = fig.subplots()
    drawn = []
    for (vx, vy), members in split.items():
        i, j = xs.index(vx), ys.index(vy)
        members = sorted(members, key=lambda c: tuple(_shown(c["swept"][f]) for f in others))
        width = 0.94 / len(members)
        for k, cell in enumerate(members):
            motion = cell["motion"] or "—"
            done = cell["status"] == "completed"
            settled = done and cell["settled"]
            colour = CLASS_COLOURS.get(motion, "#bdbdbd") if done else "#f0f0f0"
            x0 = i - 0.47 + k * width
            ax.add_patch(Rectangle((x0, j - 0.47), width, 0.94, facecolor=colour, alpha=1.0 if settled else 0.45,
                                   hatch=None if settled else "//", edgecolor="0.3", linewidth=0.8))
            words = [", ".join(f"{_short(f)} {_shown(cell['swept'][f])}" for f in others)] if others else []
            if done:
                words += [textwrap.fill(motion.replace("_", " "), max(8, int(14 * width))),
                          "settled" if settled else "not settled"]
            else:
                words += [cell["status"]]
            dark = done and motion in ("tumbling", "kayaking", "unstable", "rolling") and settled
            ax.text(x0 + width / 2, j, "\n".join(w for w in words if w), ha="center", va="center",
                    fontsize="x-small" if len(members) > 1 else "small", color="white" if dark else "black")
            drawn.append({"x": vx, "y": vy, "motion": motion, "settled": settled, "status": cell["status"],
                          **{f: cell["swept"][f] for f in others}})
    ax.set_xlim(-0.5, len(xs) - 0.5)
    ax.set_ylim(-0.5, len(ys) - 0.5)
    ax.set_xticks(range(len(xs)), [_shown(v) for v in xs])
    ax.set_yticks(range(len(ys)), [_shown(v) for v in ys] if y else [""])
    ax.set_xlabel(SWEPT_LABELS.get(x, x))
    ax.set_ylabel(SWEPT_LABELS.get(y, y) if y else "")
    shown = list(dict.fromkeys(c["motion"] for c in drawn if c["status"] == "completed"))
    handles = [Patch(facecolor=CLASS_COLOURS.get(m, "#bdbdbd"), edgecolor="0.3", label=m.replace("_", " "))
               for m in shown]
    if any(not c["settled"] for c in drawn):
        handles.append(Patch(facecolor="white", edgecolor="0.3", hatch="//", label="not settled"))
    if handles:
        fig.legend(handles=handles, loc="outside right upper", fontsize="small")
    context = _summary_context(ds)
    title = str(ds.attrs.get("title", ""))
    parts = [context[k] for k in ("shape", "law", "lam", "mesh") if context.get(k)]
    text = (f"{title}: " if title else "") + ", ".join(parts)
    note = ("each cell one run: its motion class (docs/method.md, \"Motion classes\"), filled where it settled, "
            "hatched where it did not")
    _supxlabel(fig, "\n".join(t for t in (text, note) if t))
    fig.map_cells = drawn
    return fig


def _orbit_axis(data: dict[str, Any]) -> tuple[np.ndarray, str, str]:
    """(the axis the classifier follows at every row, its name, a short symbol): the body's
    symmetry axis from the shape (capsim.solve.observables.body_axis: the short axis of a disk, the
    long axis of a prolate), or the material director for a sphere and for a run file written
    before issue 39 (no short axis recorded)."""
    from capsim.solve.observables import _stack, body_axis

    ts = data["timeseries"]
    summary = data.get("summary") or {}
    r = summary.get("jeffery_aspect_ratio")
    if not isinstance(r, (int, float)) or not math.isfinite(r):
        info = _case_info(data)
        r = info.get("aspect_ratio", 1.0) if info.get("shape") in ("oblate", "prolate") else \
            (0.4 if info.get("shape") == "biconcave" else 1.0)
    series = {k: np.asarray(v) for k, v in ts.items()}
    which = "long_axis" if r > 1.0 else "short_axis"
    axis = body_axis(series, float(r)) if which + "_x" in series else None
    if axis is not None:
        return axis, f"body axis ({'long' if r > 1.0 else 'short'} axis of the shape)", "axis"
    return _stack(series, "director"), "material director", "director"


def orbit_figure(source):
    """The orbit (issue 26; issue 39): the axis the motion classifier follows (the body's
    symmetry axis from the shape, or the material director where there is none) on the unit
    sphere seen from the vorticity axis z (the shear plane) and from the flow axis x, and its
    polar angle from z and azimuth from y (Jeffery's θ and φ, unwrapped) against kt, with the
    material director's polar angle beside it (a tank-treading membrane carries the director
    round while the shape stays put). The summary's class, whether it settled, and its
    averaging window (whole orbits or cycles; dashed lines) are marked."""
    data = _load_run(source)
    _refuse_scene(data, "orbit", "one capsule's orbit", "each capsule's motion class is in the run file's "
                  "summary/capsule; their paths: --kind separation")
    info = _case_info(data)
    ts = data["timeseries"]
    if "director_x" not in ts:
        raise ValueError("the run file has no director (written by capsim since issue 26)")
    t = np.asarray(ts["t"], float)
    d, name, symbol = _orbit_axis(data)
    director = np.stack([np.asarray(ts[f"director_{c}"], float) for c in "xyz"], axis=1)
    summary = data.get("summary") or {}
    fig = _figure()
    grid = fig.add_gridspec(2, 2, height_ratios=(1.1, 1.0))
    # the angles first: the first axes carry the legend outside on the right, as every kind's
    ax = fig.add_subplot(grid[1, :])
    polar = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    off_z = np.hypot(d[:, 0], d[:, 1]) > 1e-6  # on z to round-off the azimuth is no angle
    azimuth = np.full(t.size, np.nan)
    if off_z.any():
        azimuth[off_z] = np.unwrap(np.arctan2(d[off_z, 0], d[off_z, 1]))
    ax.plot(t, polar / np.pi, "C0-", label=rf"{symbol}: polar angle $\theta_p/\pi$ from $z$")
    ax.plot(t, azimuth / np.pi, "C1-", label=rf"{symbol}: azimuth $\varphi/\pi$ from $y$ (unwrapped)")
    if symbol != "director":
        ax.plot(t, np.arccos(np.clip(director[:, 2], -1.0, 1.0)) / np.pi, "-", color="0.6", lw=0.8,
                label=r"material director: polar angle$/\pi$")
    motion, settled = summary.get("motion"), summary.get("settled")
    window = (summary.get("averaging_t_from"), summary.get("averaging_t_to"))
    if motion:
        from capsim.quantities import canonical_motion

        verdict = "" if not isinstance(settled, (int, float)) or math.isnan(settled) else \
            (", settled" if settled else ", not settled")
        n = summary.get("orbits_averaged")
        over = f" over {int(n)} whole orbit{'s' if n != 1 else ''}" if isinstance(n, (int, float)) and n >= 1 else ""
        if all(isinstance(w, (int, float)) and math.isfinite(w) for w in window):
            for k, edge in enumerate(window):
                ax.axvline(edge, color="C2" if settled else "C3", ls="--", lw=0.9,
                           label=f"averaging window{over}" if k == 0 else None)
        ax.set_title(f"motion: {canonical_motion(str(motion))}{verdict}", fontsize="small")
    ax.set_xlabel(r"$kt$")
    ax.set_ylabel(r"angle / $\pi$")
    _tag(ax, x=("t", "$t$"))
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    circle = np.linspace(0.0, 2 * np.pi, 181)
    # (horizontal, vertical) components of each view; the hidden axis decides the front
    views = ((0, 1, 2, "seen from +z (shear plane)", "x", "y"), (1, 2, 0, "seen from +x (flow axis)", "y", "z"))
    for k, (h, v, depth, title, hl, vl) in enumerate(views):
        ax = fig.add_subplot(grid[0, k])
        ax.plot(np.cos(circle), np.sin(circle), color="0.6", lw=0.8)
        front = d[:, depth] >= 0
        ax.plot(np.where(front, d[:, h], np.nan), np.where(front, d[:, v], np.nan), "C0-", lw=1.2,
                label="front hemisphere")
        ax.plot(np.where(~front, d[:, h], np.nan), np.where(~front, d[:, v], np.nan), "C0--", lw=0.8,
                label="back hemisphere")
        ax.plot(d[:1, h], d[:1, v], "C3o", mfc="none", ms=8, label="kt = 0")
        ax.plot(d[-1:, h], d[-1:, v], "C3s", ms=5, label=f"kt = {t[-1]:.3g}")
        ax.set_aspect("equal")
        ax.set_xlim(-1.1, 1.1)
        ax.set_ylim(-1.1, 1.1)
        ax.set_xlabel(f"{symbol} ${hl}$")
        ax.set_ylabel(f"{symbol} ${vl}$")
        ax.set_title(title, fontsize="small")
        if k == 1:
            ax.legend(fontsize="x-small", loc="upper left", bbox_to_anchor=(1.02, 1.0))
    _caption(fig, [info], extra=f"the path: the {name}")
    return fig



# ------------------------------------------------------------ physical units


def _tag(ax, x: tuple[str, str] | None = None, y: tuple[str, str] | None = None) -> None:
    """Say what each axis of `ax` shows, as (a quantity of capsim.quantities whose scale the
    values are in, the axis' name in physical units), for :func:`to_physical`."""
    ax.capsim_axes = (x, y)


#: how a unit of capsim.quantities.SCALE_UNITS is typeset on an axis (the unit is the table's)
_TYPESET = {"um": "µm", "uN/m": "µN/m", "pN*um": "pN µm", "um^2": "µm²", "um^3": "µm³"}
_KT = __import__("re").compile(r"\bkt = ([-+0-9.eE]+)")


def run_factors(sources) -> dict[str, float]:
    """The physical factors (capsim.units.physical_factors) of the run(s) to draw; ValueError
    (one line) for a run without a physical block, or overlaid runs whose blocks differ."""
    from capsim.face.export import case_of
    from capsim.units import factors_for

    found = []
    for run in _sources(sources):
        name = Path(str(run)).name if not isinstance(run, dict) else "the run"
        found.append(factors_for(case_of(_load_run(run)), name))
    if any(f != found[0] for f in found[1:]):
        raise ValueError("--units physical: the overlaid runs have different physical scales (shear rate, radius, "
                         "viscosity, modulus): one axis cannot show them; overlay them in --units capsim")
    return found[0]


def to_physical(fig, factors: dict[str, float]) -> None:
    """Redraw the tagged axes (:func:`_tag`) of `fig` in physical units: every line's data
    times the factor of its quantity's scale (axhline/axvline in the one direction that is
    data), the axis named with the unit of capsim.quantities, 'kt = …' in labels and the
    caption as 't = … s'."""
    from capsim.quantities import physical_units

    def unit_of(name: str) -> tuple[float, str]:
        unit, scale = physical_units(name)
        return factors[scale], _TYPESET.get(unit, unit)

    f_t, u_t = unit_of("t")

    def kt_text(text: str) -> str:
        return _KT.sub(lambda m: f"t = {float(m.group(1)) * f_t:.3g} {u_t}", text)

    for ax in fig.axes:
        x, y = getattr(ax, "capsim_axes", (None, None))
        fx, ux = unit_of(x[0]) if x else (1.0, "")
        fy, uy = unit_of(y[0]) if y else (1.0, "")
        for line in ax.get_lines():
            transform = line.get_transform()
            sx = fx if transform in (ax.transData, ax.get_xaxis_transform(which="grid")) else 1.0
            sy = fy if transform in (ax.transData, ax.get_yaxis_transform(which="grid")) else 1.0
            line.set_xdata(np.asarray(line.get_xdata(), float) * sx)
            line.set_ydata(np.asarray(line.get_ydata(), float) * sy)
            line.set_label(kt_text(getattr(line, "physical_label", line.get_label())))
        # the wall's hatched band (a patch) and the capsule numbers (texts) are data too (issue 54:
        # the band stayed at its height in units of a)
        for patch in ax.patches:
            if patch.get_transform() == ax.transData and hasattr(patch, "get_xy"):
                patch.set_xy(np.asarray(patch.get_xy(), float) * [fx, fy])
        for text in ax.texts:
            if text.get_transform() == ax.transData:
                px, py = text.get_position()
                text.set_position((px * fx, py * fy))
        legend = ax.get_legend()
        if legend is not None:  # the same entries, their texts in physical units
            for text, label in zip(legend.get_texts(), ax.get_legend_handles_labels()[1]):
                text.set_text(label)
        if x is None and y is None:
            continue
        if x:
            ax.set_xlabel(f"{x[1]} ({ux})")
        if y:
            ax.set_ylabel(f"{y[1]} ({uy})")
        # limits a figure fixed (the wall's line spans the x-range it set) are scaled with the data;
        # autoscaling them anew would keep them in units of a (issue 54: snapshots downstream of a wall
        # fell out of view and out of the legend)
        fixed = {"x": None if ax.get_autoscalex_on() else ax.get_xlim(),
                 "y": None if ax.get_autoscaley_on() else ax.get_ylim()}
        ax.relim()
        ax.autoscale_view()
        if fixed["x"] is not None:
            ax.set_xlim(fixed["x"][0] * fx, fixed["x"][1] * fx)
        if fixed["y"] is not None:
            ax.set_ylim(fixed["y"][0] * fy, fixed["y"][1] * fy)
    if getattr(fig, "caption", ""):
        _supxlabel(fig, kt_text(fig.caption))


#: the conduit figure's panels: (summary variable(s), axis label)
CONDUIT_PANELS = ((("centroid_velocity_x",), r"speed $/ U$"),
                  (("extra_pressure_drop",), r"$\Delta P^+ a/(\mu U)$"),
                  (("length_along", "width_across"), r"length, width $/a$"))


def conduit_figure(source, x: str | None = None):
    """A campaign of capsules in conduits (issue 53): the capsule's speed over the mean velocity U,
    the pressure drop it adds and its lengths along and across the conduit, against a swept field
    (default G, the conduit's capillary number μU/E_s), one line per combination of the other swept
    values (the conduit's radius: a/R). Settled runs are points with the window's standard
    deviation as error bars; the others grey ×."""
    import xarray as xr

    ds = source if isinstance(source, xr.Dataset) else xr.load_dataset(source)
    if "extra_pressure_drop" not in ds.variables:
        raise ValueError("the summary has no 'extra_pressure_drop': no run of its campaign was in a conduit "
                         "(conduit:, flow.kind conduit)")
    swept = _swept_fields(ds)
    x = _summary_x(ds, swept, x)
    names = tuple(n for panel, _ in CONDUIT_PANELS for n in panel)
    cells = _summary_cells(ds, names, swept)
    fig = _figure(figsize=(FIGSIZE[0], FIGSIZE[1]))
    axes = np.atleast_1d(fig.subplots(len(CONDUIT_PANELS), 1, sharex=True))
    others = [f for f in swept if f != x]
    groups: dict[tuple, list[dict]] = {}
    for cell in cells:
        groups.setdefault(tuple(cell["swept"][f] for f in others), []).append(cell)

    def group_label(key) -> str:
        parts = []
        for f, v in zip(others, key):
            field = str(ds[f].attrs.get("case_field", f))
            parts.append(f"R = {_shown(v)} a (a/R = {1 / float(v):.3g})" if field == "conduit.radius"
                         else f"{_short(f)} = {_shown(v)}")
        return ", ".join(parts) or "capsim"

    for j, (key, members) in enumerate(groups.items()):
        settled = sorted((c for c in members if c["settled"]), key=lambda c: c["swept"][x])
        if not settled:
            continue
        xs = np.array([float(c["swept"][x]) for c in settled])
        color = f"C{j % 10}"
        for ax, (panel, _) in zip(axes, CONDUIT_PANELS):
            for k, name in enumerate(panel):
                y = np.array([c["values"][name] for c in settled], dtype=np.float64)
                err = np.array([c["std"].get(name, np.nan) for c in settled], dtype=np.float64)
                ax.plot(xs, y, "o-" if k == 0 else "s--", color=color, ms=4,
                        label=group_label(key) if (ax is axes[0] and k == 0) else None)
                if np.isfinite(err).any():
                    ax.errorbar(xs, y, yerr=np.where(np.isfinite(err), err, 0.0), fmt="none", ecolor=color,
                                elinewidth=0.8, capsize=2)
    unsettled = [c for c in cells if not c["settled"]]
    for ax, (panel, _) in zip(axes, CONDUIT_PANELS):
        if unsettled:
            ux = np.array([float(c["swept"][x]) for c in unsettled])
            uy = np.array([c["values"][panel[0]] for c in unsettled], dtype=np.float64)
            ax.plot(ux, uy, "x", color="0.55", ms=5, label="not settled" if ax is axes[0] else None)
    for ax, (_, label) in zip(axes, CONDUIT_PANELS):
        ax.set_ylabel(label)
    axes[-1].set_xlabel(r"$G = \mu U/E_s$ (Ca)" if x == "shear_rate_G" else SWEPT_LABELS.get(x, x))
    _legend(axes[0])
    context = _summary_context(ds)
    parts = [context[k] for k in ("shape", "law", "lam", "mesh") if context.get(k)]
    title = str(ds.attrs.get("title", ""))
    fig.caption = ((f"{title}: " if title else "") + ", ".join(parts)
                   + "; lengths along the conduit (—) and across it (--)")
    _supxlabel(fig, fig.caption)
    return fig


# ------------------------------------------------------------ dispatcher

# kinds that overlay several runs when given a list of them (lift: one curve per G of several wall runs)
OVERLAY_KINDS = ("deformation", "inclination", "separation", "migration", "lift")
# kinds drawn from a campaign summary (netCDF of capsim summarize), not from a run file
SUMMARY_KINDS = ("steady", "orbit_map", "conduit")
# kinds drawn from a run of several capsules only (capsules:, issue 43); a one-capsule run is refused
SCENE_KINDS = ("separation",)

KINDS: dict[str, Callable[..., Any]] = {
    "deformation": deformation_figure,
    "inclination": inclination_figure,
    "contour": contour_figure,
    "trajectory": trajectory_figure,
    "separation": separation_figure,
    "tensions": tensions_figure,
    "rheology": rheology_figure,
    "steady": steady_figure,
    "orbit": orbit_figure,
    "orbit_map": orbit_map_figure,
    "conduit": conduit_figure,
    "lift": lift_figure,
    "migration": migration_figure,
}


def figure_format(output: str | os.PathLike) -> str:
    """The format a figure file's suffix names (png, pdf, svg); ValueError for another."""
    suffix = Path(output).suffix.lower().lstrip(".")
    if suffix not in FIGURE_FORMATS:
        raise ValueError(f"output {os.fspath(output)}: the suffix names the format; give "
                         f"{', '.join('.' + f for f in FIGURE_FORMATS)}, got {('.' + suffix) if suffix else 'none'}")
    return suffix


def plot(source, kind: str, output: str | os.PathLike | None = None, *, dpi: float | None = None,
         fmt: str | None = None, size: tuple[float, float] | None = None, units: str = "capsim", **options: Any):
    """Draw figure `kind` of a run (or, for 'steady' and 'orbit_map', a campaign summary) at ``size``
    (W, H inches; default the kind's), legends placed by :func:`place_legends`; save it
    when `output` is given, as the format its suffix names (or ``fmt``) at ``dpi``
    (default :data:`DPI`), fonts embedded as TrueType (Type 42) in a PDF and text kept as
    text in an SVG (:data:`JOURNAL_RC`). Returns the Figure."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    if fmt is None and output is not None:
        fmt = figure_format(output)
    if fmt is not None and fmt not in FIGURE_FORMATS:
        raise ValueError(f"format must be one of {', '.join(FIGURE_FORMATS)}, got {fmt!r}")
    if dpi is not None and not (math.isfinite(dpi) and 10 <= dpi <= 2400):
        raise ValueError(f"--dpi {dpi:g}: must be in [10, 2400]")
    if size is not None:
        size = parse_size(size)
    if kind in SUMMARY_KINDS + ("lift",) and isinstance(source, (str, os.PathLike)) and Path(source).is_dir():
        # a campaign's output directory: its summary, made here (nothing written), so that one
        # command draws a swept campaign (capsim plot runs/wall-lift --kind lift)
        from capsim.campaigns.summary import summarize_campaign

        source = summarize_campaign(source)
    if kind in SUMMARY_KINDS:
        _refuse_run_file(source, kind)
    from capsim.quantities import UNIT_SYSTEMS

    if units not in UNIT_SYSTEMS:
        raise ValueError(f"--units {units!r}: must be one of {', '.join(UNIT_SYSTEMS)}")
    factors = None
    if units == "physical":
        if kind == "lift":
            raise ValueError("--units physical: --kind lift draws the lift and slip in units of ka against h/a, the "
                             "scales of its far-field laws; allowed: --units capsim")
        if kind in SUMMARY_KINDS:
            raise ValueError(f"--units physical: --kind {kind} draws ratios (D_xy, θ/π, TTF/f_s, S*) against the swept "
                             "field, whose physical values are SI already; allowed: --units capsim (capsim summarize "
                             "--units physical writes the values in physical units)")
        factors = run_factors(source)
    fig = KINDS[kind](source, **options)
    if factors is not None:
        to_physical(fig, factors)
    default_size = tuple(float(v) for v in fig.get_size_inches())
    if size is not None:
        fig.set_size_inches(size)
        if getattr(fig, "caption", ""):
            _supxlabel(fig, fig.caption)  # wrapped anew to the new width
    if fmt == "png" and output is not None:
        _check_pixels(fig.get_size_inches(), dpi or DPI)
    collapsed = _layout_collapses(fig, warn=True)
    if collapsed:
        shown = ",".join(f"{v:g}" for v in fig.get_size_inches())
        hint = _smallest_size(fig, default_size)
        import matplotlib.pyplot as plt

        plt.close(fig)
        raise ValueError(f"--size {shown}: too small for --kind {kind}, its axes collapse under their labels and "
                         f"caption; give at least about {hint[0]:.2g},{hint[1]:.2g} inches")
    if output is not None:
        import matplotlib

        output = Path(output)
        output.parent.mkdir(parents=True, exist_ok=True)
        with matplotlib.rc_context(JOURNAL_RC):
            fig.savefig(output, format=fmt, dpi=dpi or DPI, metadata=_metadata(fmt))
    return fig


#: what journals ask of vector figures: TrueType (Type 42) fonts embedded in PDF and
#: PostScript (many refuse Type 3), and SVG text as <text> elements, not paths
JOURNAL_RC = {"pdf.fonttype": 42, "ps.fonttype": 42, "svg.fonttype": "none"}
#: the range ``--size`` accepts, in inches (a column is about 3.3 in, a page 7 in)
SIZE_RANGE = (1.0, 30.0)
#: the most pixels a PNG may have, --size × --dpi in both directions (each within its own range
#: could ask for 72000² pixels, ~20 GB of memory: issue 38, finding 18); 1e8 is a 30 in × 30 in
#: figure at 333 dpi, a 7 in page at 1400 dpi
MAX_PIXELS = 1e8


def _layout_collapses(fig, warn: bool = False) -> bool:
    """Lay `fig` out at its size (place_legends) and say whether constrained layout gave up
    (its axes collapsed under their labels and caption: matplotlib warns and draws them
    anyway); other warnings of the layout are passed on when `warn`."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        place_legends(fig)
    collapsed = False
    for w in caught:
        if "collapsed" in str(w.message):
            collapsed = True
        elif warn:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return collapsed


def _smallest_size(fig, default_size: tuple[float, float]) -> tuple[float, float]:
    """About the smallest size of the requested shape at which `fig` lays out (growing it in
    steps of a quarter), else its kind's default size."""
    w0, h0 = (float(v) for v in fig.get_size_inches())
    lo, hi = SIZE_RANGE
    for f in (1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 4.0, 5.0):
        w, h = min(max(w0 * f, lo), hi), min(max(h0 * f, lo), hi)
        fig.set_size_inches((w, h))
        if getattr(fig, "caption", ""):
            _supxlabel(fig, fig.caption)
        if not _layout_collapses(fig):
            return w, h
    return default_size


def _check_pixels(size_inches, dpi: float) -> None:
    """ValueError (one line) when a PNG of this size at this dpi would exceed MAX_PIXELS."""
    w, h = (float(v) * dpi for v in size_inches)
    if w * h > MAX_PIXELS:
        most = math.sqrt(MAX_PIXELS / (float(size_inches[0]) * float(size_inches[1])))
        raise ValueError(f"--size {size_inches[0]:g},{size_inches[1]:g} at --dpi {dpi:g} is {w:.0f} x {h:.0f} = "
                         f"{w * h:.3g} pixels, more than the {MAX_PIXELS:.0e} a PNG may have: lower --dpi (at most "
                         f"{math.floor(most)} at this size) or --size, or write a PDF or SVG")


def parse_size(size) -> tuple[float, float]:
    """(W, H) in inches from 'W,H' or a pair; ValueError (one line) for anything else."""
    text = size if isinstance(size, str) else ",".join(str(v) for v in size)
    try:
        w, h = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--size {text!r}: must be W,H in inches, e.g. 3.3,2.5") from None
    lo, hi = SIZE_RANGE
    if not (lo <= w <= hi and lo <= h <= hi):
        raise ValueError(f"--size {text!r}: W and H must be in [{lo:g}, {hi:g}] inches")
    return w, h


def _metadata(fmt: str) -> dict[str, Any]:
    # reproducible files: no creation date in PDF and SVG
    if fmt == "pdf":
        return {"CreationDate": None, "Creator": "capsim"}
    if fmt == "svg":
        return {"Date": None, "Creator": "capsim"}
    return {"Software": "capsim"}


def _refuse_run_file(source, kind: str = "steady") -> None:
    if isinstance(source, (str, os.PathLike)):
        from capsim.storage.store import is_run_file

        if is_run_file(source):
            raise ValueError(f"{os.fspath(source)} is a run file; --kind {kind} takes a campaign summary "
                             f"(capsim summarize DIR -o summary.nc, then capsim plot summary.nc --kind {kind})")


def default_output(source: str | os.PathLike, kind: str, fmt: str = "png") -> Path:
    """RUN.h5 → RUN_<kind>.<fmt> beside it."""
    source = Path(source)
    return source.with_name(f"{source.stem}_{kind}.{fmt}")


class FigureError(ValueError):
    """A figure that cannot be drawn from these inputs (one line)."""


def write_figure(paths: Sequence[str | os.PathLike], kind: str, output: str | os.PathLike | None = None, *,
                 overwrite: bool = False, dpi: float | None = None, theory: bool = True, unwrap: bool = False,
                 times: Sequence[float] | None = None, node: int | None = None, x: str | None = None,
                 size: str | None = None, labels: Sequence[str] | None = None, units: str = "capsim",
                 y: str | None = None) -> Path:
    """`capsim plot`: draw `kind` of one run (several overlaid for :data:`OVERLAY_KINDS`, a
    summary for 'steady' and 'orbit_map') into `output` (default :func:`default_output`), through the output
    guards and a temporary file renamed into place. Raises FigureError, or
    :class:`capsim.storage.files.OutputError`/``StorageError``, each one line. Returns the path."""
    from capsim.storage.files import FIGURE_MAGIC, check_writable, guard_output, replace_atomically, starts_with
    from capsim.errors import first_line

    paths = [Path(p) for p in paths]
    if kind not in KINDS:
        raise FigureError(f"--kind must be one of {', '.join(KINDS)}, got {kind!r}")
    if len(paths) > 1 and kind not in OVERLAY_KINDS:
        raise FigureError(f"--kind {kind} takes one PATH, got {len(paths)}; "
                          f"several runs overlay only for {', '.join(OVERLAY_KINDS)}")
    for path in paths:
        if not path.exists():
            raise FigureError(f"{path}: no such file")
        if path.is_dir() and not (kind in SUMMARY_KINDS + ("lift",) and len(paths) == 1):
            raise FigureError(f"{path}: is a directory; give a run file (.h5) or a summary (.nc) (a campaign's "
                              f"output directory is drawn by --kind {', '.join(SUMMARY_KINDS + ('lift',))})")
    if dpi is not None and not (math.isfinite(dpi) and 10 <= dpi <= 2400):
        raise FigureError(f"--dpi {dpi:g}: must be in [10, 2400]")
    path = paths[0]
    out = Path(output) if output is not None else default_output(path, kind)
    try:
        fmt = figure_format(out)
    except ValueError as exc:
        guard_output(out, paths, overwrite)  # an input or a run file named as output: say that first
        raise FigureError(str(exc)) from None
    check_writable(out)
    guard_output(out, paths, overwrite, ours=starts_with(FIGURE_MAGIC[fmt]))
    options: dict[str, Any] = {}
    if kind in ("deformation", "inclination", "rheology", "steady", "lift", "migration"):
        options["theory"] = theory
    if kind == "inclination" and unwrap:
        options["unwrap"] = True
    if kind == "contour" and times:
        options["times"] = list(times)
    if kind == "tensions" and times:
        options["t"] = times[-1]
    if kind == "trajectory" and node is not None:
        options["node"] = node
    if labels:
        if kind not in OVERLAY_KINDS:
            raise FigureError(f"--label: only for runs overlaid by --kind {' or '.join(OVERLAY_KINDS)}, not {kind}")
        if len(labels) != len(paths) and kind != "lift":  # lift: one label per curve (per G), checked there
            raise FigureError(f"--label given {len(labels)} times for {len(paths)} runs: give one per PATH, in order")
        options["labels"] = list(labels)
    figure_size = None
    if size is not None:
        try:
            figure_size = parse_size(size)
        except ValueError as exc:
            raise FigureError(str(exc)) from None
    if x is not None:
        if kind not in SUMMARY_KINDS:
            raise FigureError(f"--x {x!r}: only for --kind steady, orbit_map and conduit (the swept field on its axis)")
        options["x"] = x
    if y is not None:
        if kind != "orbit_map":
            raise FigureError(f"--y {y!r}: only for --kind orbit_map (the second swept field)")
        options["y"] = y
    source: Any = [str(p) for p in paths] if len(paths) > 1 else path

    def draw(tmp: Path) -> None:
        import matplotlib.pyplot as plt

        from capsim.config import ConfigError
        from capsim.storage.store import TrajectoryError

        try:
            plt.close(plot(source, kind, tmp, dpi=dpi, fmt=fmt, size=figure_size, units=units, **options))
        except (TrajectoryError, ConfigError, ValueError, KeyError) as exc:
            raise FigureError(first_line(exc)) from None
        except OSError:
            raise
        except Exception as exc:  # noqa: BLE001 - a file that is not what --kind needs: one line
            raise FigureError(f"cannot plot {path} as --kind {kind}: {type(exc).__name__}: {first_line(exc)}") from None

    replace_atomically(out, draw)
    return out
