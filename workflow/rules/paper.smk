# The paper's claims and the literate reproduction (paper/reproduction_<fidelity>.md and .html).


rule claims:
    """Each of the 14 claims of paper/reading.md evaluated from the tables: statistic, values, verdict."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        tables=expand("results/{{fidelity}}/tables/{table}.csv", table=TABLES),
        profiles=expand("results/{{fidelity}}/cases/{case}/profile.csv", case=ACTIVE_CASES),
    output:
        report("results/{fidelity}/claims.csv", caption="../report/claims.rst", category="Claims"),
    log:
        "results/{fidelity}/logs/claims.log",
    script:
        "../scripts/claims.py"


rule paper:
    """The reproduction: equations linked to the code, parameters, figures beside the paper's
    captions, claims, stability, accuracy against cost, run cost against the paper's."""
    conda:
        "../envs/lbmpipe.yaml"
    input:
        claims="results/{fidelity}/claims.csv",
        figures=expand("results/{{fidelity}}/figures/{fig}.png", fig=FIGURES),
        snapshots=expand("results/{{fidelity}}/figures/fig3_{case}.png", case=PARTICLE_CASES),
        extra=paper_extra_inputs,
        template="paper/reproduction.md.j2",
    output:
        md="paper/reproduction_{fidelity}.md",
        html="paper/reproduction_{fidelity}.html",
        gallery="results/{fidelity}/figures/fig3_gallery.png",  # the snapshots tiled (figures.snapshot_gallery)
    log:
        "results/{fidelity}/logs/paper.log",
    script:
        "../scripts/paper.py"
