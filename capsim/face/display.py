"""What `capsim run` and `capsim sweep` show while they work, and their closing tables.

In a terminal (the progress stream, stderr, is a TTY): a live :mod:`rich.progress`
display — for a run, percent of t_end, elapsed time, ETA, dt and D_xy; for a
sweep, one row per running case (run id, kt / t_end) under an overall bar with
its ETA. Otherwise (a log file, a pipe, CI): one plain line every
``interval_s`` seconds (default :data:`PLAIN_INTERVAL_S`) and a last one at the
end, with no control codes, so a redirected log stays readable line by line.

Closing summaries are :class:`rich.table.Table` objects printed on stdout (no
colour when stdout is not a terminal). numba-free: the CLI imports this before
a run starts.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any, TextIO

__all__ = ["PLAIN_INTERVAL_S", "RunProgress", "SweepProgress", "fmt", "format_duration", "is_terminal", "print_summary",
           "print_table", "scene_features", "summary_rows", "summary_table"]

#: seconds between two plain progress lines (a log is not a terminal)
PLAIN_INTERVAL_S = 10.0
#: seconds between two redraws of the live display
LIVE_INTERVAL_S = 0.1
#: running cases named on one plain sweep line
PLAIN_RUNS_SHOWN = 6


def is_terminal(stream: Any) -> bool:
    """Whether `stream` is an interactive terminal that can take a live display."""
    try:
        return bool(stream.isatty()) and os.environ.get("TERM", "") != "dumb"
    except (AttributeError, ValueError, OSError):
        return False


def format_duration(seconds: float | None) -> str:
    """h:mm:ss (or '?' when unknown)."""
    if seconds is None or not math.isfinite(seconds) or seconds < 0:
        return "?"
    s = int(round(seconds))
    return f"{s // 3600}:{(s // 60) % 60:02d}:{s % 60:02d}"


def _number(state: Mapping[str, Any], key: str) -> float:
    value = state.get(key)
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan


class _Display:
    def __init__(self, stream: TextIO | None, terminal: bool | None, interval_s: float | None,
                 clock: Callable[[], float]) -> None:
        # Looked up now, not at import, so that a swapped sys.stderr is honoured.
        self.stream = stream if stream is not None else sys.stderr
        self.terminal = is_terminal(self.stream) if terminal is None else terminal
        self.interval_s = (LIVE_INTERVAL_S if self.terminal else PLAIN_INTERVAL_S) if interval_s is None else interval_s
        self.clock = clock
        self._start: float | None = None
        self._last_line: float | None = None
        self._live = None
        self._written = False
        self._pending = False  # a state not yet shown

    def _show(self, now: float) -> None:
        """Redraw the live display at most every interval, or write a plain line when one is due."""
        if self.terminal:
            if now - self._last_draw >= self.interval_s:
                self._last_draw = now
                self._refresh_live()
            return
        self._pending = True
        if self._due(now):
            self._last_line = now
            self._write(self._line(now))
            self._pending = False

    def _write(self, line: str) -> None:
        self.stream.write(line + "\n")
        self.stream.flush()
        self._written = True

    def _due(self, now: float) -> bool:
        """A plain line is due once interval_s has passed since the start or the last line."""
        ref = self._last_line if self._last_line is not None else self._start
        return now - ref >= self.interval_s

    def _console(self):
        from rich.console import Console

        return Console(file=self.stream, force_terminal=True, highlight=False)

    def finish(self) -> None:
        if self._live is not None:
            self._refresh_live(final=True)
            self._live.stop()
            self._live = None
        elif self._pending:
            self._write(self._line(self.clock()))
            self._pending = False

    # subclasses: _line(now) -> str, _refresh_live(final)


class RunProgress(_Display):
    """Progress of one run; called with run_case's ``{t, dt, D_xy, step, t_end, wall_s}``.

    The elapsed time shown is the run's ``wall_s`` where given (the clock of the closing
    table: set-up, compilation and a resumed run's earlier parts included), else the time
    since the first call."""

    def __init__(self, stream: TextIO | None = None, *, terminal: bool | None = None,
                 interval_s: float | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(stream, terminal, interval_s, clock)
        self.state: dict[str, Any] = {}
        self._t0 = math.nan
        self._task = None
        self._last_draw = -math.inf
        self._stamp = math.nan

    def _eta(self, now: float) -> float | None:
        t, t_end = _number(self.state, "t"), _number(self.state, "t_end")
        elapsed = now - (self._start if self._start is not None else now)
        done = t - self._t0
        if not (math.isfinite(done) and done > 0 and elapsed > 0 and math.isfinite(t_end)):
            return None
        return max(0.0, (t_end - t) * elapsed / done)

    def _elapsed(self, now: float) -> float:
        wall = _number(self.state, "wall_s")
        if math.isfinite(wall):
            return wall + (now - self._stamp)  # the run's clock, advanced since its last report
        return now - (self._start if self._start is not None else now)

    def _line(self, now: float) -> str:
        s = self.state
        t, t_end = _number(s, "t"), _number(s, "t_end")
        pct = 100.0 * t / t_end if t_end > 0 else math.nan
        return (f"kt {t:.4f} / {t_end:g} ({pct:3.0f} %)  elapsed {format_duration(self._elapsed(now))}"
                f"  ETA {format_duration(self._eta(now))}  dt {_number(s, 'dt'):.2e}"
                f"  D_xy {_number(s, 'D_xy'):.5f}  step {int(_number(s, 'step')) if math.isfinite(_number(s, 'step')) else 0}")

    def __call__(self, state: Mapping[str, Any]) -> None:
        now = self.clock()
        self.state = dict(state)
        self._stamp = now
        if self._start is None:
            self._start, self._t0 = now, _number(state, "t")
        self._show(now)

    def _refresh_live(self, final: bool = False) -> None:
        from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeRemainingColumn

        s = self.state
        t, t_end = _number(s, "t"), _number(s, "t_end")
        if not math.isfinite(t_end) or t_end <= 0:
            return
        info = f"dt {_number(s, 'dt'):.2e}  D_xy {_number(s, 'D_xy'):.5f}"
        # the elapsed column is the run's own clock (rich's would start at the first step)
        elapsed = format_duration(self._elapsed(self.clock()))
        if self._live is None:
            self._live = Progress(
                TextColumn("kt {task.fields[kt]}"), BarColumn(), TaskProgressColumn(),
                TextColumn("{task.fields[elapsed]}"), TextColumn("ETA"), TimeRemainingColumn(),
                TextColumn("{task.fields[info]}"),
                console=self._console(), auto_refresh=False, transient=False,
            )
            self._live.start()
            self._task = self._live.add_task("run", total=t_end, completed=t if math.isfinite(t) else 0.0,
                                             kt=f"{t:.3f} / {t_end:g}", info=info, elapsed=elapsed)
        else:
            self._live.update(self._task, completed=t, total=t_end, kt=f"{t:.3f} / {t_end:g}", info=info,
                              elapsed=elapsed)
        self._live.refresh()


class SweepProgress(_Display):
    """Progress of a campaign; called with run_campaign's ``{total, skipped, done, failed,
    running, kt: {run_id: t}}``. ``t_end`` maps run ids to their end times."""

    def __init__(self, t_end: Mapping[str, float] | None = None, stream: TextIO | None = None, *,
                 terminal: bool | None = None, interval_s: float | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(stream, terminal, interval_s, clock)
        self.t_end = dict(t_end or {})
        self.state: dict[str, Any] = {"total": 0, "skipped": 0, "done": 0, "failed": 0, "running": 0, "kt": {}}
        self._rows: dict[str, Any] = {}
        self._overall = None
        self._last_draw = -math.inf
        self._f0 = 0.0

    # what the state says, with the running count that cannot go stale
    def counts(self) -> dict[str, int]:
        s = self.state
        total = int(s.get("total", 0))
        finished = int(s.get("skipped", 0)) + int(s.get("done", 0)) + int(s.get("failed", 0))
        kt = s.get("kt") or {}
        running = len(kt) if kt else max(0, min(int(s.get("running", 0)), total - finished))
        return {"total": total, "finished": finished, "running": running, "skipped": int(s.get("skipped", 0)),
                "done": int(s.get("done", 0)), "failed": int(s.get("failed", 0))}

    def fraction(self) -> float:
        """Share of the campaign's work done: finished runs plus the running ones' kt / t_end."""
        c = self.counts()
        if c["total"] <= 0:
            return 1.0
        part = 0.0
        for run_id, t in (self.state.get("kt") or {}).items():
            t_end = self.t_end.get(run_id)
            if t_end and t_end > 0:
                part += min(max(float(t) / t_end, 0.0), 1.0)
        return min(1.0, (c["finished"] + part) / c["total"])

    def _eta(self, now: float) -> float | None:
        f = self.fraction()
        elapsed = now - (self._start if self._start is not None else now)
        if f >= 1.0:
            return 0.0
        if f - self._f0 <= 0 or elapsed <= 0:
            return None
        return (1.0 - f) * elapsed / (f - self._f0)

    def _run_text(self, run_id: str, t: float) -> str:
        t_end = self.t_end.get(run_id)
        return f"{run_id} kt {t:.2f}" + (f"/{t_end:g}" if t_end else "")

    def _line(self, now: float) -> str:
        c = self.counts()
        line = (f"runs {c['finished']}/{c['total']} done ({c['skipped']} skipped), {c['failed']} failed, "
                f"{c['running']} running  {100 * self.fraction():3.0f} %  elapsed "
                f"{format_duration(now - (self._start if self._start is not None else now))}  ETA {format_duration(self._eta(now))}")
        kt = list((self.state.get("kt") or {}).items())
        if kt:
            shown = ", ".join(self._run_text(r, t) for r, t in kt[:PLAIN_RUNS_SHOWN])
            more = f", +{len(kt) - PLAIN_RUNS_SHOWN} more" if len(kt) > PLAIN_RUNS_SHOWN else ""
            line += f"  | {shown}{more}"
        return line

    def __call__(self, state: Mapping[str, Any]) -> None:
        now = self.clock()
        self.state = {**dict(state), "kt": dict(state.get("kt") or {})}
        if self._start is None:
            self._start = now
            self._f0 = self.fraction()
        self._show(now)

    def _refresh_live(self, final: bool = False) -> None:
        from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeElapsedColumn, \
            TimeRemainingColumn

        c = self.counts()
        if self._live is None:
            self._live = Progress(
                TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(),
                TimeElapsedColumn(), TextColumn("{task.fields[eta]}"), TimeRemainingColumn(),
                TextColumn("{task.fields[info]}"),
                console=self._console(), auto_refresh=False, transient=False,
            )
            self._live.start()
            self._overall = self._live.add_task("campaign", total=max(c["total"], 1),
                                                completed=self.fraction() * max(c["total"], 1), eta="ETA", info="")
        info = f"{c['finished']}/{c['total']} done ({c['skipped']} skipped), {c['failed']} failed, {c['running']} running"
        self._live.update(self._overall, completed=self.fraction() * max(c["total"], 1), info=info)
        kt = {} if final else (self.state.get("kt") or {})
        for run_id in [r for r in self._rows if r not in kt]:
            self._live.remove_task(self._rows.pop(run_id))
        for run_id, t in kt.items():
            t_end = self.t_end.get(run_id) or 1.0
            text = f"kt {t:.2f} / {t_end:g}" if run_id in self.t_end else f"kt {t:.2f}"
            if run_id not in self._rows:
                self._rows[run_id] = self._live.add_task(f"  {run_id}", total=t_end, completed=t, eta="", info=text)
            else:
                self._live.update(self._rows[run_id], completed=t, info=text)
        self._live.refresh()


def print_table(rows: Iterable[tuple[str, Any]] | Iterable[Iterable[Any]], *, columns: Iterable[str] | None = None,
                title: str | None = None, stream: TextIO | None = None) -> None:
    """A rich table on stdout: ``rows`` of (key, value) pairs, or rows under ``columns``."""
    from rich import box
    from rich.console import Console
    from rich.table import Table

    stream = stream if stream is not None else sys.stdout
    table = Table(title=title, box=box.SIMPLE_HEAD, show_header=columns is not None, title_justify="left",
                  pad_edge=False)
    names = list(columns) if columns is not None else ["", ""]
    for i, name in enumerate(names):
        table.add_column(name, style="bold" if (columns is None and i == 0) else None, overflow="fold")
    for row in rows:
        table.add_row(*("" if v is None else str(v) for v in row))
    if is_terminal(stream):
        Console(file=stream, highlight=False).print(table)
        return
    # a log or a pipe: wide enough that no row folds, no trailing blanks, no control codes
    width = max(200, int(os.environ.get("COLUMNS", "0") or 0))
    console = Console(file=stream, highlight=False, width=width, color_system=None, force_terminal=False)
    with console.capture() as captured:
        console.print(table)
    stream.write("\n".join(line.rstrip() for line in captured.get().splitlines()).strip("\n") + "\n")
    stream.flush()


# ---------------------------------------------------------------- the closing table of a run


def fmt(value: Any, spec: str) -> str:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return format(value, spec)
    return "n/a" if value is None else str(value)


def _mean_std(summary: dict[str, Any], name: str, scale: float = 1.0) -> str | None:
    """'mean ± std' over the averaging window, or None when the run has no summary."""
    mean, std = summary.get(name), summary.get(f"{name}_std")
    if not isinstance(mean, (int, float)):
        return None
    if math.isnan(mean):  # θ of a tumbling run, or of a shape without a long axis
        return "undefined (NaN)"
    shown = f"{mean / scale:.6f}"
    return shown + (f" ± {std / scale:.2e}" if isinstance(std, (int, float)) else "")


def _area_change(summary: dict[str, Any]) -> str | None:
    """The membrane's largest area change over the run; with skalak_c auto, whether it stayed within the
    area tolerance its C was chosen for (the choice is a prediction: docs/laws.md)."""
    largest = summary.get("largest_area_change")
    if not isinstance(largest, float):
        return None
    text = f"largest {100 * largest:.3g} %"
    tolerance = summary.get("area_tolerance")
    if isinstance(tolerance, float):
        text += (f", within membrane.area_tolerance {100 * tolerance:g} % (skalak_c auto)" if largest <= tolerance
                 else f": beyond membrane.area_tolerance {100 * tolerance:g} % that skalak_c auto chose C for; "
                 "set a larger skalak_c (or a smaller area_tolerance) for a nearly area-incompressible membrane")
    return text


def _compression(summary: dict[str, Any], factors: Mapping[str, float] | None = None) -> str | None:
    """Share of the membrane under compression at the end, with a warning when large.

    A membrane without bending stiffness cannot carry compression: where the smaller
    principal tension is negative a real capsule wrinkles, and where the compression
    persists the computed solution comes to depend on the mesh (docs/user_guide.md, "Compressed
    membranes and bending stiffness").
    """
    frac, low = summary.get("compressed_fraction"), summary.get("min_tension")
    if not isinstance(frac, float):
        return None
    G = summary.get("shear_rate_G")
    # one tension scale on every screen: E_s, as the tension figure and the export (the stored
    # min_tension is in μka = E_s/G); μka only where G is not known; physical units on asking
    if factors is not None:
        factor, unit = _in("min_tension", factors)
        shown = f"{low * factor:.3g} {unit}"
    else:
        shown = f"{low * G:.3g} E_s" if isinstance(G, (int, float)) and G > 0 else f"{low:.3g} μka"
    text = f"{100 * frac:.0f} % (smallest tension {shown})"
    if frac > 0.05:
        if summary.get("bending_modulus", 0.0) > 0:
            factor, unit = _in("bending_modulus", factors)
            kappa = f"{summary['bending_modulus'] * factor:.3g} {unit}" if factors is not None else \
                f"{summary['bending_modulus']:g} E_s a²"
            text += f": held by the bending modulus {kappa}; check mesh convergence"
        else:
            text += (": would wrinkle without bending; rerun with --set membrane.bending_modulus=1e-4 "
                     "(docs/user_guide.md, \"Compressed membranes and bending stiffness\")")
    return text


def _in(name: str, factors: Mapping[str, float] | None) -> tuple[float, str]:
    """(what a value of `name` is multiplied by, its unit) for the table: 1 and "" in capsim's
    scales; in physical units (`factors` from capsim.units.physical_factors) the factor of its
    scale and the unit of capsim.quantities, the one table of units."""
    if factors is None:
        return 1.0, ""
    from capsim.quantities import physical_units

    unit, scale = physical_units(name)
    return (factors[scale], unit) if scale else (1.0, "")


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _motion(summary: dict[str, Any]) -> str | None:
    """The class, and when the run has judged it and it has not settled, that it has not (a
    run file written before issue 39 has no `settled`: its class alone is shown)."""
    motion = summary.get("motion")
    if not motion:
        return None
    from capsim.quantities import canonical_motion

    shown = canonical_motion(str(motion))
    if summary.get("settled") == 0.0 and shown not in ("unstable", "relaxing", "transient") \
            and not shown.startswith("drifting"):
        shown += " (not settled)"
    return shown


def _orbits(n: Any) -> str:
    n = int(n) if _finite(n) else 0
    return f"{n} whole orbit{'' if n == 1 else 's'}"


def _orbit_rows(summary: dict[str, Any], factors: Mapping[str, float] | None) -> list[tuple[str, str | None]]:
    """The orbit's numbers (issue 39), for a run whose body has an axis: the orbit period and
    the whole orbits behind it, Jeffery's orbit constant with its change per orbit, the axis's
    angle from the vorticity axis, the shape's own period where the shape oscillates, and the
    body's and the membrane's rotation rates (which of them ttf_ratio is)."""
    polar, r = summary.get("final_polar_angle"), summary.get("jeffery_aspect_ratio")
    if not _finite(polar) or (_finite(r) and abs(r - 1.0) < 1e-3):  # a sphere has no axis to orbit
        return []
    physical = factors is not None
    f_t, u_t = _in("t", factors)
    f_r, u_r = _in("body_rotation_ratio", factors)
    rows: list[tuple[str, str | None]] = []
    T, n = summary.get("orbit_period"), summary.get("orbit_periods")
    if _finite(T):
        jeffery = summary.get("jeffery_period")
        ref = f", Jeffery's rigid {jeffery * f_t:.4g}" if _finite(jeffery) else ""
        rows.append((f"orbit period T ({u_t})" if physical else "orbit period kT",
                     f"{T * f_t:.4g} (the axis once round; {_orbits(n)}{ref})"))
    C, change = summary.get("orbit_constant"), summary.get("orbit_constant_change")
    if _finite(C) or (isinstance(C, float) and math.isinf(C)):
        text = "inf (in the shear plane)" if math.isinf(C) else f"{C:.4g}"
        if _finite(change):
            text += f", {100 * change:+.1f} % per orbit now"
        drift = summary.get("orbit_constant_drift")
        if _finite(drift):
            text += f" ({100 * drift:+.1f} % per orbit over the run, from {summary.get('orbit_constant_first', float('nan')):.4g})"
        rows.append(("orbit constant C", text))
    rows.append(("axis from vorticity z (deg)", f"{math.degrees(polar):.2f} (at the end; 0 rolling, 90 in the plane)"))
    shape_T = summary.get("shape_period")
    if _finite(shape_T):
        rows.append((f"shape period ({u_t})" if physical else "shape period kT", f"{shape_T * f_t:.4g}"))
    body, membrane = summary.get("body_rotation_ratio"), summary.get("tank_treading_ratio")
    if _finite(body) or _finite(membrane):
        def rate(v: Any) -> str:
            return f"{v * f_r:.4g}" if _finite(v) else "n/a"

        unit = u_r if physical else "f_s"
        rows.append((f"body turn, membrane on it ({unit})" if physical else "body turn, membrane on it (/f_s)",
                     f"{rate(body)}, {rate(membrane)} (clockwise about z)"))
    return rows


def summary_rows(summary: dict[str, Any], factors: Mapping[str, float] | None = None) -> list[tuple[str, str]]:
    """The closing table of a run: (quantity, value) rows, those without a value left out.
    With `factors` (``--units physical``) times, frequencies, stresslets and tensions are in
    physical units (each row names its unit); D_xy and θ/π are ratios either way. A run whose
    body has an axis adds its orbit (:func:`_orbit_rows`); the TTF row says what it measures
    when the body turns."""
    period = summary.get("period")
    window = (summary.get("averaging_t_from"), summary.get("averaging_t_to"))
    f_t, u_t = _in("t", factors)
    time = f"t ({u_t})" if factors is not None else "t"
    physical = factors is not None

    def scaled(name: str, label: str, physical_label: str) -> tuple[str, str | None]:
        factor, unit = _in(name, factors)
        return (f"{physical_label} ({unit})" if physical else label), _mean_std(summary, name, 1.0 / factor)

    rows = [
        ("status", summary.get("status")),
        ("reason", summary.get("status_reason") or None),
        (time, fmt(summary.get("t") * f_t if isinstance(summary.get("t"), (int, float)) else summary.get("t"), "g")),
        ("motion", _motion(summary)),
        (f"averaged over {time if physical else 'kt'}",
         f"[{window[0] * f_t:.4g}, {window[1] * f_t:.4g}] (mean ± standard deviation over this window)"
         if None not in window else None),
        # the motion's period; a turning body's is its orbit period, shown with the orbit's rows
        (f"period T ({u_t})" if physical else "period kT",
         fmt(period * f_t, ".4g") if isinstance(period, float) and math.isfinite(period)
         and period != summary.get("orbit_period") else None),
        *_orbit_rows(summary, factors),
        *_scene_rows(summary),
        *_drift_rows(summary, factors),
        ("D_xy", _mean_std(summary, "D_xy")),
        ("theta/pi", _mean_std(summary, "theta", math.pi)),
        *(_conduit_rows(summary) if _in_conduit(summary) else (
            _ttf(scaled("ttf_ratio", "TTF/f_s", "TTF f"), summary),
            scaled("Sxy_star", "S*_xy", "S_xy"),
            scaled("N1_star", "N1*", "S_xx - S_yy"),
            scaled("N2_star", "N2*", "S_yy - S_zz"))),
        ("scheme", summary.get("scheme")),
        ("scheme chosen because", summary.get("scheme_choice")),
        ("rtol", (f"{summary['rtol']:g}" + (f" ({summary['rtol_choice']})" if summary.get("rtol_choice") else ""))
         if isinstance(summary.get("rtol"), float) else None),
        ("steps", fmt(summary.get("steps"), "d")),
        ("velocity evaluations", fmt(summary.get("velocity_evaluations"), "d")),
        ("layer applications", fmt(summary.get("layer_applications"), "d")),
        # only the linearly implicit scheme solves stage equations
        ("stage-solve iterations", fmt(summary.get("linear_iterations"), "d") if summary.get("linear_iterations") else None),
        ("layer matrices", fmt(summary.get("layer_matrices"), "d") if summary.get("layer_matrices") else None),
        ("wall time (s)", fmt(summary.get("wall_time_s"), ".1f")),
        ("volume drift", fmt(summary.get("volume_drift"), ".3e")),
        ("area change", _area_change(summary)),
        ("centroid travelled (a)", _travel(summary)),
        ("compressed vertices", _compression(summary, factors)),
        ("output", summary.get("path")),
    ]
    return [(key, str(value)) for key, value in rows if value is not None]


#: the closing table names the centroid's travel beyond this many a: a capsule carried far (the
#: outflow of an extension, a far-off start in shear) is measured about its own centroid, and the
#: reader of a D_xy should know it was not where it started
FAR_TRAVEL = 10.0


def _travel(summary: dict[str, Any]) -> str | None:
    """The centroid's travel, where it went beyond FAR_TRAVEL a (an extension's outflow)."""
    d = summary.get("centroid_travel")
    if not isinstance(d, float) or not d > FAR_TRAVEL:
        return None
    return f"{d:.4g} (carried far from its start; the shape's values are measured about its centroid)"


def _in_conduit(summary: dict[str, Any]) -> bool:
    """Whether the run's capsule flowed through a conduit (its summary has the conduit's numbers; ΔP+
    may be NaN: λ ≠ 1 in a constriction)."""
    return _finite(summary.get("axis_offset"))


def _conduit_rows(summary: dict[str, Any]) -> list[tuple[str, str | None]]:
    """A capsule in a conduit (capsim.scene.conduit): its speed over the mean velocity U, the
    pressure drop it adds, its distance from the axis and its lengths along and across; the
    tank-treading and stresslet rows of a linear flow have no meaning there."""
    def pair(a: str, b: str) -> str | None:
        if not (_finite(summary.get(a)) and _finite(summary.get(b))):
            return None
        return f"{summary[a]:.4f} along, {summary[b]:.4f} across"

    return [("capsule speed / U", _mean_std(summary, "centroid_velocity_x")),
            ("extra pressure drop ΔP+ (μU/a)", _mean_std(summary, "extra_pressure_drop")),
            ("distance from the axis (a)", _mean_std(summary, "axis_offset")),
            ("length (a)", pair("length_along", "width_across"))]


def _scene_rows(summary: dict[str, Any]) -> list[tuple[str, str | None]]:
    """A scene of several capsules: how many (the rows below are their means), the closest
    approach, and a pair's cross-stream separation at the start, its peak and its end."""
    per = summary.get("capsule")
    if not isinstance(per, Mapping):
        return []
    n = len(per.get("motion", ()))
    rows: list[tuple[str, str | None]] = [("capsules", f"{n} (the rows below: the mean over them)")]
    if isinstance(summary.get("min_capsule_gap"), float):
        rows.append(("closest approach (a)", fmt(summary["min_capsule_gap"], ".4g")))
    if isinstance(summary.get("separation_y_final"), float):
        rows.append(("cross-stream separation (a)",
                     f"{summary['separation_y_initial']:.4g} at the start, peak {summary['separation_y_peak']:.4g}, "
                     f"{summary['separation_y_final']:.4g} at the end (streamwise {summary['separation_x_final']:.4g})"))
    return rows


