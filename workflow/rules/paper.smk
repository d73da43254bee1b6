# The paper's claims and the literate reproduction (paper/reproduction_<fidelity>.md and .html).


rule claims:
    """Each of the 14 claims of paper/reading.md evaluated from the tables: statistic, values, verdict."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        # each verdict under the robustness controls and the measured systematic term, where the level has controls
        unpack(PIPE.claims_robustness),
        tables=expand("results/{{fidelity}}/tables/{table}.csv", table=TABLES),
        profiles=PIPE.level_files("results/{fidelity}/cases/{case}/profile.csv", case=ACTIVE_CASES),
        # each verdict under the accurate method too, where a level compares with this one
        method=lambda w: ([f"results/{w.fidelity}/method/claims.csv"] if comparison_level(config, w.fidelity) else []),
    output:
        claims=report("results/{fidelity}/claims.csv", caption="../report/claims.rst", category="Claims"),
        # per claim the verdict under each control and whether it is robust (lbmpipe.reproduction.robustness)
        robustness="results/{fidelity}/tables/robustness.csv",
    log:
        "results/{fidelity}/logs/claims.log",
    script:
        "../scripts/claims.py"


rule method_comparison:
    """The paper's method against the accurate one (a level with `compare_with` this level): each
    accurate run paired with the paper-method run of the same packing, observable by observable,
    and each claim's verdict under both (results/<level>/method/)."""
    localrule: True
    input:
        other=PIPE.method_inputs,
    params:
        contents=PIPE.inputs_digest(PIPE.method_inputs),
    output:
        runs="results/{fidelity}/method/runs.csv",
        claims="results/{fidelity}/method/claims.csv",
        summary="results/{fidelity}/method/summary.json",
        figure="results/{fidelity}/method/method_comparison.png",
        figure_pdf="results/{fidelity}/method/method_comparison.pdf",
    log:
        "results/{fidelity}/logs/method_comparison.log",
    run:
        write_method_comparison(config, wildcards.fidelity, Path("results"), Path(output.summary).parent)


rule robustness:
    """The robustness controls of this level (levels with `control_of` it): every claim's verdict under
    each, the shifts per observable and the systematic term they give, the reference's convergence,
    the run health side by side and the controls' cost (results/<level>/robustness/)."""
    localrule: True
    input:
        PIPE.robustness_inputs,
        # this level's own records (the baseline of every verdict, shift and health row): a rerun of its
        # runs rebuilds the tables and with them this
        base=expand("results/{{fidelity}}/tables/{table}.csv", table=["angular_velocity", "orientation", "run_health"]),
    params:
        # the control runs present and how each ended: a new one rebuilds this (its inputs are ancient)
        present=PIPE.robustness_present,
        contents=PIPE.inputs_digest(PIPE.robustness_inputs),
    output:
        controls="results/{fidelity}/robustness/controls.csv",
        shifts="results/{fidelity}/robustness/shifts.csv",
        systematic="results/{fidelity}/robustness/systematic.json",
        convergence="results/{fidelity}/robustness/convergence.csv",
        health="results/{fidelity}/robustness/health.csv",
        cost="results/{fidelity}/robustness/cost.csv",
        unstable="results/{fidelity}/robustness/unstable.csv",
        figure="results/{fidelity}/robustness/cost_robustness.png",
        figure_pdf="results/{fidelity}/robustness/cost_robustness.pdf",
        summary="results/{fidelity}/robustness/summary.json",
    log:
        "results/{fidelity}/logs/robustness.log",
    run:
        write_robustness(config, wildcards.fidelity, Path("results"), Path(output.summary).parent)


rule controls:
    """The runs of the default level's robustness controls (issue 47): `snakemake -c2 controls --config
    new_runs=all` runs every missing one (each checkpointed; cost: benchmarks/README.md)."""
    input:
        PIPE.control_targets,


rule convergence:
    """The paper's observables by dx (levels with `convergence_of` this level): values with their
    intervals, the changes between spacings and the observed order where the noise lets it show
    (results/<level>/convergence/)."""
    localrule: True
    input:
        PIPE.convergence_inputs,
    params:
        contents=PIPE.inputs_digest(PIPE.convergence_inputs),
    output:
        values="results/{fidelity}/convergence/values.csv",
        order="results/{fidelity}/convergence/order.csv",
        summary="results/{fidelity}/convergence/summary.json",
        figure="results/{fidelity}/convergence/accuracy_cost.png",
        figure_pdf="results/{fidelity}/convergence/accuracy_cost.pdf",
    log:
        "results/{fidelity}/logs/convergence.log",
    run:
        write_convergence(config, wildcards.fidelity, Path("results"), Path(output.summary).parent)


rule paper:
    """The reproduction: equations linked to the code, parameters, figures beside the paper's
    captions, claims, stability, accuracy against cost, run cost against the paper's."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        claims="results/{fidelity}/claims.csv",
        figures=expand("results/{{fidelity}}/figures/{fig}.png", fig=FIGURES),
        snapshots=expand("results/{{fidelity}}/figures/fig3_{case}.png", case=PARTICLE_CASES),
        extra=PIPE.paper_extra_inputs,
        template="paper/reproduction.md.j2",
    output:
        md="paper/reproduction_{fidelity}.md",
        html="paper/reproduction_{fidelity}.html",
        gallery="results/{fidelity}/figures/fig3_gallery.png",  # the snapshots tiled (snapshots.snapshot_gallery)
    log:
        "results/{fidelity}/logs/paper.log",
    script:
        "../scripts/paper.py"
