rule scene:
    """Write the validated scene of one case at one fidelity level."""
    output:
        "results/{fidelity}/cases/{case}/scene.yaml",
    log:
        "results/{fidelity}/logs/{case}.scene.log",
    script:
        "../scripts/write_scene.py"


rule simulate:
    """Run one case with the lbmpipe solver."""
    input:
        "results/{fidelity}/cases/{case}/scene.yaml",
    output:
        summary="results/{fidelity}/cases/{case}/summary.json",
        flow_rate="results/{fidelity}/cases/{case}/flow_rate.csv",
        profile="results/{fidelity}/cases/{case}/profile.csv",
    log:
        "results/{fidelity}/logs/{case}.simulate.log",
    benchmark:
        "results/{fidelity}/benchmarks/{case}.simulate.tsv"
    threads: 2
    resources:
        mem_mb=2000,
    shell:
        "NUMBA_NUM_THREADS={threads} {LBMPIPE} run {input} --out $(dirname {output.summary}) --quiet > {log} 2>&1"
