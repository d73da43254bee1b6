# Cases: packing -> scene -> simulation. Particle-free cases have no packing.
#
# Committed results are regenerated, not rerun: a fresh clone gives its files arbitrary mtimes, so
# the inputs of every step that costs minutes are ancient() (their mtimes are ignored; a changed
# scene still reruns its case through the params trigger, and a rerun upstream job still reruns
# them), and the particle trajectory (particles.parquet, too big to commit) is written beside the
# declared outputs, not declared: its absence does not make a committed case "missing".


rule pack:
    """A dense random packing (mm, shared by all levels and both Re): positions and orientations,
    or the record that the target is not reachable (with the highest concentration reached)."""
    conda:
        "../envs/lbmpipe.yaml"
    output:
        csv="results/packings/{packing}.csv",
        info="results/packings/{packing}.json",
    log:
        "results/packings/{packing}.log",
    threads: 1
    # longest case first: its packing and scene go before the others (see simulate_particles)
    priority: PIPE.packing_priority
    resources:
        runtime=3,
    script:
        "../scripts/pack.py"


rule scene:
    """Write the validated scene of one case at one fidelity level (``run:``: in a thread of the
    running Snakemake under profiles/default, as writing a YAML file costs less than starting a
    process)."""
    localrule: True
    conda:
        "../envs/lbmpipe.yaml"
    input:
        unpack(PIPE.packing_input),
    output:
        "results/{fidelity}/cases/{case}/scene.yaml",
    log:
        "results/{fidelity}/logs/{case}.scene.log",
    params:
        settings=PIPE.scene_settings,
    priority: PIPE.runtime
    run:
        PIPE.write_scene(wildcards.fidelity, wildcards.case, output[0], packing_csv=input.get("packing"))


rule simulate_flow:
    """Run one particle-free case with the lbmpipe solver."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        scene=ancient("results/{fidelity}/cases/{case}/scene.yaml"),
    output:
        summary="results/{fidelity}/cases/{case}/summary.json",
        flow_rate="results/{fidelity}/cases/{case}/flow_rate.csv",
        profile="results/{fidelity}/cases/{case}/profile.csv",
    wildcard_constraints:
        case="flow_[^/]+",
    log:
        "results/{fidelity}/logs/{case}.simulate.log",
    benchmark:
        "results/{fidelity}/benchmarks/{case}.simulate.tsv"
    threads: PIPE.threads
    # longest first (the cost estimate), so that the last case to start is a short one
    priority: PIPE.runtime
    resources:
        mem_mb=2000,
        runtime=PIPE.time_limit,
    params:
        # a particle-free case must complete: its flow is the reference of Fig. 10
        accept=["completed"],
    script:
        "../scripts/simulate_case.py"


rule simulate_particles:
    """Run one particle case (or record it as not packable); checkpoints let an interrupted run
    resume where it stopped."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        scene=ancient("results/{fidelity}/cases/{case}/scene.yaml"),
        packing_info=ancient(PIPE.packing_info),
    output:
        summary="results/{fidelity}/cases/{case}/summary.json",
        flow_rate="results/{fidelity}/cases/{case}/flow_rate.csv",
        profile="results/{fidelity}/cases/{case}/profile.csv",
        static="results/{fidelity}/cases/{case}/particles_static.csv",
        # and particles.parquet, the trajectory (not declared: see the top of this file)
    wildcard_constraints:
        case="(cyl|cube|sphere)[^/]+(/seed[0-9]+)?",
    params:
        checkpoint=lambda wc: f"results/{wc.fidelity}/checkpoints/{wc.case}.npz",
        # an unstable or unpackable particle case is a result the statistics report
        accept=["completed", "unpackable", "unstable"],
    log:
        "results/{fidelity}/logs/{case}.simulate.log",
    benchmark:
        "results/{fidelity}/benchmarks/{case}.simulate.tsv"
    threads: PIPE.threads
    # longest first (the cost estimate): without priorities the paper level's longest case
    # (cube24_c30_re26, 13.7 min) started 30 min into the DAG, and one core idled for its last 10
    priority: PIPE.runtime
    resources:
        mem_mb=3000,
        runtime=PIPE.time_limit,
    script:
        "../scripts/simulate_case.py"
