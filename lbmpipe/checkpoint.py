"""Checkpoints: the complete state of a run in one file, written atomically, so that a run stopped
by a time limit or Ctrl-C resumes exactly where it stopped, bit for bit.

What is saved (generic, so a new effect needs no code here): every ndarray and every plain value
(number, bool, string, None, and dicts/lists/tuples of those) held as an attribute of

* the ``Simulation`` (populations ``f`` and ``f_next``, the driving force, ``step_count``, ...),
* its ``ParticleSystem`` and the ``Bodies`` (centres, velocities, quaternions, owner map, runs,
  link lists, impulses, force sums, ...),
* each effect of the step, matched by position and name (the flow-rate controller's integral,
  the flux correction's fluid momentum and step counter, the mass correction's target and calls,
  the collision totals, ...),

plus the run loop's own accumulators (``run``: flow-rate series, profile sums, particle samples,
initial mass, number of averaged samples, wall time so far), which ``run.run_scene`` passes in.
Objects (grid, lattice, kernels, link records) are rebuilt from the scene and not saved;
per-thread scratch buffers are skipped.

Restoring writes arrays in place (``a[...] = saved``), so arrays shared between objects stay
shared; a shape or dtype that differs means the checkpoint belongs to another simulation and is
refused. Each file carries the scene's fingerprint (SHA-256 of the resolved scene, all defaults
filled in): a checkpoint written for another scene is refused with :class:`CheckpointError`.

Format: an uncompressed ``.npz`` (NumPy arrays, no pickles), the plain values as JSON in the
member ``__meta__``. Written to ``<path>.tmp``, flushed to disk and renamed over ``<path>``, so a
crash mid-write leaves the previous checkpoint intact.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

FORMAT = "lbmpipe-checkpoint-1"
_META = "__meta__"
#: attributes that are objects rebuilt from the scene, or scratch
_SKIP = {"grid", "lattice", "effects", "particles", "bodies", "system", "guard", "particle_static", "packing",
         "packing_info", "kernel", "spec", "links", "domain", "params", "scratch", "collide", "units"}


class CheckpointError(ValueError):
    """A checkpoint that cannot be used for this run (other scene, other simulation, bad file)."""


def scene_fingerprint(scene) -> str:
    """SHA-256 of the resolved scene (pydantic dump, keys sorted) and the checkpoint format."""
    doc = scene.model_dump(mode="json") if hasattr(scene, "model_dump") else scene
    text = json.dumps({"format": FORMAT, "scene": doc}, sort_keys=True, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _plain(v):
    """``v`` as a JSON value, or ``_NO`` when it is not plain data."""
    if v is None or isinstance(v, (bool, str)):
        return v
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v)
    if isinstance(v, dict):
        out = {}
        for k, x in v.items():
            p = _plain(x)
            if p is _NO or not isinstance(k, str):
                return _NO
            out[k] = p
        return out
    if isinstance(v, (list, tuple)):
        out = [_plain(x) for x in v]
        return _NO if any(p is _NO for p in out) else out
    return _NO


_NO = object()


def _objects(sim) -> list[tuple[str, object]]:
    objs: list[tuple[str, object]] = [("sim", sim)]
    if sim.particles is not None:
        objs += [("particles", sim.particles), ("bodies", sim.particles.bodies)]
    objs += [(f"effect{i}", e) for i, e in enumerate(sim.effects)]
    return objs


def _effect_names(sim) -> list[str]:
    return [e.name for e in sim.effects]


def capture(sim) -> tuple[dict[str, np.ndarray], dict]:
    """``(arrays, meta)`` of the simulation's state (module docstring)."""
    arrays: dict[str, np.ndarray] = {}
    meta: dict[str, dict] = {}
    for prefix, obj in _objects(sim):
        attrs = obj.__dict__ if hasattr(obj, "__dict__") else {}
        m = {}
        for name, v in attrs.items():
            if name in _SKIP:
                continue
            if isinstance(v, np.ndarray):
                arrays[f"{prefix}/{name}"] = v
                continue
            p = _plain(v)
            if p is not _NO:
                m[name] = p
        meta[prefix] = m
    return arrays, meta


def restore(sim, arrays: dict[str, np.ndarray], meta: dict) -> None:
    """Put a captured state back into ``sim`` (built from the same scene), arrays in place."""
    objs = dict(_objects(sim))
    if set(meta) != set(objs):
        raise CheckpointError(f"the checkpoint's simulation has other parts ({sorted(set(meta) ^ set(objs))}) than "
                              "this one")
    # A checkpoint of another lbmpipe version can name other arrays for the same state (e.g. the
    # particle link lists changed layout): restoring the common part would leave the rest as built
    # from the scene and silently inconsistent, so the sets of arrays must match.
    current = set(capture(sim)[0])
    missing = sorted(current - set(arrays))
    unknown = sorted(k for k in arrays if not hasattr(objs[k.split("/", 1)[0]], k.split("/", 1)[1]))
    if missing or unknown:
        raise CheckpointError(f"the checkpoint was written by another version of lbmpipe (it lacks {missing[:4]}"
                              f"{' ...' if len(missing) > 4 else ''}, and holds {unknown[:4]}"
                              f"{' ...' if len(unknown) > 4 else ''}, which this version does not have); "
                              "delete it to start afresh")
    for key, saved in arrays.items():
        prefix, name = key.split("/", 1)
        obj = objs[prefix]
        cur = getattr(obj, name, None)
        if isinstance(cur, np.ndarray):
            if cur.shape != saved.shape or cur.dtype != saved.dtype:
                raise CheckpointError(f"{prefix}.{name}: the checkpoint holds {saved.dtype}{saved.shape}, this "
                                      f"simulation {cur.dtype}{cur.shape}")
            cur[...] = saved
        else:
            setattr(obj, name, np.array(saved))
    for prefix, values in meta.items():
        obj = objs[prefix]
        for name, v in values.items():
            cur = getattr(obj, name, None)
            setattr(obj, name, tuple(v) if isinstance(cur, tuple) and isinstance(v, list) else v)


