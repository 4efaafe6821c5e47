"""A run's surface mesh over time, with membrane fields, for ParaView.

``capsim export RUN.h5 [--format xdmf|vtu] [-o DIR]`` writes every snapshot of
the trajectory as 6-node quadratic triangles (VTK_QUADRATIC_TRIANGLE / XDMF
``Triangle_6``: three corners, then the mid-side nodes of edges 01, 12, 20 —
the node order capsim uses) with

point data
    ``displacement``        x − X from the rest shape (a)
    ``velocity``            u(x), recomputed from the boundary-integral equation (a k)
    ``traction_jump``       nodal Δf, when the model's traction is nodal (galerkin) (E_s/a)
    ``tension``             tension tensor T, 9 components row-major (E_s)
    ``principal_tension_1/2``  eigenvalues of T in the tangent plane, τ1 ≥ τ2 (E_s)
    ``principal_stretch_1/2``  λ1 ≥ λ2 (1)

cell data
    ``traction``            element average of Δf, ∫ Δf dS / S_e (E_s/a)

point and cell data of a run of several capsules (one mesh, every capsule's surface)
    ``capsule``             the capsule's index (0, 1, ...: the case's ``capsules`` order), an
                            integer to colour or threshold by (one capsule: not written)

T and the stretches live at the vertex nodes; a mid-side node gets the mean of
its edge's two vertices. Fields are recomputed from the stored positions by
rebuilding the run's model from its stored case (``runner.build_model``).

xdmf: ``<stem>.xdmf`` (a temporal collection, one grid per snapshot with its
own geometry, so the surface moves) with heavy data in ``<stem>_data.h5``.
vtu: ``<stem>_NNNN.vtu`` per snapshot and ``<stem>.pvd`` giving their times.
Open the .xdmf (XDMF reader) or the .pvd in ParaView.
"""

from __future__ import annotations

import os
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from capsim.storage.files import StorageError, write_failure

__all__ = ["FORMATS", "case_of", "export_run", "membrane_fields", "model_for", "snapshot_fields"]

FORMATS = ("xdmf", "vtu")


def case_of(data: dict[str, Any]):
    """The Case a trajectory was run with (from its stored config_yaml)."""
    import yaml

    from capsim.config import case_from_dict

    return case_from_dict(yaml.safe_load(data["attrs"]["config_yaml"]), source="config_yaml")


def model_for(data: dict[str, Any]):
    """The run's CapsuleModel, its membranes' stress-free reference made from the stored rest shape
    (the initial positions) as the run made it (capsim.solve.solver.build_model: shape.inflation,
    membrane.reference_shape)."""
    from capsim.runs.runner import build_model

    rest = np.asarray(data["rest_positions"], dtype=np.float64)
    try:
        model, X = build_model(case_of(data), rest_positions=rest)
        matches = np.array_equal(model.disc.elements, data["elements"])
    except ValueError as exc:  # the stored rest shape has another node count
        if not str(exc).startswith("rest positions of shape"):
            raise
        matches, X = False, None
    if not matches:
        rebuilt = f"{X.shape[0]} nodes" if X is not None else "another node count"
        raise ValueError(f"the stored mesh ({rest.shape[0]} nodes) does not match the mesh rebuilt from the case "
                         f"({rebuilt})")
    return model


#: the fields a run of several capsules adds (issue 43): name → (what it is, its capsim scale;
#: "" for a pure number), beside capsim.quantities.EXPORT_FIELDS
SCENE_FIELDS: dict[str, tuple[str, str]] = {
    "capsule": ("the capsule's index (0, 1, ... in the case's capsules order), at every node and element", ""),
}


