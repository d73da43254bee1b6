"""The functions the workflow's rules use, bound to the run's config (Snakemake's lint wants them
apart from the rules): input lists, resources and priorities, and each case's scene.

A case's scene is built, validated and derived once per Snakemake process (``Pipeline.checked``):
the config check before any job, the ``scene`` rule's params (rerun trigger), the cost estimate
(time limits, priorities) and the ``scene`` rule that writes ``scene.yaml`` all read that one
value; the run reads the file.
"""

from __future__ import annotations

import functools
import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path

from snakemake.io import ancient, expand

from lbmpipe.reproduction import study_plan as lbm_study
from lbmpipe.reproduction.cases import (case_scene, estimate_minutes, level_cases, level_runs, level_seeds, packing_id,
                                        run_case, split_run, write_case_scene)
from lbmpipe.reproduction.convergence import levels as convergence_levels
from lbmpipe.reproduction.literate import study_level
from lbmpipe.reproduction.methods import comparison_level
from lbmpipe.reproduction.robustness import control_levels, run_status, runs_done, unstable_levels
from lbmpipe.scene import Scene
from lbmpipe.units import LatticeParams, derive

# Minutes a simulation job spends before its first step: the job's Snakemake, the imports and the
# kernels (loaded from numba's cache, or compiled: about a minute cold). The cost estimate covers
# the steps only; a smoke case's estimate is 1 minute, which on the local test cluster ran out
# before the first step.
STARTUP_MINUTES = 2

# Inputs the document reads beyond figures and claims (the stability table, the study), as
# patterns of {fidelity}.
PAPER_EXTRA_INPUTS = [
    "results/{fidelity}/tables/stability.csv",
    "results/{fidelity}/study/recommendation.json",
    "results/{fidelity}/study/accuracy_cost.png",
    "results/{fidelity}/study/cost_model.png",
]


def run_present(level: str, run: str) -> bool:
    """Whether a run of ``level`` has its summary (finished, or recorded as not runnable)."""
    return Path("results", level, "cases", run, "summary.json").exists()


def level_regex(levels) -> str:
    """A wildcard constraint matching exactly these fidelity levels (none: matches nothing)."""
    return "|".join(re.escape(x) for x in levels) if levels else "(?!)"


@dataclass(frozen=True)
class CheckedScene:
    """One run's scene at one level: the scene file's data (before the packing file is named),
    the validated scene and its lattice parameters."""

    data: dict
    scene: Scene
    params: LatticeParams


