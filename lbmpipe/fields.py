"""Flow-field output for ParaView: VTK image data of the lattice and polydata of the particles,
one file per sample, in a ``.pvd`` time series (``outputs.fields`` of the scene).

Written with ``pyevtk`` (VTK XML, raw binary appended data). Per sample, in ``<out>/fields/``:

- ``lattice_<step>.vti``: image data whose *cells* are the lattice nodes (node centres at cell
  centres, spacing dx in mm; ghost layers of walls included, so the walls show in ``solid``).
  Cell arrays, physical units: ``velocity_m_s`` (3 components, float32, zero at solid nodes),
  ``density_kg_m3`` (float32, NaN at solid nodes), ``solid`` (uint8: 0 fluid, 1 wall, 2 particle).
  Coordinates: the lab frame of the scene in mm (pipe axis at x = y = 0; box from 0).
- ``particles_<step>.vtp`` (scenes with particles): one vertex per body at its centre (mm) with
  point arrays ``id``, ``shape_id`` (0 sphere, 1 cylinder, 2 cube), ``half_extents_mm`` (body
  frame: sphere (r, r, r), cylinder (r, r, L/2), cube (a/2, a/2, a/2)), ``bounding_radius_mm``,
  ``velocity_m_s``, ``angular_velocity_rad_s`` (lab), ``qw, qx, qy, qz`` (unit quaternion body ->
  lab) and ``axis_x``, ``axis_y``, ``axis_z`` (the body axes in the lab frame; a cylinder's axis is
  ``axis_z``), for glyphs or the true shapes.

``<out>/fields.pvd`` lists the samples by simulated time (s): part 0 the lattice, part 1 the
particles. It is rewritten (atomically) after every sample, so an interrupted run leaves a valid
series. The writer's state is a function of the step count alone (samples at multiples of the
interval, plus the last step of a completed run), so a run resumed from a checkpoint rebuilds the
same list: no entry is lost or repeated, and the resumed samples rewrite identical files.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .particles.rigid import quat_to_matrices
from .particles.shapes import bounding_radius

SUBDIR = "fields"
SERIES = "fields.pvd"
#: bytes per node of each field (float32 vectors and scalars, uint8 mask)
BYTES_PER_NODE = {"velocity": 12, "density": 4, "solid": 1}
#: bytes per particle of the polydata: float64 centre, int32 vertex connectivity and offset,
#: int64 id and shape id, 5 float64 scalars (bounding radius, quaternion), 6 float64 vectors
BYTES_PER_PARTICLE = 24 + 8 + 16 + 5 * 8 + 6 * 24
#: XML header and the 8-byte size prefix of each array, per file (approximate)
HEADER_BYTES = {"lattice": 1024, "particles": 2560}
#: memory per node while a sample is written: the float64 moments (32), the float32 fields and
#: their file-ordered copies, and the Python numbers pyevtk packs them through (tracemalloc peak
#: of the writer: 138 bytes a node with all three fields)
MEMORY_BYTES_PER_NODE = 200


def field_every(scene, params) -> int:
    """Steps between field samples (``outputs.fields.interval_s`` rounded to whole steps), or 0
    when the scene asks for no field output."""
    spec = scene.outputs.fields
    if spec is None:
        return 0
    return max(1, int(round(params.units.time(spec.interval_s))))


def sample_count(scene, params) -> int:
    """Number of samples a full run writes (the start, every interval, and the last step)."""
    every = field_every(scene, params)
    if not every:
        return 0
    return 1 + params.n_steps // every + (1 if params.n_steps % every else 0)


def grid_nodes(scene, params) -> int:
    """Nodes of the simulation grid, wall ghost layers included (what a lattice file holds)."""
    nx, ny, nz = params.shape
    if scene.domain.kind == "pipe":
        return (nx + 2) * (ny + 2) * nz
    walls = scene.domain.walls
    return math.prod(n + (2 if getattr(walls, a) == "wall" else 0) for n, a in zip((nx, ny, nz), "xyz"))


def bytes_per_sample(scene, params, n_particles: int | None = None) -> tuple[int, int]:
    """(lattice, particles) bytes of one sample on disk. ``n_particles`` defaults to the number of
    bodies the scene makes (``count_particles``)."""
    spec = scene.outputs.fields
    if spec is None:
        return 0, 0
    lattice = grid_nodes(scene, params) * sum(BYTES_PER_NODE[f] for f in spec.fields) + HEADER_BYTES["lattice"]
    if n_particles is None:
        n_particles = count_particles(scene, params)
    parts = n_particles * BYTES_PER_PARTICLE + HEADER_BYTES["particles"] if (spec.particles and n_particles) else 0
    return lattice, parts


def memory_per_sample(scene, params) -> int:
    """Bytes of memory a sample takes while it is written (``MEMORY_BYTES_PER_NODE``)."""
    return grid_nodes(scene, params) * MEMORY_BYTES_PER_NODE if scene.outputs.fields is not None else 0


def count_particles(scene, params) -> int:
    """Number of bodies the scene makes, without placing them (groups given by concentration:
    round(concentration x domain volume / particle volume), at least 1)."""
    ps = scene.particles
    if ps is None:
        return 0
    n = len(ps.bodies)
    dx = scene.numerics.dx_mm
    nx, ny, nz = params.shape
    domain_volume = (math.pi * (nx / 2.0) ** 2 * nz) if scene.domain.kind == "pipe" else float(nx * ny * nz)
    for g in list(ps.random) + list(ps.packed):
        if getattr(g, "count", None):
            n += g.count
            continue
        if g.shape == "sphere":
            v = math.pi / 6.0 * (g.diameter_mm / dx) ** 3
        elif g.shape == "cylinder":
            v = math.pi / 4.0 * (g.diameter_mm / dx) ** 2 * (g.length_mm / dx)
        else:
            v = (g.edge_mm / dx) ** 3
        n += max(1, int(round(g.concentration * domain_volume / v)))
    return n


class FieldWriter:
    """Writes the VTK series of a run: ``sample(sim, step)`` at each due step, ``close()`` at the
    end (returns the file names for the summary). Lattice values are converted to physical units
    here through ``params.units``."""

    def __init__(self, scene, params, grid, out_dir: Path, n_steps: int | None = None):
        spec = scene.outputs.fields
        self.every = field_every(scene, params)
        self.fields = tuple(spec.fields)
        self.with_particles = bool(spec.particles)
        self.units = params.units
        self.n_steps = params.n_steps if n_steps is None else n_steps  # the run's last step
        self.out_dir = Path(out_dir)
        self.dir = self.out_dir / SUBDIR
        self.dir.mkdir(parents=True, exist_ok=True)
        self.rho_kg_m3 = params.units.rho_kg_m3
        dx_mm = params.units.dx_m * 1e3
        self.spacing = (float(dx_mm),) * 3
        first = [c[0] for c in grid.positions()]  # first node centre, lattice units
        # plain floats: pyevtk writes the repr of what it is given (a numpy scalar would not parse)
        self.origin = tuple(float((c - 0.5) * dx_mm) for c in first)
        self.grid = grid
        self.entries: list[tuple[int, list[str]]] = []

    @classmethod
    def from_scene(cls, scene, params, grid, out_dir: Path, n_steps: int | None = None):
        """The writer the scene asks for, or ``None`` without ``outputs.fields``."""
        return cls(scene, params, grid, out_dir, n_steps) if scene.outputs.fields is not None else None

    # -- schedule ---------------------------------------------------------------------------
    def due(self, step: int) -> bool:
        return step % self.every == 0 or step == self.n_steps

    def steps_to_next(self, step: int) -> int:
        """Steps from ``step`` to the next sample (the run loop stops there)."""
        return self.every - step % self.every

    def start(self, sim, resumed: bool) -> None:
        """First sample (the initial state), or, resuming, the entries written before the
        checkpoint's step, rebuilt from the schedule."""
        if not resumed:
            self.sample(sim, sim.step_count)
            return
        s = sim.step_count
        steps = list(range(0, s + 1, self.every))
        if s == self.n_steps and s % self.every:
            steps.append(s)
        self.entries = [(k, self._names(k, sim)) for k in steps]
        self._write_series()

    # -- writing ----------------------------------------------------------------------------
    def _names(self, step: int, sim) -> list[str]:
        names = [f"{SUBDIR}/lattice_{step:08d}.vti"]
        if self.with_particles and sim.particles is not None and sim.particles.n:
            names.append(f"{SUBDIR}/particles_{step:08d}.vtp")
        return names

    def arrays(self, sim) -> dict[str, np.ndarray | tuple]:
        """The cell arrays of one sample (physical units, the grid's (nx, ny, nz) layout)."""
        rho, ux, uy, uz = sim.moments()
        fluid = sim.fluid_mask()
        out: dict[str, np.ndarray | tuple] = {}
        if "velocity" in self.fields:
            scale = self.units.velocity_phys(1.0)
            out["velocity_m_s"] = tuple(np.ascontiguousarray(np.where(fluid, c * scale, 0.0), dtype=np.float32)
                                        for c in (ux, uy, uz))
        if "density" in self.fields:
            out["density_kg_m3"] = np.ascontiguousarray(np.where(fluid, rho * self.rho_kg_m3, np.nan), dtype=np.float32)
        if "solid" in self.fields:
            solid = np.where(fluid, 0, np.where(self.grid.solid, 1, 2)).astype(np.uint8)
            out["solid"] = np.ascontiguousarray(solid)
        return out

    def particle_arrays(self, sim) -> dict[str, np.ndarray | tuple]:
        """Point arrays of the particles (physical units), and ``points`` (x, y, z) in mm."""
        ps, u = sim.particles, self.units
        b = ps.bodies
        mm = u.dx_m * 1e3
        rot = quat_to_matrices(np.ascontiguousarray(b.q))
        om = ps.omega_lab() * u.angular_velocity_phys(1.0)
        vel = b.v * u.velocity_phys(1.0)
        h = b.h * mm

        def vec(a):
            return tuple(np.ascontiguousarray(a[:, k], dtype=np.float64) for k in range(3))

        return {
            "points": vec(b.x * mm),
            "id": np.arange(b.n, dtype=np.int64),
            "shape_id": np.ascontiguousarray(b.kind, dtype=np.int64),
            "bounding_radius_mm": np.array([bounding_radius(int(k), hh) for k, hh in zip(b.kind, b.h)]) * mm,
            "half_extents_mm": vec(h),
            "velocity_m_s": vec(vel),
            "angular_velocity_rad_s": vec(om),
            "qw": np.ascontiguousarray(b.q[:, 0]), "qx": np.ascontiguousarray(b.q[:, 1]),
            "qy": np.ascontiguousarray(b.q[:, 2]), "qz": np.ascontiguousarray(b.q[:, 3]),
            "axis_x": vec(rot[:, :, 0]), "axis_y": vec(rot[:, :, 1]), "axis_z": vec(rot[:, :, 2]),
        }

    def sample(self, sim, step: int) -> None:
        """Write the lattice (and particle) files of ``step`` and rewrite the series."""
        names = self._names(step, sim)
        base = str(self.out_dir / names[0]).removesuffix(".vti")
        _write_image(base, self.origin, self.spacing, self.grid.shape, self.arrays(sim))
        if len(names) > 1:
            _write_points(str(self.out_dir / names[1]).removesuffix(".vtp"), self.particle_arrays(sim))
        self.entries = [e for e in self.entries if e[0] != step] + [(step, names)]
        self._write_series()

    def _write_series(self) -> None:
        from pyevtk.vtk import VtkGroup

        tmp = self.out_dir / (SERIES + ".tmp")
        group = VtkGroup(str(tmp).removesuffix(".pvd"))  # writes <tmp>.pvd
        for step, names in self.entries:
            for part, name in enumerate(names):
                group.addFile(str(self.out_dir / name), sim_time=self.units.time_phys(step), part=str(part))
        group.save()
        os.replace(str(tmp).removesuffix(".pvd") + ".pvd", self.out_dir / SERIES)

    def close(self) -> list[str]:
        """What the summary's ``files`` lists: the series and its folder."""
        return [SERIES, SUBDIR + "/"]