def capsule_fields(data: dict[str, Any]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(point_data, cell_data) ``capsule`` of a run of several capsules: each node's and each
    element's capsule index in the union mesh (capsim.scene.bodies layout); ({}, {}) for one capsule."""
    from capsim.scene import run_bodies

    bodies = run_bodies(data)
    if bodies.count < 2:
        return {}, {}
    cell = np.repeat(np.arange(bodies.count, dtype=np.int64), bodies.elements_per_body)
    return {"capsule": bodies.node_body}, {"capsule": cell}


def _tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (N, 3) orthogonal to the unit normals n (N, 3)."""
    helper = np.zeros_like(n)
    use_x = np.abs(n[:, 0]) < 0.9
    helper[use_x, 0] = 1.0
    helper[~use_x, 1] = 1.0
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    return t1, np.cross(n, t1)


def _vertex_to_nodes(values: np.ndarray, elements: np.ndarray, n_nodes: int) -> np.ndarray:
    """Extend vertex values (N_v, ...) to all nodes: mid-side node = mean of its edge's vertices."""
    out = np.empty((n_nodes,) + values.shape[1:], dtype=np.float64)
    n_v = values.shape[0]
    out[:n_v] = values
    for mid, (a, b) in zip((3, 4, 5), ((0, 1), (1, 2), (2, 0))):
        out[elements[:, mid]] = 0.5 * (values[elements[:, a]] + values[elements[:, b]])
    return out


def membrane_fields(model, x: np.ndarray, state=None) -> dict[str, np.ndarray]:
    """Nodal tension tensor, principal tensions and stretches at configuration x."""
    if state is None:
        state = model.membrane(x)
    elements = model.disc.elements
    n_nodes = x.shape[0]
    T = np.asarray(state.tension)
    t1, t2 = _tangent_basis(np.asarray(state.strain.normals))
    basis = np.stack([t1, t2], axis=1)                    # (N_v, 2, 3)
    M = np.einsum("vai,vij,vbj->vab", basis, T, basis)
    M = 0.5 * (M + np.swapaxes(M, 1, 2))
    eig = np.linalg.eigvalsh(M)                           # ascending
    l1, l2 = state.strain.principal_stretches
    fields = {
        "tension": _vertex_to_nodes(T.reshape(-1, 9), elements, n_nodes),
        "principal_tension_1": _vertex_to_nodes(eig[:, 1], elements, n_nodes),
        "principal_tension_2": _vertex_to_nodes(eig[:, 0], elements, n_nodes),
        "principal_stretch_1": _vertex_to_nodes(np.asarray(l1), elements, n_nodes),
        "principal_stretch_2": _vertex_to_nodes(np.asarray(l2), elements, n_nodes),
    }
    return fields


def snapshot_fields(model, x: np.ndarray, rest: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(point_data, cell_data) of one snapshot."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    state = model.membrane(x)
    u = model.velocity(x, state)
    point = {"displacement": x - rest, "velocity": np.asarray(u, dtype=np.float64)}
    traction = np.asarray(state.traction)
    if traction.shape[0] == x.shape[0] and traction.shape[0] != model.disc.elements.shape[0]:
        point["traction_jump"] = traction
    point.update(membrane_fields(model, x, state))
    density = np.asarray(state.density)
    if density.ndim == 3:  # (N_e, 6, 3) nodal values of each element: the cell's force over its area
        integral = np.einsum("qk,ekd,eq->ed", model.disc.reg_phi, density, state.weights)
        cell_traction = integral / state.geometry.weights.sum(axis=1)[:, None]
    else:                  # (N_e, 3) element-constant
        cell_traction = density
    return point, {"traction": np.ascontiguousarray(cell_traction, dtype=np.float64)}


# ------------------------------------------------------------------ writers


def _units_text(name: str, factors: dict | None) -> str:
    """The unit of export field `name` (capsim.quantities.EXPORT_FIELDS): the physical unit of
    its scale (SCALE_UNITS) with `factors`, else the capsim scale it is measured in."""
    from capsim.quantities import EXPORT_FIELDS, SCALE_UNITS

    scale = {**EXPORT_FIELDS, **SCENE_FIELDS}[name][1]
    if not scale:
        return "1"
    return SCALE_UNITS[scale][1] if factors is not None else f"1 (capsim scale {scale})"


def _scaled(fields: dict[str, np.ndarray], factors: dict | None) -> dict[str, np.ndarray]:
    """The fields times the factor of their scale (physical units), or as they are."""
    from capsim.quantities import EXPORT_FIELDS

    if factors is None:
        return fields
    return {name: value * factors[EXPORT_FIELDS[name][1]] if EXPORT_FIELDS[name][1] else value
            for name, value in fields.items()}


def _xdmf_item(parent: ET.Element, h5name: str, path: str, array: np.ndarray) -> None:
    if array.dtype.kind == "f":
        number, precision = "Float", "8"
    else:
        number, precision = "Int", "8"
    dims = " ".join(str(d) for d in array.shape)
    item = ET.SubElement(parent, "DataItem", Dimensions=dims, NumberType=number, Precision=precision, Format="HDF")
    item.text = f"{h5name}:{path}"


def _attribute_type(array: np.ndarray) -> str:
    if array.ndim == 1:
        return "Scalar"
    return {3: "Vector", 9: "Tensor"}.get(array.shape[1], "Matrix")


def _field_names(extra: tuple[str, ...]) -> list[str]:
    """The export fields whose units the index file names: capsim.quantities.EXPORT_FIELDS and
    the scene's fields this run writes (``extra``)."""
    from capsim.quantities import EXPORT_FIELDS

    return list(EXPORT_FIELDS) + [name for name in extra if name not in EXPORT_FIELDS]


def _write_xdmf(out_dir: Path, stem: str, elements, rest, snapshots, factors=None, extra=()) -> list[Path]:
    h5name = f"{stem}_data.h5"
    xdmf_path = out_dir / f"{stem}.xdmf"
    root = ET.Element("Xdmf", Version="3.0")
    domain = ET.SubElement(root, "Domain")
    # the units of time, positions and each field, as XDMF Information elements of the domain
    # (readers such as meshio take every child of the collection for a time step, and an
    # Attribute for its one DataItem)
    for name in _field_names(extra):
        ET.SubElement(domain, "Information", Name=f"units_{name}", Value=_units_text(name, factors))
    collection = ET.SubElement(domain, "Grid", Name=stem, GridType="Collection", CollectionType="Temporal")
    elements = np.asarray(elements, dtype=np.int64)
    # Built in memory and written with one plain write: a full disk or a file-size limit
    # then fails that write cleanly, never inside HDF5 (where it has crashed the process).
    h5 = h5py.File(f"capsim-export-{os.getpid()}-{id(root)}", "w", driver="core", backing_store=False)
    try:
        h5.create_dataset("topology", data=elements)
        for k, (t, x, point, cell) in enumerate(snapshots):
            grid = ET.SubElement(collection, "Grid", Name=f"{stem}_{k:04d}", GridType="Uniform")
            ET.SubElement(grid, "Time", Value=repr(float(t)))
            topo = ET.SubElement(
                grid, "Topology", TopologyType="Triangle_6", NumberOfElements=str(elements.shape[0]),
                NodesPerElement="6",
            )
            _xdmf_item(topo, h5name, "/topology", elements)
            geo = ET.SubElement(grid, "Geometry", GeometryType="XYZ")
            h5.create_dataset(f"geometry/{k}", data=x)
            _xdmf_item(geo, h5name, f"/geometry/{k}", x)
            for center, fields in (("Node", point), ("Cell", cell)):
                for name, value in fields.items():
                    path = f"/{center.lower()}/{name}/{k}"
                    h5.create_dataset(path, data=value)
                    attr = ET.SubElement(grid, "Attribute", Name=name, AttributeType=_attribute_type(value), Center=center)
                    _xdmf_item(attr, h5name, path, value)
        h5.flush()
        image = h5.id.get_file_image()
    finally:
        h5.close()
    with open(out_dir / h5name, "wb") as fh:
        fh.write(image)
    ET.indent(root)
    ET.ElementTree(root).write(xdmf_path, encoding="utf-8", xml_declaration=True)
    return [xdmf_path, out_dir / h5name]


def _write_vtu(out_dir: Path, stem: str, elements, rest, snapshots, factors=None, extra=()) -> list[Path]:
    import meshio

    written = []
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    # a .vtu has no place for units: the collection file names them, one comment
    root.append(ET.Comment(" units: " + "; ".join(f"{name}: {_units_text(name, factors)}"
                                                   for name in _field_names(extra)) + " "))
    coll = ET.SubElement(root, "Collection")
    for k, (t, x, point, cell) in enumerate(snapshots):
        name = f"{stem}_{k:04d}.vtu"
        mesh = meshio.Mesh(
            np.asarray(x, dtype=np.float64), [("triangle6", np.asarray(elements, dtype=np.int64))],
            point_data=point, cell_data={key: [value] for key, value in cell.items()},
        )
        meshio.write(out_dir / name, mesh, file_format="vtu", binary=True)
        ET.SubElement(coll, "DataSet", timestep=repr(float(t)), group="", part="0", file=name)
        written.append(out_dir / name)
    pvd = out_dir / f"{stem}.pvd"
    ET.indent(root)
    ET.ElementTree(root).write(pvd, encoding="utf-8", xml_declaration=True)
    return [pvd] + written


def _write_boundary(out_dir: Path, stem: str, label: str, drawing, factors=None) -> Path:
    """A piece of the scene's boundary (its ``drawing``: the wall under the capsules' paths, a quad;
    a conduit's side wall along them) as ``<stem>_<label>.vtu`` (``_wall.vtu`` for the wall,
    ``_conduit.vtu`` for a conduit), for ParaView to draw beside the membrane."""
    import meshio

    points, cells = drawing
    f = factors["a"] if factors is not None else 1.0
    name = out_dir / f"{stem}_{label}.vtu"
    meshio.write(name, meshio.Mesh(f * np.asarray(points, dtype=np.float64), cells), file_format="vtu", binary=True)
    return name


def export_run(
    path: str | os.PathLike,
    out_dir: str | os.PathLike | None = None,
    fmt: str = "xdmf",
    fields: bool = True,
    units: str = "capsim",
) -> list[Path]:
    """Write a trajectory's snapshots for ParaView; returns the files written (index file first).
    ``units="physical"``: times in s, positions in µm and every field in the physical unit of
    its scale (capsim.quantities.EXPORT_FIELDS, SCALE_UNITS) from the run's physical block."""
    from capsim.storage.store import read_trajectory

    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    path = Path(path)
    data = read_trajectory(path)
    out = Path(out_dir) if out_dir is not None else path.parent / f"{path.stem}_{fmt}"
    out.mkdir(parents=True, exist_ok=True)
    elements = np.asarray(data["elements"])
    rest = np.asarray(data["rest_positions"], dtype=np.float64)
    positions, times = data["positions"], data["snapshot_t"]
    if len(positions) == 0:
        positions, times = rest[None], np.zeros(1)
    factors = None
    if units == "physical":
        from capsim.units import factors_for

        factors = factors_for(case_of(data), path.name)
    else:
        from capsim.quantities import UNIT_SYSTEMS

        if units not in UNIT_SYSTEMS:
            raise ValueError(f"units must be one of {', '.join(UNIT_SYSTEMS)}, got {units!r}")
    model = model_for(data) if fields else None
    # several capsules (issue 43): the union mesh holds every capsule's surface; each node and
    # element carries its capsule's index (a pure number: no unit to scale)
    capsule_point, capsule_cell = capsule_fields(data)

    def snapshots():
        f_t, f_x = (factors["1/k"], factors["a"]) if factors is not None else (1.0, 1.0)
        for t, x in zip(times, positions):
            x = np.asarray(x, dtype=np.float64)
            if model is None:
                point, cell = {"displacement": x - rest}, {}
            else:
                point, cell = snapshot_fields(model, x, rest)
            yield (float(t) * f_t, x * f_x, {**_scaled(point, factors), **capsule_point},
                   {**_scaled(cell, factors), **capsule_cell})

    writer = _write_xdmf if fmt == "xdmf" else _write_vtu
    from capsim.scene import Scene

    scene = Scene.of(case_of(data))
    patches = []
    if scene.has_boundary:  # the scene's boundaries (a wall): a piece under the capsules' whole paths
        xs = np.concatenate([np.asarray(p, dtype=np.float64) for p in positions])
        patches = [(b.label, b.drawing(xs)) for b in scene.boundaries]
    # Every file is written in a private staging directory inside `out`, then renamed into
    # place: a full disk, a size limit or a kill leaves what was in `out` as it was.
    staging = out / f".capsim-export-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    try:
        staging.mkdir()
        staged = writer(staging, path.stem, elements, rest, snapshots(), factors, tuple(capsule_point))
        for label, corners in patches:
            staged.append(_write_boundary(staging, path.stem, label, corners, factors))
        for file in staged:
            os.replace(file, out / file.name)
    except (OSError, RuntimeError) as exc:
        raise StorageError(write_failure(out, exc) + "; the files that were there are unchanged") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return [out / file.name for file in staged]


class ExportError(ValueError):
    """A run that cannot be exported (not a run file, an unreadable one); one line."""


def export_to_dir(path: str | os.PathLike, out_dir: str | os.PathLike | None = None, fmt: str = "xdmf", *,
                  fields: bool = True, overwrite: bool = False, units: str = "capsim") -> list[Path]:
    """`capsim export`: :func:`export_run` behind the output guards: the files it would
    replace in `out_dir` (``<stem>.xdmf``, ``<stem>_data.h5`` | ``<stem>_NNNN.vtu``,
    ``<stem>.pvd``) are replaced only if they are not run files, checkpoints or campaign
    files, unless `overwrite`. Raises ExportError, OutputError or StorageError (one line)."""
    from capsim.config import ConfigError
    from capsim.errors import first_line
    from capsim.storage.files import OutputError, guard_output, is_run_file, protected
    from capsim.storage.store import TrajectoryError

    path = Path(path)
    if not path.exists():
        raise ExportError(f"{path}: no such file")
    if not is_run_file(path):
        raise ExportError(f"{path}: not a capsim run file (an HDF5 file written by capsim run or sweep)")
    out = Path(out_dir) if out_dir is not None else path.with_name(f"{path.stem}_{fmt}")
    if out.exists() and not out.is_dir():
        raise OutputError(f"output path {out} is not a directory")
    if out.is_dir():
        planned = [out / f"{path.stem}.xdmf", out / f"{path.stem}_data.h5", out / f"{path.stem}.pvd",
                   out / f"{path.stem}_wall.vtu"]
        planned += sorted(out.glob(f"{path.stem}_[0-9][0-9][0-9][0-9].vtu"))
        for target in planned:
            guard_output(target, [path], overwrite, ours=lambda p: protected(p) is None)
    try:
        return export_run(path, out, fmt, fields=fields, units=units)
    except (TrajectoryError, ConfigError, ValueError) as exc:
        raise ExportError(first_line(exc)) from None
    except StorageError:
        raise
    except OSError as exc:
        raise StorageError(f"cannot write {out}: {exc.strerror or first_line(exc)}") from None
    except Exception as exc:  # noqa: BLE001 - one line, not a traceback
        raise ExportError(f"cannot export {path}: {type(exc).__name__}: {first_line(exc)}") from None