class Pipeline:
    """The workflow's functions for one config: ``new_runs`` (``all`` or ``none``), the default
    level ``fidelity``, its ``runs`` and the particle cases, the levels with seeds."""

    def __init__(self, config: dict, fidelity: str, new_runs: str, runs: list[str], particle_cases: list[str],
                 seeded_levels: list[str]):
        self.config = config
        self.fidelity = fidelity
        self.new_runs = new_runs
        self.runs = runs
        self.particle_cases = particle_cases
        self.seeded_levels = seeded_levels
        self._checked: dict[tuple[str, str], CheckedScene] = {}

    def level_files(self, pattern: str, **lists):
        """Input function of a rule that gathers a whole level (tables, figures, claims): ``pattern``
        expanded over ``lists`` (this workflow's level's cases or runs) for the target's ``fidelity``.
        Those lists are the configured level's, so a target of another level is an error naming the
        fix, never a plan over the wrong cases."""
        def files(w):
            if w.fidelity != self.fidelity:
                raise ValueError(f"results/{w.fidelity}/ is level {w.fidelity!r}, but this workflow builds level "
                                 f"{self.fidelity!r} (its cases and runs): run it with `--config fidelity={w.fidelity}`")
            return expand(pattern, fidelity=w.fidelity, **lists)
        return files

    # -- a case's scene ----------------------------------------------------------------------------
    def checked(self, level: str, run: str) -> CheckedScene:
        """The run's scene at ``level``, built, validated and derived on first use only; raises
        ``SceneError`` (or ``ValueError``, ``KeyError``) as ``lbmpipe check`` would."""
        key = (level, run)
        if key not in self._checked:
            name, case = run_case(self.config, run)
            data = case_scene(name, case, level, self.config["fidelities"][level])
            scene = Scene.model_validate(data)
            self._checked[key] = CheckedScene(data, scene, derive(scene))
        return self._checked[key]

    def check(self, case: str, level: str) -> None:
        """``cases.config_problems``' check of one case at one level, through the cache."""
        self.checked(level, case)

    def scene_settings(self, wildcards) -> str:
        # The case's scene as a param: an edit of config.yaml that changes it (a level's dx, dt or
        # duration, a case's particles) reruns that case under Snakemake's params rerun trigger, and
        # only the cases it changes.
        return json.dumps(self.checked(wildcards.fidelity, wildcards.case).data, sort_keys=True)

    def write_scene(self, level: str, run: str, path, packing_csv=None) -> None:
        """``scene.yaml`` of a run (the file the run reads), from the scene validated once."""
        write_case_scene(self.config, level, run, path, packing_csv=packing_csv,
                         scene=self.checked(level, run).scene)

    # -- packings ----------------------------------------------------------------------------------
    def packing_input(self, wildcards) -> dict:
        pid = packing_id(run_case(self.config, wildcards.case)[1])
        return {} if pid is None else {"packing": ancient(f"results/packings/{pid}.csv")}

    def packing_info(self, wildcards) -> str:
        return f"results/packings/{packing_id(run_case(self.config, wildcards.case)[1])}.json"

    def packing_priority(self, wildcards) -> int:
        # The longest case waiting for this packing (at the default level): priorities on the
        # simulations alone did not reach their packings, and the paper level's two longest cases
        # (13 min each) waited 18 min for theirs.
        return max((self.estimate(self.fidelity, r) for r in self.runs
                    if packing_id(run_case(self.config, r)[1]) == wildcards.packing), default=1)

    # -- resources ---------------------------------------------------------------------------------
    def threads(self, wildcards) -> int:
        return int(self.config["fidelities"][wildcards.fidelity].get("threads", 2))

    @functools.cache  # noqa: B019 (one Pipeline per Snakemake process)
    def estimate(self, level: str, run: str) -> int:
        """Wall-time estimate of a run in minutes (``cases.estimate_minutes``) from its scene."""
        checked = self.checked(level, run)
        return estimate_minutes(self.config, level, run, scene=checked.scene)

    def runtime(self, wildcards) -> int:
        return self.estimate(wildcards.fidelity, wildcards.case)

    def time_limit(self, wildcards, attempt) -> int:
        # The cluster's time limit (`runtime`, minutes): the estimate plus the start-up; a retry (after
        # a time-limit kill, resuming from the checkpoint) gets twice as long.
        return (self.estimate(wildcards.fidelity, wildcards.case) + STARTUP_MINUTES) * attempt

    # -- study -------------------------------------------------------------------------------------
    def study_run_dirs(self, wildcards) -> list[str]:
        return expand("results/{fidelity}/study/runs/{run}", fidelity=wildcards.fidelity,
                      run=lbm_study.run_ids(self.config, wildcards.fidelity))

    def study_case_inputs(self, wildcards) -> dict:
        # The averaging-time reference reads one particle case of this level; it is an input so that
        # the study waits for it. Other levels and the other cases are read if present, not required.
        case = lbm_study.study_settings(self.config, wildcards.fidelity)["averaging"]["case"]
        if case not in self.config["cases"]:
            return {}
        # ancient, and the case's trajectory (particles.parquet) read if present, not declared: the
        # committed study is regenerated on a fresh clone without rerunning the case (cases.smk)
        return {"case_summary": ancient(f"results/{wildcards.fidelity}/cases/{case}/summary.json"),
                "case_stats": ancient(f"results/{wildcards.fidelity}/cases/{case}/stats.json")}

    def study_threads(self, wildcards) -> int:
        return int(lbm_study.study_settings(self.config, wildcards.fidelity)["threads"])

    # -- per-case records and figures ----------------------------------------------------------------
    def seed_files(self, name: str):
        """The seeds' files ``name`` a case's combined record reads (lbmpipe.reproduction.seeds)."""
        def files(wildcards):
            runs = [f"{wildcards.case}/seed{k}" for k in level_seeds(self.config["fidelities"][wildcards.fidelity])]
            if self.new_runs != "all":  # the seeds present (Snakefile)
                runs = [r for r in runs if run_present(wildcards.fidelity, r)]
            return [f"results/{wildcards.fidelity}/cases/{r}/{name}" for r in runs]
        return files

    def snapshot_files(self, name: str):
        """The run each snapshot (Fig. 3) draws: the case's, or its first seed's in a seeded level."""
        def files(wildcards):
            seeded = wildcards.fidelity in self.seeded_levels

            def run_dir(case):
                return "/".join(["results", wildcards.fidelity, "cases", case] + (["seed1"] if seeded else []))

            # under new_runs=none the runs whose last frame is here or can be made from their
            # trajectory (a snapshot drawn from a trajectory no longer here is kept as it is)
            def drawable(d):
                return any(Path(d, f).exists() for f in ("last_frame.csv", "particles.parquet"))

            # a level may run a subset of the cases; a case declared unpackable has no run to draw
            ran = {split_run(r)[0] for r in level_runs(self.config, wildcards.fidelity)}
            return [f"{run_dir(c)}/{name}" for c in self.particle_cases
                    if c in ran and (self.new_runs == "all" or drawable(run_dir(c)))]
        return files

    # -- the document ------------------------------------------------------------------------------
    def paper_extra_inputs(self, wildcards) -> list[str]:
        # a level with `study_level` shows that level's stability table and study (the same lattice);
        # a level another one compares its method with shows that comparison
        level = study_level(self.config, wildcards.fidelity)
        extra = [pattern.format(fidelity=level) for pattern in PAPER_EXTRA_INPUTS]
        if comparison_level(self.config, wildcards.fidelity) is not None:
            extra += [f"results/{wildcards.fidelity}/method/{name}" for name in ("summary.json", "method_comparison.png")]
        if len(convergence_levels(self.config, wildcards.fidelity)) > 1:
            extra.append(f"results/{wildcards.fidelity}/convergence/summary.json")
        if control_levels(self.config, wildcards.fidelity):
            extra += [f"results/{wildcards.fidelity}/{name}" for name in
                      ("robustness/summary.json", "robustness/cost_robustness.png", "robustness/unstable.csv",
                       "tables/robustness.csv")]
            # the measured causes of the unstable runs, of this level and of its reruns (robustness.unstable_causes)
            extra += sorted(str(p) for lvl in [wildcards.fidelity, *unstable_levels(self.config, wildcards.fidelity)]
                            for p in Path(f"results/{lvl}/unstable").glob("*.json"))
        # the reruns the provenance paragraph counts (provenance.rerun_counts), where the level has them
        if Path(f"results/{wildcards.fidelity}/reruns.csv").exists():
            extra.append(f"results/{wildcards.fidelity}/reruns.csv")
        return extra

    def method_inputs(self, wildcards) -> list:
        # the runs of both levels the comparison pairs, where present: it reads what exists (a level's
        # production is finished in parts) and evaluates the claims of both methods itself
        other = comparison_level(self.config, wildcards.fidelity)
        if other is None:
            return []
        files = []
        for run in level_runs(self.config, other):
            for lvl in (other, wildcards.fidelity):
                files += [ancient(f) for f in (f"results/{lvl}/cases/{run}/summary.json",
                                               f"results/{lvl}/cases/{run}/stats.json") if Path(f).exists()]
        return files

    def control_runs_present(self, level: str) -> list[str]:
        """The runs of a control level whose summary says how it ended (its production is run apart:
        `snakemake controls`): the runs the robustness verdicts read (``robustness.runs_done``)."""
        return runs_done(self.config, level, Path("results"))[0]

    def robustness_inputs(self, wildcards) -> list:
        # each control run present with its statistics (built here where missing: a run just copied
        # in), and a seeded level's combined record of every case with a packing present
        files = []
        for lvl in control_levels(self.config, wildcards.fidelity):
            present = self.control_runs_present(lvl)
            for run in present:
                files.append(ancient(f"results/{lvl}/cases/{run}/summary.json"))
                if self.config["cases"][split_run(run)[0]].get("particles") is not None:
                    files.append(ancient(f"results/{lvl}/cases/{run}/stats.json"))
            if "seeds" in self.config["fidelities"][lvl]:
                files += [ancient(f"results/{lvl}/cases/{c}/stats.json")
                          for c in sorted({split_run(r)[0] for r in present if "/seed" in r})]
        for lvl in unstable_levels(self.config, wildcards.fidelity):  # how each rerun ended: its summary
            files += [ancient(f"results/{lvl}/cases/{run}/summary.json") for run in self.control_runs_present(lvl)]
        return files

    def robustness_present(self, wildcards) -> str:
        """The control runs present with how each ended: a rerun trigger (params), so a run added
        since the last build rebuilds the robustness outputs although the inputs are ancient."""
        rows = []
        for lvl in control_levels(self.config, wildcards.fidelity) + unstable_levels(self.config, wildcards.fidelity):
            for run in self.control_runs_present(lvl):
                rows.append(f"{lvl}/{run}={run_status(Path('results'), lvl, run)}")
        return "; ".join(rows)

    def claims_robustness(self, wildcards) -> dict:
        # the controls' verdicts and the measured systematic term, where this level has controls
        if not control_levels(self.config, wildcards.fidelity):
            return {}
        return {"controls": f"results/{wildcards.fidelity}/robustness/controls.csv",
                "systematic": f"results/{wildcards.fidelity}/robustness/systematic.json"}

    def control_targets(self, wildcards=None) -> list[str]:
        """Every record of the default level's controls (`snakemake controls --config new_runs=all` runs
        what is missing; under new_runs=none only what is present)."""
        files = []
        for lvl in control_levels(self.config, self.fidelity):
            seeded = "seeds" in self.config["fidelities"][lvl]
            for run in level_runs(self.config, lvl):
                particle = self.config["cases"][run.partition("/seed")[0]].get("particles") is not None
                files.append(f"results/{lvl}/cases/{run}/{'stats' if particle else 'summary'}.json")
            if seeded:
                files += [f"results/{lvl}/cases/{c}/stats.json" for c in level_cases(self.config, lvl)
                          if self.config["cases"][c].get("particles") is not None]
        for lvl in unstable_levels(self.config, self.fidelity):  # the unstable packings rerun: their summaries
            files += [f"results/{lvl}/cases/{run}/summary.json" for run in level_runs(self.config, lvl)]
        if self.new_runs != "all":
            files = [f for f in files if Path(f).exists()]
        return files

    def inputs_digest(self, inputs) -> callable:
        """A params function: the sha256 of the contents of ``inputs(wildcards)``'s files, a rerun
        trigger for a rule whose inputs are ancient (their mtimes ignored), so that a run's statistics
        rebuilt in place (a rerun, a statistics fix) rebuild what reads them instead of leaving it stale.
        An input another job of the same DAG still has to build (a copied-in run's statistics) enters
        by its name alone; the job runs anyway, since that input is new."""
        def digest(wildcards) -> str:
            h = hashlib.sha256()
            for f in sorted(str(f) for f in inputs(wildcards)):
                h.update(f.encode() + b"\0" + (Path(f).read_bytes() if Path(f).exists() else b"\0(to be built)"))
            return h.hexdigest()
        return digest

    def convergence_inputs(self, wildcards) -> list:
        # the records of the cases the refining levels share with this one, where present
        files = []
        for lvl in convergence_levels(self.config, wildcards.fidelity):
            for case in level_cases(self.config, lvl):
                files += [ancient(f) for f in (f"results/{lvl}/cases/{case}/stats.json",
                                               f"results/{lvl}/cases/{case}/profile.csv") if Path(f).exists()]
        return files