def scene_features(summary: Mapping[str, Any]) -> dict[str, bool]:
    """What the run's scene has, for the rows only some scenes show: ``wall`` (a plane wall), ``conduit``,
    ``varying_gradient`` (a far field whose rate varies across the stream, Poiseuille's: a capsule
    migrates across it). From ``summary["scene"]`` where given, else the scene of the case stored in the
    run file at ``summary["path"]`` (capsim.scene.Scene), else what the summary's own numbers show (a
    wall's gap; the varying gradient is then not known, and not shown)."""
    given = summary.get("scene")
    if isinstance(given, Mapping):
        return {k: bool(given.get(k, False)) for k in ("wall", "conduit", "varying_gradient")}
    try:
        from capsim.scene import Scene
        from capsim.storage.store import read_case

        scene = Scene.of(read_case(summary["path"]))
    except Exception:  # noqa: BLE001 - no readable run file (a summary given by hand): its own numbers
        conduit = _in_conduit(dict(summary))
        return {"wall": _finite(summary.get("wall_gap_final")) and not conduit, "conduit": conduit,
                "varying_gradient": False}
    names = {b.name for b in scene.boundaries}
    return {"wall": "plane_wall" in names, "conduit": bool(names - {"plane_wall"}),
            "varying_gradient": not scene.uniform_gradient and not scene.has_boundary}


