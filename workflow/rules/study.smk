# Accuracy against cost (lbmpipe.reproduction.study_plan, study_errors, study): error against a reference and wall time for each
# accuracy knob (dx, dt, wall, collision, precision, averaging time). Settings per fidelity from
# config["study"][<fidelity>] over the defaults in lbmpipe/reproduction/study_plan.py. Every study run has its own
# scene, Snakemake benchmark and log; `collect` reads them with the case runs present (for the
# cost model and the observable's convergence across levels), `report` writes the figures, the
# Markdown table and the computed recommendation.
#   snakemake -c2 study                      the study at the default fidelity
#   snakemake -c2 study --config fidelity=smoke


rule study_scene:
    """The scene of one study run (a knob setting of the pipe or sphere-drag reference). Runs
    inside Snakemake (``run:``, in a thread under profiles/default): writing a YAML file costs less
    than starting a process."""
    localrule: True
    conda:
        "../envs/lbmpipe.yaml"
    output:
        "results/{fidelity}/study/runs/{run}/scene.yaml",
    wildcard_constraints:
        run="(pipe|drag)_[^/]+",
    log:
        "results/{fidelity}/logs/study/{run}.scene.log",
    run:
        lbm_study.write_run_scene(config, wildcards.fidelity, wildcards.run, output[0])


rule study_warmup:
    """Compile every kernel the study uses once, so that the benchmarks time runs, not the compiler."""
    conda:
        "../envs/lbmpipe.yaml"
    output:
        "results/{fidelity}/study/warmup.json",
    log:
        "results/{fidelity}/logs/study/warmup.log",
    threads: PIPE.study_threads
    script:
        "../scripts/study_warmup.py"


rule study_run:
    """Run one study scene (wall time in the benchmark, exact CPU time in process.json); an
    unstable run (exit status 4) is a result of the study, not a failure."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        # ancient: a fresh clone's mtimes do not rerun the committed study (cases.smk)
        scene=ancient("results/{fidelity}/study/runs/{run}/scene.yaml"),
        warmup=ancient("results/{fidelity}/study/warmup.json"),
    output:
        summary="results/{fidelity}/study/runs/{run}/summary.json",
        flow_rate="results/{fidelity}/study/runs/{run}/flow_rate.csv",
        process="results/{fidelity}/study/runs/{run}/process.json",
    wildcard_constraints:
        run="(pipe|drag)_[^/]+",
    log:
        "results/{fidelity}/logs/study/{run}.run.log",
    benchmark:
        "results/{fidelity}/study/benchmarks/{run}.tsv"
    threads: PIPE.study_threads
    resources:
        mem_mb=1500,
        runtime=10,
    script:
        "../scripts/study_run.py"


rule study_collect:
    """Errors, times and work of every study run (accuracy_cost.csv), the cost model fitted on the
    study runs and the case runs present (cost_model.json, cost_runs.csv)."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        # ancient: the collection reads the averaging case's trajectory when present, so on a fresh
        # clone (no trajectories, arbitrary mtimes) it must not run again unless a study run did
        unpack(PIPE.study_case_inputs),
        summaries=lambda wc: [ancient(f"{d}/summary.json") for d in PIPE.study_run_dirs(wc)],
        processes=lambda wc: [ancient(f"{d}/process.json") for d in PIPE.study_run_dirs(wc)],
        benchmarks=lambda wc: [ancient(f) for f in expand("results/{fidelity}/study/benchmarks/{run}.tsv",
                                                          fidelity=wc.fidelity, run=lbm_study.run_ids(config, wc.fidelity))],
    output:
        table="results/{fidelity}/study/accuracy_cost.csv",
        runs="results/{fidelity}/study/cost_runs.csv",
        model="results/{fidelity}/study/cost_model.json",
    log:
        "results/{fidelity}/logs/study/collect.log",
    script:
        "../scripts/study_collect.py"


rule study_report:
    """Error-against-time plots with the Pareto front, the Markdown table, the recommendation
    (cheapest setting meeting each target) and the cost model's predicted-vs-measured plot."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        table="results/{fidelity}/study/accuracy_cost.csv",
        runs="results/{fidelity}/study/cost_runs.csv",
        model="results/{fidelity}/study/cost_model.json",
    output:
        multiext("results/{fidelity}/study/accuracy_cost", ".pdf", ".png", ".md"),
        multiext("results/{fidelity}/study/cost_model", ".pdf", ".png"),
        rec_json="results/{fidelity}/study/recommendation.json",
        rec_md="results/{fidelity}/study/recommendation.md",
    log:
        "results/{fidelity}/logs/study/report.log",
    script:
        "../scripts/study_report.py"


rule study:
    """The whole accuracy-cost study at the configured fidelity."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        expand("results/{fidelity}/study/recommendation.json", fidelity=FIDELITY),
        expand("results/{fidelity}/study/accuracy_cost.{ext}", fidelity=FIDELITY, ext=["pdf", "png", "md", "csv"]),
        expand("results/{fidelity}/study/cost_model.{ext}", fidelity=FIDELITY, ext=["pdf", "png", "json"]),
