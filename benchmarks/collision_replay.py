"""The collision step replayed on saved states of issue 4's case, and compared with another checkout.

The end-to-end benchmark (``collisions.py``) times the collision step in a running simulation,
where the fluid sweep's memory traffic and other jobs on the host move single windows by 10-25 %:
too much to see a change of a few percent. This script takes the case of ``collisions.py``
(``cyl8x8_c50``: the paper's pipe at dx = 1 mm, 244 cylinders of 8 x 8 mm at 50 %), runs it with
the fluid to the steps given by ``--at``, keeps a copy of the bodies there, and then times
``resolve_collisions`` on copies of those states, each with its Verlet list kept from a first call,
as a time step does:

* alone: the median time per call over ``--rounds`` rounds of ``--reps`` calls per state;
* with ``--against PATH`` (the root of another checkout, e.g. a ``git worktree`` of the commit
  before a change): both versions in one process, taking turns round by round (the order flips
  every round), so that a drift of the host's load falls on both alike. It prints each version's
  median and the median of the per-round ratios, and whether the two give the same bits (bodies
  after the call and every stat) on every state.

The other checkout's ``lbmpipe`` is imported from a copy whose absolute imports are renamed
(``lbmpipe_against``, kept in the temporary folder under a hash of its sources); it is handed the bodies, domain and parameters of this checkout's classes,
so the two must agree on those attributes. States are built with this checkout; ``--states FILE``
keeps them between runs (a pickle: load only files you wrote).

Run: ``python benchmarks/collision_replay.py [--at 100 200 300] [--rounds 31] [--reps 5]
[--threads 1] [--against ../other-checkout] [--states FILE]``.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import importlib
import pickle
import re
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import machine_info, set_threads  # noqa: E402
from collisions import scene_dict  # noqa: E402

CASE = "cyl8x8_c50"


def build_states(at: list[int]) -> dict:
    """Run the case with the fluid and keep the bodies at the steps ``at``."""
    from lbmpipe.particles.collisions import CollisionEffect
    from lbmpipe.scene import Scene
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.units import derive

    scene = Scene.model_validate(scene_dict(CASE))
    sim = simulation_from_scene(scene, derive(scene))
    coll = next(e for e in sim.effects if isinstance(e, CollisionEffect))
    states = []
    for step in sorted(at):
        sim.step(step - sim.step_count)
        states.append((step, copy.deepcopy(sim.particles.bodies)))
    return {"case": CASE, "states": states, "domain": coll.domain, "params": coll.params}


def import_other(root: Path):
    """``lbmpipe.particles.collisions`` of the checkout at ``root``, imported as ``lbmpipe_against`` from a
    renamed copy in the temporary folder. The copy's folder is named after a hash of the sources
    and kept: numba's cache knows a function by its file's path and time, so a second run against
    the same sources loads the compiled code instead of compiling it again (minutes)."""
    src, module = root / "lbmpipe", Path("particles", "collisions", "__init__.py")
    if not (src / module).is_file():
        raise SystemExit(f"--against {root}: no lbmpipe/{module.parent} package there (give the root of a checkout "
                         "of this layout)")
    digest = hashlib.sha256()
    for f in sorted(src.rglob("*.py")):
        digest.update(str(f.relative_to(src)).encode())
        digest.update(f.read_bytes())
    workdir = Path(tempfile.gettempdir()) / "lbmpipe_against" / digest.hexdigest()[:16]
    dst = workdir / "lbmpipe_against"
    if not (dst / module).is_file():
        tmp = Path(tempfile.mkdtemp(dir=workdir.parent if workdir.parent.is_dir() else None))
        shutil.copytree(src, tmp / "lbmpipe_against", ignore=shutil.ignore_patterns("__pycache__"))
        for f in (tmp / "lbmpipe_against").rglob("*.py"):
            text = f.read_text()
            text = re.sub(r"\bfrom lbmpipe(\.| import)", r"from lbmpipe_against\1", text)
            text = re.sub(r"\bimport lbmpipe\.", "import lbmpipe_against.", text)
            f.write_text(text)
        workdir.mkdir(parents=True, exist_ok=True)
        (tmp / "lbmpipe_against").rename(dst)  # whole or not at all: a stopped copy is never reused
        shutil.rmtree(tmp, ignore_errors=True)
    sys.path.insert(0, str(workdir))
    return importlib.import_module("lbmpipe_against.particles.collisions")


def first_calls(mod, data: dict) -> tuple[list, list]:
    """One call per state on a fresh copy with a new Verlet list, outside the timing: it compiles
    the code, builds each state's list for the timed calls, and gives (bodies after, stats) for
    the bit comparison (a new list gives what a call without one gives)."""
    out, lists = [], []
    for _, bodies in data["states"]:
        b = copy.deepcopy(bodies)
        nl = mod.NeighbourList()
        st = mod.resolve_collisions(b, data["domain"], data["params"], 1.0, nlist=nl)
        out.append((b, st))
        lists.append(nl)
    return out, lists


def same_bits(a: list, b: list) -> bool:
    import numpy as np

    for (ba, sa), (bb, sb) in zip(a, b):
        if sa != sb:
            return False
        if not all(np.array_equal(getattr(ba, f), getattr(bb, f)) for f in ("x", "v", "q", "wb")):
            return False
    return True


def time_round(mod, data: dict, lists: list, reps: int) -> float:
    """Mean time of a call over ``reps`` calls per state (each on a fresh copy of the state)."""
    total = 0.0
    for (_, bodies), nl in zip(data["states"], lists):
        for _ in range(reps):
            b = copy.deepcopy(bodies)
            t0 = time.perf_counter()
            mod.resolve_collisions(b, data["domain"], data["params"], 1.0, nlist=nl)
            total += time.perf_counter() - t0
    return total / (reps * len(data["states"]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--at", type=int, nargs="+", default=[100, 200, 300], help="steps whose states are replayed")
    ap.add_argument("--rounds", type=int, default=31)
    ap.add_argument("--reps", type=int, default=5, help="calls per state and round")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--against", type=Path, default=None, help="root of another checkout to compare with")
    ap.add_argument("--states", type=Path, default=None, help="pickle keeping the states between runs")
    args = ap.parse_args(argv)
    if min(args.at) < 1 or args.rounds < 1 or args.reps < 1:
        ap.error("--at, --rounds and --reps must be positive")
    set_threads(args.threads)

    import lbmpipe.particles.collisions as here

    if args.states is not None and args.states.is_file():
        with open(args.states, "rb") as fh:
            data = pickle.load(fh)
        if [s for s, _ in data["states"]] != sorted(args.at):
            raise SystemExit(f"--states {args.states} holds steps {[s for s, _ in data['states']]}, not --at "
                             f"{sorted(args.at)}: give another file or the same --at")
    else:
        t0 = time.perf_counter()
        data = build_states(args.at)
        print(f"states at steps {sorted(args.at)} built in {time.perf_counter() - t0:.0f} s")
        if args.states is not None:
            with open(args.states, "wb") as fh:
                pickle.dump(data, fh)

    mods = {"this checkout": here}
    if args.against is not None:
        mods["against"] = import_other(args.against.resolve())
    results, lists = {}, {}
    for name, m in mods.items():
        results[name], lists[name] = first_calls(m, data)
    times = {name: [] for name in mods}
    names = list(mods)
    for r in range(args.rounds):
        for name in (names if r % 2 == 0 else names[::-1]):
            times[name].append(time_round(mods[name], data, lists[name], args.reps))

    info = machine_info()
    st = results["this checkout"][0][1]
    print(f"{info['cpu_model']}; {args.threads} thread(s); case {data['case']}, states at steps "
          f"{[s for s, _ in data['states']]}; median of {args.rounds} rounds of {args.reps} calls per state")
    print(f"first state: {st['candidates']} candidate pairs, {st['pair_contacts']} pair and {st['wall_contacts']} "
          f"wall contacts, {st['impulses']} impulses in {st['sweeps']} sweeps")
    base = times["this checkout"]
    for name in names:
        line = f"  {name:<14} {1e3 * statistics.median(times[name]):8.3f} ms a call"
        if name != "this checkout":
            ratio = statistics.median(t / b for t, b in zip(times[name], base))
            bits = "same bits" if same_bits(results[name], results["this checkout"]) else "DIFFERENT bits"
            line += f"   against / this checkout: {ratio:.3f} (median of per-round ratios); {bits}"
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
