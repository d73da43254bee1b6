# Per-case statistics -> aggregated tables -> the paper's figures (Figs. 3-10).

FIGURES = ["fig4_cylinders_re26", "fig5_cubes8_concentration", "fig6_cubes24_reynolds", "fig7a_shape_re9.4",
           "fig7b_shape_re26", "fig8_cylinder_orientation", "fig9_cube_orientation", "fig10_profiles"]
TABLES = ["angular_velocity", "orientation", "orientation_summary", "packing", "run_health", "runtime"]


rule statistics:
    """Spin-up found (MSER-5, >= two viscous times), mean |Omega| about x, y, z and orientation statistics
    with valid batch-means intervals, orientation histograms, diagnostics (frozen, locked, run health)."""
    localrule: True
    conda:
        "../envs/lbmpipe.yaml"
    input:
        summary="results/{fidelity}/cases/{case}/summary.json",
        particles="results/{fidelity}/cases/{case}/particles.parquet",
        static="results/{fidelity}/cases/{case}/particles_static.csv",
        flow_rate="results/{fidelity}/cases/{case}/flow_rate.csv",
    output:
        stats="results/{fidelity}/cases/{case}/stats.json",
        orientation="results/{fidelity}/cases/{case}/orientation.csv",
    wildcard_constraints:
        case="(cyl|cube|sphere)[^/]+(/seed[0-9]+)?",
    log:
        "results/{fidelity}/logs/{case}.statistics.log",
    run:
        write_case_outputs(wildcards.case, Path(output.stats).parent, run_case(config, wildcards.case)[1], config)


rule tables:
    """Aggregated tables over all cases (CSV), incl. packing outcomes and run times."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        stats=expand("results/{{fidelity}}/cases/{case}/stats.json", case=PARTICLE_CASES),
        summaries=expand("results/{{fidelity}}/cases/{case}/summary.json", case=CASES),
        benchmarks=expand("results/{{fidelity}}/benchmarks/{case}.simulate.tsv", case=CASES),
    output:
        expand("results/{{fidelity}}/tables/{table}.csv", table=[t for t in TABLES if t != "runtime"]),
        runtime=report("results/{fidelity}/tables/runtime.csv", caption="../report/runtime.rst", category="Run time"),
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
        profiles=expand("results/{{fidelity}}/cases/{case}/profile.csv", case=CASES),
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
        particles=expand("results/{{fidelity}}/cases/{case}/particles.parquet", case=PARTICLE_CASES),
        static=expand("results/{{fidelity}}/cases/{case}/particles_static.csv", case=PARTICLE_CASES),
    output:
        [report(f"results/{{fidelity}}/figures/fig3_{case}.png", caption="../report/fig3_snapshot.rst",
                category="Snapshots", subcategory=case) for case in PARTICLE_CASES],
    log:
        "results/{fidelity}/logs/snapshots.log",
    script:
        "../scripts/snapshots.py"
