"""The reference of every scene field, ``docs/scene.md``, generated from the pydantic models of
:mod:`lbmpipe.scene` by :func:`describe_fields`."""

from __future__ import annotations

import enum
import types
import typing
from typing import Any, Literal, Union

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from lbmpipe.particles.lubrication_params import Lubrication
from lbmpipe.scene import (Collisions, FieldOutput, MovingWall, PackedParticles, ParticleBody, RandomParticles, Scene,
                           Walls, _model_at)


def _type_name(annotation: Any) -> str:
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is Literal:
        return " \\| ".join(f"`{a}`" for a in args)
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return " \\| ".join(f"`{m.value}`" for m in annotation)
    if origin in (Union, types.UnionType):
        names = [_type_name(a) for a in args if a is not type(None)]
        return " \\| ".join(names) + (" or null" if type(None) in args else "")
    if origin is tuple:
        return "[" + ", ".join(_type_name(a) for a in args) + "]"
    if origin is list:
        return f"list of {_type_name(args[0])}"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return f"mapping ([{annotation.__name__}](#{annotation.__name__.lower()}))"
    return getattr(annotation, "__name__", str(annotation))


def _constraints(info) -> str:
    out = []
    for m in info.metadata:
        for attr, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            if getattr(m, attr, None) is not None:
                out.append(f"{sym} {getattr(m, attr)}")
        if getattr(m, "pattern", None):
            out.append(f"matches `{m.pattern}`")
    return ", ".join(out)


def _default(info) -> str:
    if info.is_required():
        return "**required**"
    value = info.default_factory() if info.default is PydanticUndefined else info.default
    if isinstance(value, BaseModel):
        return "(defaults below)"
    if value is None:
        return "`null`"
    if isinstance(value, tuple):
        value = list(value)
    return f"`{value}`"