def _write_image(base: str, origin, spacing, shape, arrays: dict) -> str:
    """Image data of ``shape`` cells with ``arrays`` as cell data (pyevtk's low-level writer, as
    its ``imageToVTK`` does, but a vector goes in as one interleaved array: ``imageToVTK`` packs
    vectors value by value in Python, seconds per sample at the paper's resolution)."""
    from pyevtk.vtk import VtkFile, VtkImageData

    flat = {}
    w = VtkFile(base, VtkImageData)
    w.openGrid(start=(0, 0, 0), end=tuple(int(n) for n in shape), origin=origin, spacing=spacing)
    w.openPiece(start=(0, 0, 0), end=tuple(int(n) for n in shape))
    scalars = next((k for k, a in arrays.items() if not isinstance(a, tuple)), None)
    vectors = next((k for k, a in arrays.items() if isinstance(a, tuple)), None)
    w.openData("Cell", scalars=scalars, vectors=vectors)
    for name, a in arrays.items():
        if isinstance(a, tuple):  # VTK: cells x fastest, the components of a cell together
            flat[name] = np.stack([np.ravel(c, order="F") for c in a], axis=1).ravel()
            w.addHeader(name, flat[name].dtype.name, flat[name].size // 3, 3)
        else:
            flat[name] = np.ravel(a, order="F")
            w.addData(name, flat[name])
    w.closeData("Cell")
    w.closePiece()
    w.closeGrid()
    for a in flat.values():
        w.appendData(a)
    w.save()
    return w.getFileName()


def _write_points(base: str, arrays: dict) -> str:
    """Polydata of vertices at ``arrays['points']`` with the other entries as point arrays
    (pyevtk's low-level writer: its ``pointsToVTK`` writes an unstructured grid instead)."""
    from pyevtk.vtk import VtkFile, VtkPolyData

    x, y, z = arrays["points"]
    data = {k: v for k, v in arrays.items() if k != "points"}
    n = x.size
    conn = np.arange(n, dtype=np.int32)
    offs = np.arange(1, n + 1, dtype=np.int32)
    w = VtkFile(base, VtkPolyData)
    w.openGrid()
    w.openPiece(npoints=n, nverts=n)
    w.openElement("Points")
    w.addData("points", (x, y, z))
    w.closeElement("Points")
    w.openElement("Verts")
    w.addData("connectivity", conn)
    w.addData("offsets", offs)
    w.closeElement("Verts")
    w.openData("Point", scalars="shape_id", vectors="velocity_m_s")
    for key, value in data.items():
        w.addData(key, value)
    w.closeData("Point")
    w.closePiece()
    w.closeGrid()
    w.appendData((x, y, z)).appendData(conn).appendData(offs)
    for value in data.values():
        w.appendData(value)
    w.save()
    return w.getFileName()


# -- reading back (with vtk, the library ParaView is built on) ---------------------------------

#: what a user without vtk is told (vtk is the `fields` extra: 0.5 GB the main job does not need)
NEED_VTK = "lbmpipe.fields' readers need vtk, which the main install leaves out: pip install -e '.[fields]'"


def _vtk_readers():
    """``(vtkmodules.vtkIOXML, vtk_to_numpy)``, or an ImportError whose one line names the extra."""
    try:
        from vtkmodules import vtkIOXML
        from vtkmodules.util.numpy_support import vtk_to_numpy
    except ImportError:
        raise ImportError(NEED_VTK) from None
    return vtkIOXML, vtk_to_numpy


def read_series(pvd: Path) -> list[tuple[float, int, str]]:
    """Entries ``(time_s, part, file)`` of a ``.pvd`` series, files relative to its folder."""
    import xml.etree.ElementTree as ET

    root = ET.parse(pvd).getroot()
    return [(float(d.get("timestep")), int(d.get("part", 0)), d.get("file")) for d in root.iter("DataSet")]


def read_lattice(path: Path) -> dict:
    """A lattice file as ``{"origin", "spacing", "shape", <array name>: ndarray}``; cell arrays
    come back in the (nx, ny, nz) layout of the grid, vectors as (nx, ny, nz, 3). Needs vtk (the
    ``fields`` extra)."""
    vtkIOXML, vtk_to_numpy = _vtk_readers()
    r = vtkIOXML.vtkXMLImageDataReader()
    r.SetFileName(str(path))
    r.Update()
    img = r.GetOutput()
    shape = tuple(d - 1 for d in img.GetDimensions())
    out = {"origin": np.array(img.GetOrigin()), "spacing": np.array(img.GetSpacing()), "shape": shape}
    cd = img.GetCellData()
    for i in range(cd.GetNumberOfArrays()):
        a = vtk_to_numpy(cd.GetArray(i))  # VTK orders cells x fastest (Fortran order)
        if a.ndim == 1:
            out[cd.GetArrayName(i)] = a.reshape(shape, order="F")
        else:
            out[cd.GetArrayName(i)] = np.stack([a[:, k].reshape(shape, order="F") for k in range(a.shape[1])], axis=-1)
    return out


def read_particles(path: Path) -> dict:
    """A particle file as ``{"points": (n, 3), <array name>: (n,) or (n, 3)}``. Needs vtk (the
    ``fields`` extra)."""
    vtkIOXML, vtk_to_numpy = _vtk_readers()
    r = vtkIOXML.vtkXMLPolyDataReader()
    r.SetFileName(str(path))
    r.Update()
    poly = r.GetOutput()
    out = {"points": vtk_to_numpy(poly.GetPoints().GetData()), "n_verts": poly.GetNumberOfVerts()}
    pd_ = poly.GetPointData()
    for i in range(pd_.GetNumberOfArrays()):
        out[pd_.GetArrayName(i)] = vtk_to_numpy(pd_.GetArray(i))
    return out
