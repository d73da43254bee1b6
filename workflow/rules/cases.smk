# Cases: packing -> scene -> simulation. Particle-free cases have no packing.


def _packing_input(wildcards):
    pid = packing_id(config["cases"][wildcards.case])
    return {} if pid is None else {"packing": f"results/packings/{pid}.csv"}


def _packing_info(wildcards):
    return f"results/packings/{packing_id(config['cases'][wildcards.case])}.json"


def _threads(wildcards):
    return int(config["fidelities"][wildcards.fidelity].get("threads", 2))


def _runtime(wildcards):
    return estimate_minutes(config, wildcards.fidelity, wildcards.case)


rule pack:
    """A dense random packing (mm, shared by all levels and both Re): positions and orientations,
    or the record that the target is not reachable (with the highest concentration reached)."""
    output:
        csv="results/packings/{packing}.csv",
        info="results/packings/{packing}.json",
    log:
        "results/packings/{packing}.log",
    threads: 1
    resources:
        runtime=3,
    script:
        "../scripts/pack.py"


rule scene:
    """Write the validated scene of one case at one fidelity level."""
    input:
        unpack(_packing_input),
    output:
        "results/{fidelity}/cases/{case}/scene.yaml",
    log:
        "results/{fidelity}/logs/{case}.scene.log",
    script:
        "../scripts/write_scene.py"


rule simulate_flow:
    """Run one particle-free case with the lbmpipe solver."""
    input:
        "results/{fidelity}/cases/{case}/scene.yaml",
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
    threads: _threads
    resources:
        mem_mb=2000,
        runtime=_runtime,
    shell:
        "NUMBA_NUM_THREADS={threads} {LBMPIPE} run {input} --out $(dirname {output.summary}) --quiet --force > {log} 2>&1"


rule simulate_particles:
    """Run one particle case (or record it as not packable); checkpoints let an interrupted run
    resume where it stopped."""
    input:
        scene="results/{fidelity}/cases/{case}/scene.yaml",
        packing_info=_packing_info,
    output:
        summary="results/{fidelity}/cases/{case}/summary.json",
        flow_rate="results/{fidelity}/cases/{case}/flow_rate.csv",
        profile="results/{fidelity}/cases/{case}/profile.csv",
        particles="results/{fidelity}/cases/{case}/particles.parquet",
        static="results/{fidelity}/cases/{case}/particles_static.csv",
    wildcard_constraints:
        case="(cyl|cube|sphere)[^/]+",
    params:
        checkpoint=lambda wc: f"results/{wc.fidelity}/checkpoints/{wc.case}.npz",
    log:
        "results/{fidelity}/logs/{case}.simulate.log",
    benchmark:
        "results/{fidelity}/benchmarks/{case}.simulate.tsv"
    threads: _threads
    resources:
        mem_mb=3000,
        runtime=_runtime,
    script:
        "../scripts/simulate_case.py"
