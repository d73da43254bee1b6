# Stability suite (lbmpipe.reproduction.stability): the numerically hard cases (Re 26 at the paper's dt with BGK
# and TRT, tau near 1/2, 50 % packings, the largest particles at the wall, particles released in
# contact, light particles, a long run) with the run-time guard, and their invariants, as a table.
# Lattice spacing and step counts per fidelity: lbmpipe.reproduction.stability.FIDELITY_DEFAULTS, overridden by
# config["stability"][<fidelity>] ({dx_mm, steps, flow_steps, long_steps, long_dx_mm}).
#   snakemake -c2 stability                      the table at the default fidelity
#   snakemake -c2 stability --config fidelity=smoke


rule stability_table:
    """Run the suite and write results/<fidelity>/tables/stability.csv (+ .json: settings, bounds,
    the cheapest stable Re 26 setting)."""
    conda:
        "../envs/lbmpipe.yaml"
    output:
        table="results/{fidelity}/tables/stability.csv",
        info="results/{fidelity}/tables/stability.json",
    log:
        "results/{fidelity}/logs/stability.log",
    benchmark:
        "results/{fidelity}/benchmarks/stability.tsv"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=lambda wc: {"smoke": 15, "quick": 40}.get(wc.fidelity, 240),
    params:
        # a config edit of the suite's settings reruns it
        settings=lambda wc: lbm_stability.fidelity_settings(config, wc.fidelity),
    script:
        "../scripts/stability_suite.py"


rule stability:
    """The stability table at the configured fidelity."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        expand("results/{fidelity}/tables/stability.csv", fidelity=FIDELITY),
