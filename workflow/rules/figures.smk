# Per-case statistics -> aggregated tables -> the paper's figures (Figs. 3-10).

FIGURES = ["fig4_cylinders_re26", "fig5_cubes8_concentration", "fig6_cubes24_reynolds", "fig7a_shape_re9.4",
           "fig7b_shape_re26", "fig8_cylinder_orientation", "fig9_cube_orientation", "fig10_profiles"]
TABLES = ["angular_velocity", "orientation", "orientation_summary", "packing", "run_health", "runtime", "cost_validation"]


rule statistics:
    """Spin-up found (MSER-5, >= two viscous times), mean |Omega| about x, y, z and orientation statistics
    with valid batch-means intervals, orientation histograms, diagnostics (frozen, locked, run health)."""
    localrule: True
    conda:
        "../envs/lbmpipe.yaml"
    input:
        # and particles.parquet beside them (undeclared, as in simulate_particles); ancient: a fresh
        # clone's mtimes must not ask for statistics of a trajectory that is not there
        summary=ancient("results/{fidelity}/cases/{case}/summary.json"),
        static=ancient("results/{fidelity}/cases/{case}/particles_static.csv"),
        flow_rate=ancient("results/{fidelity}/cases/{case}/flow_rate.csv"),
    output:
        stats="results/{fidelity}/cases/{case}/stats.json",
        orientation="results/{fidelity}/cases/{case}/orientation.csv",
        last_frame="results/{fidelity}/cases/{case}/last_frame.csv",
    wildcard_constraints:
        case="(cyl|cube|sphere)[^/]+(/seed[0-9]+)?",
    log:
        "results/{fidelity}/logs/{case}.statistics.log",
    run:
        write_case_outputs(wildcards.case, Path(output.stats).parent, run_case(config, wildcards.case)[1], config)


rule combine_seeds:
    """A case of a level with several packings: the seeds' statistics combined (mean over the
    seeds, intervals with the within-run and the between-seed variance, diagnostics of the worst
    seed), the orientation histograms and velocity profile averaged, the seeds' statuses."""
    localrule: True
    input:
        stats=PIPE.seed_files("stats.json"),
        orientation=PIPE.seed_files("orientation.csv"),
        profile=PIPE.seed_files("profile.csv"),
        summary=PIPE.seed_files("summary.json"),
    output:
        stats="results/{fidelity}/cases/{case}/stats.json",
        orientation="results/{fidelity}/cases/{case}/orientation.csv",
        profile="results/{fidelity}/cases/{case}/profile.csv",
        summary="results/{fidelity}/cases/{case}/summary.json",
    params:
        # the run-health thresholds: changing one recombines the cases (health is judged here again)
        health=config["diagnostics"]["health"],
    wildcard_constraints:
        fidelity=level_regex(SEEDED_LEVELS),
        case="(cyl|cube|sphere)[^/]+",
    log:
        "results/{fidelity}/logs/{case}.combine.log",
    run:
        write_combined(wildcards.case, Path(output.stats).parent, [int(Path(f).parent.name[4:]) for f in input.stats],
                       config)


# In a seeded level cases/<case>/ is the seeds' combined record, never a run of its own.
ruleorder: combine_seeds > statistics
ruleorder: combine_seeds > simulate_particles


rule tables:
    """Aggregated tables over all cases (CSV), incl. packing outcomes, run times and the wall-time
    cost model of the level's runs with its leave-one-family-out validation."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        # the cases and runs present under new_runs=none (Snakefile); the benchmarks are read if present
        stats=PIPE.level_files("results/{fidelity}/cases/{case}/stats.json", case=ACTIVE_PARTICLE_CASES),
        summaries=PIPE.level_files("results/{fidelity}/cases/{case}/summary.json", case=ACTIVE_CASES),
        run_summaries=PIPE.level_files("results/{fidelity}/cases/{run}/summary.json", run=ACTIVE_RUNS),
    output:
        expand("results/{{fidelity}}/tables/{table}.csv", table=[t for t in TABLES if t != "runtime"]),
        runtime=report("results/{fidelity}/tables/runtime.csv", caption="../report/runtime.rst", category="Run time"),
        cost_model="results/{fidelity}/tables/cost_model.json",
    log:
        "results/{fidelity}/logs/tables.log",
    script:
        "../scripts/tables.py"


rule figures:
    """Figs. 4-10 as PDF and PNG, in the paper's form, with error bars from the confidence intervals."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        tables=expand("results/{{fidelity}}/tables/{table}.csv", table=TABLES),
        profiles=PIPE.level_files("results/{fidelity}/cases/{case}/profile.csv", case=ACTIVE_CASES),
    output:
        pdf=expand("results/{{fidelity}}/figures/{fig}.pdf", fig=FIGURES),
        png=[report(f"results/{{fidelity}}/figures/{fig}.png", caption=f"../report/{fig}.rst", category="Figures")
             for fig in FIGURES],
    log:
        "results/{fidelity}/logs/figures.log",
    script:
        "../scripts/figures.py"


rule snapshots:
    """One instant of each particle case: the particles in the pipe (like the paper's Fig. 3).
    One job for all cases: a drawing takes less time than starting a process for it."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        frames=PIPE.snapshot_files("last_frame.csv"),
        static=PIPE.snapshot_files("particles_static.csv"),
    output:
        [report(f"results/{{fidelity}}/figures/fig3_{case}.png", caption="../report/fig3_snapshot.rst",
                category="Snapshots", subcategory=case) for case in PARTICLE_CASES],
    log:
        "results/{fidelity}/logs/snapshots.log",
    script:
        "../scripts/snapshots.py"
