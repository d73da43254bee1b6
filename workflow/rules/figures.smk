rule fig10_profiles:
    """Fig. 10: axial velocity profiles against the Hagen-Poiseuille parabola."""
    input:
        profiles=expand("results/{{fidelity}}/cases/{case}/profile.csv", case=[c for c in CASES if c.startswith("flow_")]),
    output:
        pdf="results/{fidelity}/figures/fig10_profiles.pdf",
        png="results/{fidelity}/figures/fig10_profiles.png",
    log:
        "results/{fidelity}/logs/fig10_profiles.log",
    script:
        "../scripts/fig10_profiles.py"