def write(path: Path, sim, fingerprint: str, run: dict | None = None, run_arrays: dict | None = None) -> Path:
    """Write ``sim``'s state plus the run loop's plain values ``run`` and arrays ``run_arrays``
    atomically to ``path`` (``.tmp`` beside it, fsync, rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays, meta = capture(sim)
    for k, a in (run_arrays or {}).items():
        arrays[f"run/{k}"] = np.asarray(a)
    head = {"format": FORMAT, "fingerprint": fingerprint, "step": int(sim.step_count), "state": meta,
            "effects": _effect_names(sim),
            "run": _plain(run or {})}
    if head["run"] is _NO:
        raise TypeError("run accumulators must be plain values (numbers, strings, lists, dicts)")
    arrays[_META] = np.frombuffer(json.dumps(head, allow_nan=True).encode(), dtype=np.uint8)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    return path


def _unreadable(path: Path, exc: Exception) -> CheckpointError:
    text = " ".join(str(exc).split())[:160] or type(exc).__name__
    return CheckpointError(f"cannot read the checkpoint {path} ({type(exc).__name__}: {text}); delete it to start "
                           "afresh")


def _check_head(path: Path, raw: np.ndarray, fingerprint: str | None) -> dict:
    """The header decoded from its archive member ``raw``, refused (``CheckpointError``) if it is
    unreadable, of another format or, with ``fingerprint``, of another scene."""
    try:
        head = json.loads(raw.tobytes().decode())
        if not isinstance(head, dict):
            raise ValueError("the header is not a mapping")
    except (ValueError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"{path} has an unreadable header ({exc}); delete it to start afresh") from None
    if head.get("format") != FORMAT:
        raise CheckpointError(f"{path} has format {head.get('format')!r}, this lbmpipe reads {FORMAT!r}; "
                              "delete it to start afresh")
    if fingerprint is not None and head.get("fingerprint") != fingerprint:
        raise CheckpointError(
            f"the checkpoint {path} was written for a different scene (fingerprint {str(head.get('fingerprint', '?'))[:12]} "
            f"!= {fingerprint[:12]} of this scene); delete it to start afresh, or pass the scene it belongs to")
    return head


def read(path: Path, fingerprint: str | None = None) -> tuple[dict, dict[str, np.ndarray]]:
    """``(head, arrays)`` of a checkpoint; refuses (``CheckpointError``) a file of another format
    or, with ``fingerprint``, of another scene."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            if not hasattr(z, "files"):  # a bare .npy array, not an archive
                raise ValueError("a single NumPy array, not an lbmpipe archive")
            arrays = {k: z[k] for k in z.files}
    except Exception as exc:  # noqa: BLE001 - truncated, not a zip, bad members: all one answer
        raise _unreadable(path, exc) from None
    if _META not in arrays:
        raise CheckpointError(f"{path} is not an lbmpipe checkpoint; delete it or choose another path")
    return _check_head(path, arrays.pop(_META), fingerprint), arrays


def read_head(path: Path, fingerprint: str | None = None) -> dict:
    """The header of a checkpoint (format, scene fingerprint, step), reading no state array:
    ``lbmpipe run`` refuses a bad or foreign checkpoint with it before building the simulation.
    Raises CheckpointError as :func:`read` does."""
    path = Path(path)
    try:
        z = np.load(path, allow_pickle=False, mmap_mode=None)
    except Exception as exc:  # noqa: BLE001 - not a file NumPy reads at all
        raise _unreadable(path, exc) from None
    if not hasattr(z, "files"):
        raise CheckpointError(f"cannot read the checkpoint {path} (a single NumPy array, not an lbmpipe archive); "
                              "delete it or choose another path")
    try:
        with z:
            if _META not in z.files:
                raise CheckpointError(f"{path} is not an lbmpipe checkpoint; delete it or choose another path")
            raw = z[_META]
    except CheckpointError:
        raise
    except Exception as exc:  # noqa: BLE001 - truncated archive, bad member
        raise _unreadable(path, exc) from None
    return _check_head(path, raw, fingerprint)


def load(path: Path, sim, fingerprint: str) -> tuple[dict, dict[str, np.ndarray]]:
    """Read the checkpoint at ``path``, check it belongs to this scene, restore ``sim`` in place;
    returns the run loop's ``(run values, run arrays)``."""
    head, arrays = read(path, fingerprint)
    run_arrays = {k.split("/", 1)[1]: v for k, v in arrays.items() if k.startswith("run/")}
    state = {k: v for k, v in arrays.items() if not k.startswith("run/")}
    if head.get("effects") != _effect_names(sim):
        raise CheckpointError(f"{path}: the checkpoint's time step has the effects {head.get('effects')}, this run "
                              f"{_effect_names(sim)}; delete it to start afresh")
    restore(sim, state, head["state"])
    if sim.step_count != head["step"]:
        raise CheckpointError(f"{path}: step count {sim.step_count} after restore, the file says {head['step']}")
    return head["run"], run_arrays