_DOC_HEAD = """# Scene files

A scene is a YAML file in **physical units** describing one simulation. `lbmpipe check SCENE`
validates it and prints the derived lattice parameters; `lbmpipe run SCENE --out DIR` runs it.
Examples: `scenes/pipe_re9.4.yaml` (the paper's particle-free pipe), `scenes/box_couette.yaml`,
`scenes/box_poiseuille.yaml`.

*This file is generated from the pydantic models in `lbmpipe/scene.py` by
`lbmpipe.scene_docs.describe_fields()`; regenerate it with*
`python -c "import lbmpipe.scene_docs as s; open('docs/scene.md', 'w').write(s.describe_fields())"`.

## Errors

Unknown or mistyped keys are errors. Every problem is reported as one line
`scene error in <field>: <message>. Fix: <fix>` (all problems found are listed; `lbmpipe check`
exits with status 2). Beyond the per-field types and ranges in the tables below, a scene must
satisfy these rules:

- `domain.kind: pipe` needs `diameter_mm` and `length_mm` and takes no `size_mm`, `walls` or
  `moving_walls`; `domain.kind: box` needs `size_mm` and takes no `diameter_mm` or `length_mm`.
- Every extent (diameter, length, box sizes) is an integer multiple of `numerics.dx_mm` within
  1e-6 relative.
- The pipe diameter, and each walled box extent, spans at least `numerics.min_diameter_nodes` nodes.
- A moving wall's axis is `wall` in `domain.walls`, its velocity is tangential (zero component
  along that axis), and each face is listed at most once.
- Exactly one of `fluid.viscosity_m2_s` and `fluid.reynolds`; `reynolds` only for a pipe with
  `driving.kind: flow_rate` (then `nu = U D / Re`, `U = Q / (pi D^2 / 4)`).
- `driving.kind: flow_rate` only for a pipe, with `flow_rate_m3_s`; `body_force` needs a non-zero
  `acceleration_m_s2` (in a pipe along z only); each of these two keys only with its own kind.
- `initial.velocity: parabolic` only for a pipe driven by `flow_rate` or `body_force`;
  `initial.velocity: linear` only for a box with moving walls, all on its single walled axis.
- `outputs.fields.interval_s` lies between `numerics.dt_s` and `run.duration_s`.
- `run.spinup_s < run.duration_s`; `numerics.dt_s <= run.sample_interval_s <= run.duration_s`.
- `particles`: each body or group gives exactly the sizes of its shape (sphere `diameter_mm`;
  cylinder `diameter_mm` and `length_mm`; cube `edge_mm`); a random group gives exactly one of
  `count` and `concentration`; an explicit body's centre lies inside the pipe (or inside the box
  along walled axes); a particle's bounding diameter plus two nodes fits in every periodic length.
  Random placement that cannot fit the requested number of non-overlapping bounding spheres fails
  at run time with the number it reached.
- Explicit bodies (`particles.bodies`) that are free may not reach into the pipe wall or a box
  wall, and no two explicit bodies (unless both are fixed) may overlap, beyond the collision
  model's tolerance `overlap_tol_dx` spacings; the error gives the overlap in mm.
- A random group given by `count` holds less volume than the domain.
- Collisions with a pair search (collisions and `pairs` on, two or more bodies, one of them free)
  need every periodic length to hold two interaction ranges, `2 (2 r_b + contact_gap_dx + skin)`
  with `r_b` the largest bounding radius, `skin` 0.5 spacing: the run's own rule
  (`lbmpipe.particles.collisions.min_periodic_length`); the error names the smallest length that works. One
  free body, or `pairs: false`, needs no such length.

## Limits of a scene file and of a run

`lbmpipe check` and `lbmpipe run` refuse, before allocating anything:

- a scene file larger than 1 MB, not UTF-8 (the byte and line are named), nested deeper than 40
  levels, or expanding (anchors and aliases) to more than 200,000 values;
- more than 10^7 nodes along one axis (e.g. a tiny `dx_mm`);
- a run whose memory estimate exceeds the memory available (the smallest of MemAvailable, a
  cgroup limit and `ulimit -v`); `lbmpipe check` prints the estimate (`estimated memory`): two
  population arrays of `q` values per node of the whole block, 64 bytes per node of other fields,
  4 kB per particle and 300 MB for the interpreter and compiled kernels.

`lbmpipe run` also refuses, with exit status 2 and one line, before the first step: an `--out`
that is a file, lies under a file or cannot be written; a `--checkpoint` that is a folder or lies
under a file; `--checkpoint-every-s` or `--steps` that is not a positive finite number; a
checkpoint that cannot be read (truncated, not an archive) or belongs to another scene. An `--out`
holding a finished run, or a run of another scene (name and fingerprint of its `summary.json`),
is refused with exit status 3 even when a checkpoint is resumed, unless `--force` is given.
Outputs are written to temporary names and renamed into place; the checkpoint is removed only
after the last output. `run.threads` sets the number of numba threads (at most
`NUMBA_NUM_THREADS`). `lbmpipe check-config CONFIG` applies the checks the Snakefile makes before
any job: the schema, the fidelity level, and every case's scene at every level.

## Derived lattice parameters (`lbmpipe.units.derive`)

Lattice units have `dx = dt = 1` and density 1 = `fluid.density_kg_m3`.

- Shape in nodes: pipe `(D/dx, D/dx, L/dx)`; box `size_mm / dx_mm` per axis. Walls sit half a link
  outside the outermost fluid nodes (half-way bounce-back), so a pipe of `n` nodes has radius `n/2`.
- `nu_lu = nu dt / dx^2`, `tau = 3 nu_lu + 1/2`, `omega = 1/tau`; TRT:
  `1/omega_minus = trt_magic / (tau - 1/2) + 1/2` (for BGK `omega_minus = omega`).
- Expected centre-line velocity `u_max`: pipe flow_rate `2 Q/A`; pipe body_force `g R^2 / (4 nu)`;
  box body_force `g H^2 / (8 nu)` across the narrowest walled gap `H`; with no wall across the
  force, fixed particles' Stokes drag balancing it (superficial `U = g V / (3 pi nu sum d_i)`,
  volume-equivalent diameters, peak `2 U / (1 - phi)`: an estimate, the run-time guard checks the
  real speed), or free acceleration `g T` when lower or with nothing to resist; moving walls add
  their largest speed. `lbmpipe check` names the estimate used.
- Rejected: `tau <= 1/2`; `u_max / c_s > numerics.mach_limit` (the message gives the largest `dt_s`
  that satisfies the limit; every lattice velocity scales with `dt` at fixed physics).
- Reported: Reynolds number (pipe `U D / nu`, box `u_max H / nu`), step counts (durations rounded
  to whole steps, with a warning when rounding changes them) and an estimated run time
  (`lbmpipe.cost`).

## Fields
"""


def describe_fields() -> str:
    """Markdown reference of every scene field (the content of docs/scene.md)."""
    sections = [("(top level)", Scene)] + [(key, _model_at((key,))) for key in Scene.model_fields if _model_at((key,))]
    sections += [("domain.walls", Walls), ("domain.moving_walls[i]", MovingWall), ("numerics.lubrication", Lubrication),
                 ("outputs.fields", FieldOutput),
                 ("particles.bodies[i]", ParticleBody), ("particles.random[i]", RandomParticles),
                 ("particles.packed[i]", PackedParticles), ("particles.collisions", Collisions)]
    lines = [_DOC_HEAD]
    for where, model in sections:
        doc = " ".join((model.__doc__ or "").split())
        lines.append(f"### {model.__name__}\n")
        lines.append(f"Key: `{where}`. {doc}\n")
        lines.append("| field | type | default | constraints | description |")
        lines.append("| --- | --- | --- | --- | --- |")
        for name, info in model.model_fields.items():
            desc = " ".join((info.description or "").split()).replace("|", "\\|")
            lines.append(f"| `{name}` | {_type_name(info.annotation)} | {_default(info)} | {_constraints(info)} | {desc} |")
        lines.append("")
    return "\n".join(lines)