def _drift_rows(summary: dict[str, Any], factors: Mapping[str, float] | None) -> list[tuple[str, str | None]]:
    """A scene's drift across the flow (issue 54): with a wall, the lift and slip velocities (window mean
    ± standard deviation) and the gap (start, smallest, end); in a flow whose rate varies across the stream
    (Poiseuille's), the migration in y from start to end with its mean rate and its rate over the window.
    Only where the scene has them (:func:`scene_features`)."""
    scene = scene_features(summary)
    f_v, u_v = _in("centroid_velocity_y", factors)
    f_a, u_a = _in("wall_gap", factors)
    f_t, u_t = _in("t", factors)
    speed = u_v if factors is not None else "k a"
    length = u_a if factors is not None else "a"
    rows: list[tuple[str, str | None]] = []
    if scene["wall"]:
        rows.append((f"lift velocity, y ({speed})", _mean_std(summary, "centroid_velocity_y", 1.0 / f_v)))
        rows.append((f"slip velocity, x ({speed})", _mean_std(summary, "slip_velocity_x", 1.0 / f_v)))
        if all(_finite(summary.get(k)) for k in ("wall_gap_initial", "wall_gap_min", "wall_gap_final")):
            rows.append((f"wall gap ({length})",
                         f"{summary['wall_gap_initial'] * f_a:.4g} at the start, smallest "
                         f"{summary['wall_gap_min'] * f_a:.4g}, {summary['wall_gap_final'] * f_a:.4g} at the end"))
    if scene["varying_gradient"] and all(_finite(summary.get(k)) for k in ("centroid_y_initial", "centroid_y_final")):
        y0, y1 = summary["centroid_y_initial"], summary["centroid_y_final"]
        moved = summary.get("migration_y", y1 - y0)
        t = summary.get("t")
        text = f"{y0 * f_a:.4g} -> {y1 * f_a:.4g} ({moved * f_a:+.4g}"
        if _finite(t) and t > 0:
            unit = f" {u_v}" if factors is not None else " k a"
            text += f" over {'t' if factors is not None else 'kt'} {t * f_t:.4g}: {moved / t * f_v:+.3g}{unit} on average"
        text += ")"
        now = _mean_std(summary, "centroid_velocity_y", 1.0 / f_v)
        if now is not None:
            text += f"; over the window {now}"
        rows.append((f"migration in y ({length})", text))
    return rows


def _ttf(row: tuple[str, str | None], summary: dict[str, Any]) -> tuple[str, str | None]:
    """The TTF row, saying what it is when the body turns (ttf_ratio_kind: it is then the
    body's turn, nearly rigid or with tank-treading on top, not tank-treading alone)."""
    label, value = row
    kind = summary.get("ttf_ratio_kind")
    if value is not None and kind in (1.0, 2.0):
        value += " (the body's turn, nearly rigid)" if kind == 2.0 else " (the body's turn plus tank-treading)"
    return label, value


def summary_table(summary: dict[str, Any], factors: Mapping[str, float] | None = None) -> str:
    """The closing table as plain aligned text."""
    rows = summary_rows(summary, factors)
    width = max(len(key) for key, _ in rows)
    return "\n".join(f"{key:<{width}}  {value}" for key, value in rows)


def print_summary(summary: dict[str, Any], title: str | None = None,
                  factors: Mapping[str, float] | None = None) -> None:
    print_table(summary_rows(summary, factors), title=title)


def print_sweep_result(result: dict[str, Any], campaign: Any, table: bool = True) -> None:
    """What `capsim sweep` prints at the end: the runs that did not complete (stderr), a
    table of the runs (unless not `table`) and the one-line count."""
    import typer

    for record in result["records"]:
        if record["status"] != "completed":
            typer.echo(f"{record['run_id']}: {record['status']}: {record['status_reason']}", err=True)
    if result["records"] and table:
        def cell(record: dict, key: str, spec: str) -> str:
            summary = record.get("summary") or {}
            return fmt(summary.get(key), spec) if key in summary else ""

        print_table([(r["run_id"], r["status"], cell(r, "t", ".4g"), cell(r, "D_xy", ".5f"),
                      cell(r, "wall_time_s", ".1f"), r.get("status_reason") or "")
                     for r in result["records"]],
                    columns=("run", "status", "kt", "D_xy", "wall (s)", "reason"), title=campaign.name)
    not_started = result["total"] - result["skipped"] - result["completed"] - result["failed"]
    typer.echo(
        f"{campaign.name}: {result['total']} runs, {result['skipped']} skipped, {result['completed']} completed, "
        f"{result['failed']} not completed{' (interrupted)' if result['interrupted'] else ''}"
        + (f", {not_started} not started" if not_started > 0 else "")
        + f" -> {campaign.output.dir}"
    )


def key_value_lines(result: Mapping[str, Any]) -> str:
    """A flat mapping as aligned 'key  value' lines (floats to 6 digits, others as JSON)."""
    import json

    width = max((len(key) for key in result), default=0)
    lines = []
    for key, value in result.items():
        if isinstance(value, float):
            shown = f"{value:.6g}"
        elif isinstance(value, (str, int)):
            shown = str(value)
        else:
            shown = json.dumps(value, default=str)
        lines.append(f"{key:<{width}}  {shown}")
    return "\n".join(lines)
