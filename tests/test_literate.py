"""The literate reproduction (lbmpipe.reproduction.literate): every equation of the paper is linked to the code
that implements it, the links stay true, and the document is built from results alone."""

import ast
import json
import re
import shutil
from pathlib import Path

import pandas as pd
import pytest
import yaml

from lbmpipe.reproduction import claims, document_sections, equations, findings, literate
from lbmpipe.reproduction.snapshots import fig3_cases
from lbmpipe.reproduction.cases import case_scene
from lbmpipe.scene import Scene
from lbmpipe.units import derive

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def index():
    return equations.equation_index(REPO / "lbmpipe")


def test_every_equation_of_the_paper_is_cited_by_a_function_or_class_docstring(index):
    missing = [n for n in range(1, equations.N_EQUATIONS + 1)
               if not any(r.qualname != "<module>" for r in index.get(n, []))]
    assert missing == []
    assert sorted(equations.EQUATIONS) == list(range(1, equations.N_EQUATIONS + 1))


def test_every_equation_reference_is_a_definition_whose_docstring_cites_it(index):
    files = {}
    for n, refs in index.items():
        for ref in refs:
            if ref.module not in files:
                source = (REPO / ref.module).read_text()
                tree = ast.parse(source)
                defs = {nd.lineno: nd for nd in ast.walk(tree)
                        if isinstance(nd, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))}
                files[ref.module] = (source.splitlines(), tree, defs)
            lines, tree, defs = files[ref.module]
            if ref.qualname == "<module>":
                assert ref.line == 1
                doc = ast.get_docstring(tree, clean=False)
            else:
                name = ref.qualname.rsplit(".", 1)[-1]
                assert re.match(rf"\s*(async\s+def|def|class)\s+{re.escape(name)}\b", lines[ref.line - 1]), ref
                doc = ast.get_docstring(defs[ref.line], clean=False)
            assert n in equations.cited_equations(doc), (n, ref)


def test_equations_cited_in_subpackages_are_indexed_with_their_paths(index, tmp_path):
    # the fluid, particle and reproduction layers live in subpackages: Eq. (7) (the lattice) and
    # Eqs. (16)-(21) (collisions) are cited there only
    assert any(r.module == "lbmpipe/fluid/lattice.py" for r in index[7])
    assert any(r.module == "lbmpipe/particles/collisions/impulse.py" for r in index[16])
    pkg = tmp_path / "lbmpipe"
    (pkg / "deep" / "deeper").mkdir(parents=True)
    (pkg / "deep" / "deeper" / "m.py").write_text('def f():\n    """Implements Eq. (3)."""\n')
    assert equations.equation_index(pkg)[3] == [equations.Ref("lbmpipe/deep/deeper/m.py", "f", 1)]


def test_citation_forms_single_range_list_pair_and_subequation_are_read():
    cite = equations.cited_equations
    assert cite("Ladd's rule, Eq. (8).") == {8}
    assert cite("coupling, Eqs. (8)-(12), then") == {8, 9, 10, 11, 12}
    assert cite("Eqs. (14), (15) and Eqs. (16) and (18)") == {14, 15, 16, 18}
    assert cite("recovers Navier-Stokes (Eq. (5, 6))") == {5, 6}
    assert cite("Euler, Eq. (13a)") == {13}
    assert cite("Table 1 (not an equation), equation (3) without the abbreviation") == set()


def test_number_format_keeps_three_significant_digits_and_marks_missing_values():
    assert document_sections.fmt(1.7812) == "1.78"
    assert document_sections.fmt(0.000123456) == "1.23e-04"
    assert document_sections.fmt(2000.0) == "2000"
    assert document_sections.fmt(float("nan")) == "–"


# ---------------------------------------------------------------- a synthetic results tree


@pytest.fixture(scope="module")
def config():
    return yaml.safe_load((REPO / "config.yaml").read_text())


def synthetic_level(fid_dir: Path, config: dict) -> None:
    """A small results tree following the pipeline contract: tables, one figure, runtimes."""
    cases = config["cases"]
    tables = fid_dir / "tables"
    tables.mkdir(parents=True)
    rows = []
    for k, (name, case) in enumerate(n_c for n_c in cases.items() if "particles" in n_c[1]):
        p = case["particles"]
        rows.append({"case": name, "shape": p["shape"], "size_label": "", "diameter_mm": p.get("diameter_mm"),
                     "length_mm": p.get("length_mm"), "edge_mm": p.get("edge_mm"),
                     "concentration": p["concentration"], "reynolds": case["reynolds"],
                     "collisions": case.get("collisions", True), "status": "completed",
                     "concentration_achieved": p["concentration"], "n_particles": 10, "samples": 50,
                     "omega_x": 1.0 + 0.01 * k, "omega_y": 1.0, "omega_z": 0.5, "ci_x": 0.05, "ci_y": 0.05,
                     "ci_z": 0.05})
    pd.DataFrame(rows).to_csv(tables / "angular_velocity.csv", index=False)
    pd.DataFrame({"case": list(cases), "status": "completed", "steps": 1000, "simulated_s": 2.0,
                  "wall_s": 7654.0, "s_per_step": 0.5, "mlups": 3.21, "particles": 10,
                  "max_rss_mb": 300.0}).to_csv(tables / "runtime.csv", index=False)
    figs = fid_dir / "figures"
    figs.mkdir()
    # a 1x1 PNG is all the document needs; it does not look inside
    (figs / "fig4_cylinders.png").write_bytes(bytes.fromhex(
        "89504e470d0a1a0a0000000d4948445200000001000000010806000000"
        "1f15c4890000000d49444154789c6360000002000154a24f5d0000000049454e44ae426082"))
    claims.write_claims(fid_dir, cases)


@pytest.fixture
def document(tmp_path, config):
    fid_dir = tmp_path / "results" / "synthetic"
    synthetic_level(fid_dir, config)
    out = literate.build_document(REPO, fid_dir, "paper", config, fid_dir / "paper" / "reproduction.md")
    return out, fid_dir


def test_rendered_document_has_no_stale_links_and_links_every_equation(document):
    out, _ = document
    assert equations.check_links(out, REPO) == []
    text = out.read_text()
    for n in range(1, equations.N_EQUATIONS + 1):
        assert f'"Eq. {n}: ' in text, n
    assert out.with_suffix(".html").read_text().count("<table>") >= 3


def test_document_numbers_come_from_the_results_and_the_derived_lattice(document, config):
    out, fid_dir = document
    text = out.read_text()
    fid = config["fidelities"]["paper"]
    params = derive(Scene.model_validate(case_scene("flow_re26", {"reynolds": 26}, "paper", fid)))
    # one row per level, the Reynolds numbers' values joined Re 9.4/26: Re 26's is the last of each
    row = next(line for line in text.splitlines() if line.startswith("| **paper** |"))
    cells = [c.strip() for c in row.strip("| ").split("|")]
    assert cells[4].split("/")[-1] == document_sections.fmt(params.tau)
    assert cells[5].split("/")[-1] == document_sections.fmt(params.mach_max)
    assert cells[7].split("/")[-1] == document_sections.fmt(params.n_steps)
    # runtime: 7654 s per case from runtime.csv, reported in hours and against the paper's 24 h
    assert document_sections.fmt(7654.0 / 3600) in text and document_sections.fmt(7654.0 / 3600 / 24.0) in text
    verdicts = pd.read_csv(fid_dir / "claims.csv")["verdict"]
    assert all(f"| {v} |" in text for v in verdicts)
    assert "![fig4_cylinders](../figures/fig4_cylinders.png)" in text
    assert document_sections.PAPER_CAPTIONS["4"] in text


def test_sections_without_input_say_they_were_not_built(tmp_path, config):
    fid_dir = tmp_path / "results" / "empty"
    fid_dir.mkdir(parents=True)
    out = literate.build_document(REPO, fid_dir, "smoke", config, fid_dir / "reproduction.md")
    text = out.read_text()
    # (the accuracy-cost study of the lattice is no longer shown: Appendix F reads the level's own controls)
    for rel in ("claims.csv", "tables/stability.csv", "tables/runtime.csv", "tables/run_health.csv",
                "figures/fig*.png"):
        assert re.search(rf"not built at this level: `[^`]*/{re.escape(rel)}` missing", text), rel
    assert equations.check_links(out, REPO) == []


def copy_repo(dst: Path) -> Path:
    shutil.copytree(REPO / "lbmpipe", dst / "lbmpipe", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(REPO / "paper", dst / "paper")
    return dst


def test_check_links_reports_links_whose_definition_moved_or_no_longer_cites_the_equation(tmp_path, config):
    repo = copy_repo(tmp_path / "repo")
    fid_dir = repo / "results" / "synthetic"
    fid_dir.mkdir(parents=True)
    out = literate.build_document(repo, fid_dir, "smoke", config, fid_dir / "reproduction.md")
    assert equations.check_links(out, repo) == []
    links = re.findall(r'\]\(([^)\s]+\.py)#L(\d+) "Eq\. (\d+): ([^"]+)"\)', out.read_text())
    by_file = {}
    for rel, line, eq, qual in links:
        by_file.setdefault(Path(rel).name, []).append((int(line), int(eq), qual))

    # shift every definition of lattice.py down by one line
    lattice = repo / "lbmpipe" / "fluid" / "lattice.py"
    lattice.write_text("\n" + lattice.read_text())
    stale = equations.check_links(out, repo)
    assert stale and all(s.startswith("lbmpipe/fluid/lattice.py#L") and "no longer holds" in s for s in stale)
    assert len(stale) == len(by_file["lattice.py"])

    # the line still holds the definition but its docstring stops citing the equation
    lattice.write_text(lattice.read_text()[1:].replace("Table 1 and Eq. (7)", "Table 1"))
    stale = equations.check_links(out, repo)
    line = next(ln for ln, eq, qual in by_file["lattice.py"] if qual == "get_lattice")
    assert f"lbmpipe/fluid/lattice.py#L{line}: docstring of get_lattice no longer cites Eq. (7)" in stale
    assert all(s.startswith("lbmpipe/fluid/lattice.py") for s in stale)

    # a file that is gone
    (repo / "lbmpipe" / "fluid" / "observables.py").unlink()
    stale = equations.check_links(out, repo)
    assert any(s.startswith("lbmpipe/fluid/observables.py#L") and s.endswith("file missing") for s in stale)


@pytest.mark.parametrize("level", ["paper"])
def test_committed_reproduction_links_still_point_at_the_code_that_implements_each_equation(level):
    # The committed document links equations to lines of the package: a change that moves or
    # rewrites one of those definitions must come with the rebuilt document.
    md = REPO / "paper" / f"reproduction_{level}.md"
    if not md.exists():
        pytest.skip(f"{md.name} is not committed")
    stale = equations.check_links(md, REPO)
    assert stale == [], (f"{len(stale)} stale links in {md.name}; rebuild it with "
                         f"`lbmpipe document --fidelity {level}`: {stale[:5]}")


def test_document_command_without_results_names_the_pipeline_command_and_fails(tmp_path, capsys):
    from lbmpipe.cli import EXIT_FAILED, run_cli
    (tmp_path / "config.yaml").write_text("fidelities: {}\ncases: {}\n")
    assert run_cli(["document", "--fidelity", "nosuch", "--root", str(tmp_path)]) == EXIT_FAILED
    assert "snakemake -c2 --config fidelity=nosuch" in capsys.readouterr().err
    assert not (tmp_path / "paper").exists()  # nothing written


# ---------------------------------------------------------------- the document of the committed results


@pytest.fixture(scope="module")
def committed_document(tmp_path_factory):
    """The document and page of the committed ``results/paper``, built into a temporary folder."""
    if not (REPO / "results" / "paper" / "claims.csv").is_file():
        pytest.skip("results/paper/claims.csv is not in this checkout")
    config = yaml.safe_load((REPO / "config.yaml").read_text())
    out = tmp_path_factory.mktemp("doc") / "reproduction_paper.md"
    md, stale = literate.build_checked_document(REPO, "paper", config, out_md=out)
    return md, stale


def test_committed_document_has_the_structure_of_a_paper_with_a_short_main_text(committed_document):
    md, stale = committed_document
    assert stale == []
    text = md.read_text()
    assert literate.word_count(literate.main_text(text)) < 4000
    sections = re.findall(r"^## (.+)$", text, flags=re.M)
    main = ["Abstract", "Method"] + [f"Fig. {k}:" for k in ("4", "5", "6", "7", "8", "9", "10")] + [
        "Claims summary", "Limitations", "Run health"]
    assert len(sections) > len(main)
    assert all(s.startswith(m) for s, m in zip(sections, main)), sections
    assert all(s.startswith("Appendix") for s in sections[len(main):]), sections


def test_committed_document_anchors_each_claim_once_and_shows_one_snapshot_gallery(committed_document):
    md, _ = committed_document
    text, page = md.read_text(), md.with_suffix(".html").read_text()
    claims_csv = pd.read_csv(REPO / "results" / "paper" / "claims.csv")
    anchors = re.findall(r'\sid="(claim-\d+)"', page)
    assert sorted(anchors) == sorted(f"claim-{c}" for c in claims_csv["claim"])
    snapshots = re.findall(r"!\[[^\]]*\]\(([^)]*fig3_[^)]*)\)", text)
    # Fig. 3: one image of four snapshots (the file name the pipeline's paper rule writes), each case named
    assert len(snapshots) == 1 and snapshots[0].endswith("figures/fig3_gallery.png")
    config = yaml.safe_load((REPO / "config.yaml").read_text())
    shown = fig3_cases(config, REPO / "results" / "paper")
    assert len(shown) == 4 and all(f"`{c}`" in text for c in shown)
    assert (md.parent / snapshots[0]).resolve().is_file()
    # the key equations are displayed maths, converted to MathML
    assert page.count('display="block"') >= len(equations.KEY_EQUATIONS)


def test_word_count_leaves_out_link_targets_and_table_rules():
    assert literate.word_count("| a | b |\n| --- | --- |\n[two words](../x.py#L3 \"Eq. 3: f\")") == 4
    assert literate.main_text("intro\n## Appendix A: x\nmore") == "intro\n"


def test_the_document_of_an_accurate_method_level_builds_and_names_the_level_it_is_compared_with(tmp_path, config):
    # `snakemake --config fidelity=credible_accurate` builds this level's own document too
    fid_dir = tmp_path / "results" / "credible_accurate"
    fid_dir.mkdir(parents=True)
    out = literate.build_document(REPO, fid_dir, "credible_accurate", config, fid_dir / "reproduction.md")
    text = out.read_text()
    paper_level = config["fidelities"]["credible_accurate"]["compare_with"]
    assert "## What the method changes" in text and f"`results/{paper_level}/method/`" in text
    # the numerics its method changes, read from the config (METHODS), not a fixed sentence
    method = config["fidelities"]["credible_accurate"]["method"]
    assert f"the method `{method}`" in text and "wall: bouzidi" in text
    assert "### The paired runs of the method comparison" not in text
    assert equations.check_links(out, REPO) == []


def test_claims_summary_counts_missing_and_flagged_cases_not_the_clauses_of_their_flags():
    """A reason lists its missing cases, then its flagged cases with their flags seed by seed
    (``"; "`` inside parentheses too): the summary counts cases, one each, not clauses."""
    from lbmpipe.reproduction.literate import _short_reason, claims_summary

    reason = ("the pooled 95 % interval excludes 0; missing: a_re26: status unstable (seed 3: unstable); "
              "flagged cases: b_re9.4: unhealthy (seed 1: mass 0.02 > 0.01; seed 2: mass 0.03 > 0.01); "
              "b_re9.4: not steady (seed 1: x: halves differ by 0.1 > 0.05); c_re26: frozen (0.6 > 0.5)")
    assert _short_reason(reason) == ("the pooled 95 % interval excludes 0", 1, 2)
    rows = claims_summary(pd.DataFrame([{"claim": 1, "statement": "s", "verdict": "reproduced",
                                         "values": "pooled D = 1", "reason": reason}]))
    assert rows[0]["reason"] == "the pooled 95 % interval excludes 0 (1 case missing; 2 cases flagged)"


# --------------------------------------------------------------------------------------------------
# numbers the document prints (issue 46, item 4)


def test_claims_summary_prints_the_accurate_methods_verdict_the_deciding_number_and_what_carries_it():
    from lbmpipe.reproduction.literate import claims_summary

    base = {"statement": "s", "values": "pooled D = 0.1 ± 0.09 over 9; first comparison", "reason": "r",
            "carried_by": "1 of 9 significant in the claimed direction, 0 reversed",
            "verdict_without_frozen_locked": "reproduced", "verdict_without_flagged": "inconclusive",
            "robust": "yes"}
    rows = claims_summary(pd.DataFrame([
        {**base, "claim": 3, "verdict": "reproduced", "deciding": "pooled D = 0.1 ± 0.09 rad/s",
         "verdict_paper_method_seed1": "inconclusive", "verdict_accurate_method_seed1": "inconclusive",
         "same_under_both_methods": "yes"},
        {**base, "claim": 12, "verdict": "inconclusive", "deciding": "b vs a: d = 2 [-5, 9] deg against ±4.5",
         "verdict_paper_method_seed1": "reproduced", "verdict_accurate_method_seed1": "inconclusive",
         "same_under_both_methods": "no"},
        {**base, "claim": 14, "verdict": "inconclusive", "deciding": "", "verdict_paper_method_seed1": "inconclusive",
         "verdict_accurate_method_seed1": "inconclusive", "same_under_both_methods": "not compared"}]))
    # the accurate method's own verdict, never the paper method's seed-1 one
    assert rows[0]["method"].startswith("inconclusive (paper method on the same packing: the same)")
    assert rows[1]["method"] == "inconclusive (paper method on the same packing: reproduced)"
    assert rows[2]["method"].startswith("none:")
    assert rows[1]["number"] == "b vs a: d = 2 [-5, 9] deg against ±4.5"
    assert rows[0]["carried"] == "1 of 9 significant in the claimed direction, 0 reversed"
    assert rows[0]["without"] == "reproduced / inconclusive" and rows[0]["robust"] == "yes"


def test_claims_changed_by_the_method_read_as_a_count_with_their_numbers():
    assert document_sections.changed_text([]) == "none"
    assert document_sections.changed_text([12]) == "1 claim (claim 12)"
    assert document_sections.changed_text([3, 12]) == "2 claims (claims 3, 12)"


def _profile(d: Path, u, u_ref, summary: dict):
    import json

    import numpy as np

    d.mkdir(parents=True, exist_ok=True)
    r = np.linspace(0.5, 24.5, len(u))
    pd.DataFrame({"r_mm": r, "uz_m_s": u, "uz_poiseuille_m_s": u_ref, "nodes": np.round(8 * r)}).to_csv(
        d / "profile.csv", index=False)
    (d / "summary.json").write_text(json.dumps(summary))


def test_abstract_claim13_and_fig10_print_one_particle_free_baseline_and_the_particle_cases_distance(tmp_path):
    import numpy as np

    from lbmpipe.reproduction.profile_error import read_profile_error

    r = np.linspace(0.5, 24.5, 25)
    par = 0.32 * (1 - (r / 25.0) ** 2)
    cases = {"flow_re26": {"reynolds": 26}, claims.PROFILE_CASE: {
        "reynolds": 26, "particles": {"shape": "cylinder", "diameter_mm": 16, "length_mm": 16, "concentration": 0.3}}}
    # the run's own summary holds another (unweighted) distance: the document must not print it
    _profile(tmp_path / "cases" / "flow_re26", par * (1 + 0.02 * (r / 25) ** 4), par,
             {"status": "completed", "profile_error_rel_l2": 0.00123})
    # a case combined over packings: its summary has no distance of its own
    _profile(tmp_path / "cases" / claims.PROFILE_CASE, np.where(r < 20, 0.2, 0.2 * (25 - r) / 5), par,
             {"status": "completed"})
    e0 = read_profile_error(tmp_path / "cases" / "flow_re26" / "profile.csv")
    abstract = literate.abstract_section(tmp_path, "x", {"cases": cases}, None, [], literate._case_dirs(
        tmp_path, {"cases": cases}), [])
    assert abstract["poiseuille"] == f"{document_sections.fmt(e0)} at Re 26"
    row = claims.evaluate_claims(tmp_path, cases).set_index("claim").loc[13]
    assert f"e0 = {e0:.3g}" in row["values"]
    (tmp_path / "tables").mkdir()
    pd.DataFrame([{"case": claims.PROFILE_CASE, "shape": "cylinder", "size_label": "16x16 mm", "concentration": 0.3,
                   "reynolds": 26.0, "collisions": True, "status": "completed",
                   **{f"{q}_{a}": 0.1 for q in ("omega", "ci") for a in "xyz"}}]).to_csv(
        tmp_path / "tables" / "angular_velocity.csv", index=False)
    sec = literate.figure_sections(tmp_path, tmp_path, {"cases": cases}, [], literate._case_dirs(
        tmp_path, {"cases": cases}), [])
    fig10 = next(s for s in sec if s["key"] == "10")["numbers"]
    d = read_profile_error(tmp_path / "cases" / claims.PROFILE_CASE / "profile.csv")
    assert f"`{claims.PROFILE_CASE}`: relative L2 difference from the Hagen-Poiseuille parabola " \
           f"{document_sections.fmt(d)}" in fig10
    assert f"`flow_re26`: relative L2 difference from the Hagen-Poiseuille parabola {document_sections.fmt(e0)}" \
        in fig10


def test_combined_case_summary_carries_its_profiles_distance_from_the_parabola(tmp_path):
    import json

    import numpy as np

    from lbmpipe.reproduction import seeds
    from lbmpipe.reproduction.profile_error import profile_error

    r = np.linspace(0.5, 24.5, 25)
    par = 0.32 * (1 - (r / 25.0) ** 2)
    case = tmp_path / "c"
    for k, scale in ((1, 0.9), (2, 1.1)):
        _profile(case / f"seed{k}", par * scale, par, {"status": "completed"})
        (case / f"seed{k}" / "stats.json").write_text(json.dumps({"status": "completed", "samples": 10}))
    seeds.write_combined("c", case, [1, 2])
    summary = json.loads((case / "summary.json").read_text())
    assert summary["profile_error_rel_l2"] == pytest.approx(profile_error(pd.read_csv(case / "profile.csv")))


def test_run_health_of_a_case_with_an_unstable_packing_says_so_not_completed(tmp_path):
    import json

    from lbmpipe.reproduction import health

    case = tmp_path / "c"
    case.mkdir()
    (case / "stats.json").write_text(json.dumps({
        "status": "completed", "seed_status": {"1": "completed", "2": "completed", "3": "unstable"},
        "seeds": [], "health": {"issues": ["seed 3: status unstable"]}, "flags": ["unhealthy"]}))
    (case / "summary.json").write_text(json.dumps({"status": "unstable", "message": "seed 3: unstable"}))
    row = health.health_row("c", case, health.thresholds()["health"])
    assert row["status"] == "unstable (seed 3: unstable)"


# --------------------------------------------------------------------------------------------------
# issue 48: the document reads as a paper, within its word limits


@pytest.mark.parametrize("level", ["paper", "credible"])
def test_committed_documents_keep_the_main_text_and_the_whole_within_their_word_limits(level):
    """Both committed documents: at most MAIN_WORDS before the first appendix, TOTAL_WORDS in all."""
    md = REPO / "paper" / f"reproduction_{level}.md"
    if not md.is_file():
        pytest.skip(f"{md.name} is not in this checkout")
    text = md.read_text(encoding="utf-8")
    assert (literate.MAIN_WORDS, literate.TOTAL_WORDS) == (4000, 10000)
    main, whole = literate.word_count(literate.main_text(text)), literate.word_count(text)
    assert main <= literate.MAIN_WORDS, f"{md.name}: main text {main} words"
    assert whole <= literate.TOTAL_WORDS, f"{md.name}: {whole} words"
    # and by a plain whitespace count (link targets, table rules and code included), as issue 48 states them
    plain_main, plain = len(literate.main_text(text).split()), len(text.split())
    assert plain_main <= literate.MAIN_WORDS, f"{md.name}: main text {plain_main} whitespace-separated tokens"
    assert plain <= literate.TOTAL_WORDS, f"{md.name}: {plain} whitespace-separated tokens"
    # the abstract gives findings, not only counts: claims by number and the physical results
    abstract = text.split("## Abstract", 1)[1].split("\n## ", 1)[0]
    assert "(#claim-" in abstract and "What we found:" in abstract and "mass correction" in abstract
    # the run-cost model per processor lives in benchmarks/README.md, linked
    assert "## Appendix G" not in text and "benchmarks/README.md#run-cost-per-processor" in text


def test_a_case_that_did_not_complete_is_named_one_way_no_numbers_and_left_out():
    row = {"case": "cube24_c30_re26", "status": "unstable", "omega_x": 0.1, "omega_y": 0.1, "omega_z": 0.1,
           "ci_x": 0.01, "ci_y": 0.01, "ci_z": 0.01}
    assert literate._omega_line(row) is None
    line = literate._not_completed_line(row, {"cube24_c30_re26": {"status": "unstable (seed 3: unstable)"}})
    assert line == "`cube24_c30_re26`: unstable (seed 3: unstable); no bars, and left out of the claims"
    assert "|Ω|" in literate._omega_line({**row, "status": "completed"})


def _tables(fid, av_rows, ori_rows):
    (fid / "tables").mkdir(parents=True)
    pd.DataFrame(av_rows).to_csv(fid / "tables" / "angular_velocity.csv", index=False)
    pd.DataFrame(ori_rows).to_csv(fid / "tables" / "orientation_summary.csv", index=False)


def _av(case, shape, conc, omega, edge=None, d=None, length=None, flags="", status="completed"):
    return {"case": case, "shape": shape, "edge_mm": edge, "diameter_mm": d, "length_mm": length,
            "concentration": conc, "reynolds": 9.4, "collisions": True, "status": status, "n_particles": 4,
            "omega_x": omega, "omega_y": omega, "omega_z": omega, "flags": flags}


def test_claim_lists_link_every_claim_and_shorten_three_or_more_in_a_row_to_a_range():
    assert findings._links(["1", "2", "3", "4", "6", "8", "9", "13"]) == (
        "[1](#claim-1)–[4](#claim-4), [6](#claim-6), [8](#claim-8), [9](#claim-9), [13](#claim-13)")
    assert findings._links(["3", "1"]) == "[1](#claim-1), [3](#claim-3)"
    with pytest.raises(ValueError, match="not claim numbers"):
        findings._links(["1", "3a"])


def test_a_range_of_measured_ratios_prints_both_ends_to_the_same_significant_digits():
    assert findings._range([1.3, 5.18]) == "1.30–5.18"
    assert findings._range([0.0282, 0.078]) == "0.0282–0.0780"
    assert findings._range([39.9, 62.2], " deg") == "39.9–62.2 deg"
    assert findings._range([1.0, 2.0]) == "1–2" and findings._range([0.5, 0.5]) == "0.5"
    assert findings._range([float("nan")]) == "–"


def test_physical_results_are_computed_from_the_tables_cubes_against_cylinders_and_random_orientation(tmp_path):
    fid = tmp_path / "lvl"
    _tables(fid,
            [_av("cube8_c30", "cube", 0.3, 0.5, edge=8), _av("cyl8x8_c30", "cylinder", 0.3, 1.5, d=8, length=8),
             _av("cube8_c50", "cube", 0.5, 0.25, edge=8), _av("cube24_c30", "cube", 0.3, 0.05, edge=24,
                                                               flags="locked;unhealthy")],
            [{"case": "cyl8x8_c30", "kind": "cyl_axis_angle", "status": "completed", "collisions": True,
              "mean_deg": 60.0, "ci95_deg": 5.0},
             {"case": "cube24_c30", "kind": "cube_axis_angle", "status": "completed", "collisions": True,
              "mean_deg": 5.0, "ci95_deg": 1.0}])
    text = " ".join(findings.physical_results(fid))
    assert findings.ISOTROPIC_MEAN_DEG == pytest.approx(57.2958, abs=1e-4)
    assert "do not align" in text and "60 deg over 1 cases" in text and "inside the 95 % interval of 1 of them" in text
    assert "Cubes spin 3 times slower than cylinders of the same size" in text
    assert "by a factor 2" in text
    assert "The 24 mm cubes (4 per pipe) lock: 1 of 1 cases run are flagged locked" in text
    # the opposite ordering reads the other way round, from the same tables
    fid2 = tmp_path / "other"
    _tables(fid2, [_av("cube8_c30", "cube", 0.3, 3.0, edge=8), _av("cyl8x8_c30", "cylinder", 0.3, 1.5, d=8, length=8)],
            [{"case": "cyl8x8_c30", "kind": "cyl_axis_angle", "status": "completed", "collisions": True,
              "mean_deg": 20.0, "ci95_deg": 5.0}])
    text2 = " ".join(findings.physical_results(fid2))
    assert "Cubes spin 2 times faster" in text2 and "lean towards the flow" in text2


def test_a_level_without_controls_says_nothing_about_robustness_in_its_abstract(tmp_path):
    fid = tmp_path / "lvl"
    (fid / "tables").mkdir(parents=True)
    pd.DataFrame({"claim": [1], "statement": ["a."], "verdict": ["reproduced"]}).to_csv(fid / "claims.csv", index=False)
    pd.DataFrame({"claim": [1], "verdict": ["reproduced"], "verdict_with_systematic": ["reproduced"],
                  "robust_under_controls": ["not covered by any control"]}).to_csv(fid / "tables" / "robustness.csv",
                                                                                   index=False)
    assert findings.claim_findings(fid)["robustness"] is None


def test_claim_findings_render_the_robustness_tables_strings_pending_included(tmp_path):
    fid = tmp_path / "lvl"
    (fid / "tables").mkdir(parents=True)
    pd.DataFrame({"claim": [1, 2, 3], "statement": ["a.", "b.", "c."],
                  "verdict": ["reproduced", "contradicted", "reproduced"]}).to_csv(fid / "claims.csv", index=False)
    pd.DataFrame({"claim": [1, 2, 3], "under X": ["reproduced (holds; baseline reproduced)", "not run",
                                                  "inconclusive (changes; baseline reproduced)"],
                  "under Y": ["reproduced (partly run (holds on the runs present); baseline reproduced)",
                              " (partly run (no comparison on the runs present); baseline contradicted)",
                              "inconclusive (partly run (changes on the runs present); baseline reproduced)"],
                  "under Y, packing 1 (interim, 4 cases)": ["reproduced (holds; baseline reproduced)",
                                                            "no comparison",
                                                            "reproduced (changes; baseline inconclusive)"],
                  "robust_under_controls": ["yes", "pending: X not (fully) run", "no: changes under X"]}
                 ).to_csv(fid / "tables" / "robustness.csv", index=False)
    # which columns are interim, and on how many cases, comes from the controls' rows, not the header
    with pytest.raises(FileNotFoundError, match="controls.csv"):
        findings.claim_findings(fid)
    (fid / "robustness").mkdir()
    pd.DataFrame({"claim": [1, 1, 1], "control": ["X", "Y", "Y, packing 1"], "status": ["holds", "partly run", "interim"],
                  "interim_cases": [0, 0, 4]}).to_csv(fid / "robustness" / "controls.csv", index=False)
    f = findings.claim_findings(fid)
    assert f["verdicts"] == "reproduced: claims [1](#claim-1), [3](#claim-3); contradicted: claims [2](#claim-2)"
    assert f["contradicted"] == 'claim 2 ("b")'
    assert f["robustness"]["by_status"] == ("robust (holds under every control): [1](#claim-1); pending (a control "
                                            "not fully run): [2](#claim-2); changed by a control: [3](#claim-3)")
    # a partly run control's differences on its runs present are pending, not changes
    assert f["robustness"]["per_control"] == ("under X claims [1](#claim-1) hold and [3](#claim-3) change; Y partly run: "
                                              "on its runs present claims [1](#claim-1) agree and [3](#claim-3) differ "
                                              "(pending); Y on packing 1 alone (4 cases, interim): claims [1](#claim-1) agree "
                                              "and [3](#claim-3) differ")


def test_the_mass_correction_sizes_say_in_how_many_runs_it_took_mass_out(tmp_path, monkeypatch):
    fid = tmp_path / "lvl"
    (fid / "tables").mkdir(parents=True)
    pd.DataFrame({"case": ["a/seed1", "a/seed2", "b/seed1"], "status": ["completed"] * 3,
                  "mass_floor_rel": [0, 0, 0], "mass_corrected_rel": [0.01, 0.02, 0.6],
                  "mass_corrected_throughflow": [0.001, 0.002, 0.01], "mass_corrected_signed": [-0.01, 0.02, 0.6]}
                 ).to_csv(fid / "tables" / "run_health.csv", index=False)
    config = {"cases": {"a": {"particles": {"concentration": 0.02}}, "b": {"particles": {"concentration": 0.3}}}}
    monkeypatch.setattr(findings, "run_health_figures", lambda run_dir: {"floor_sample_share": 0.0})
    sizes = {c["concentration"]: c for c in findings.correction_sizes(fid, config)}
    assert (sizes["2"]["taken_out"], sizes["2"]["runs"], sizes["30"]["taken_out"]) == (1, 2, 0)
    # a run-health table without the sign is an old one: a loud error, not a count of zero
    pd.read_csv(fid / "tables" / "run_health.csv").drop(columns="mass_corrected_signed").to_csv(
        fid / "tables" / "run_health.csv", index=False)
    with pytest.raises(KeyError):
        findings.correction_sizes(fid, config)


def test_why_reads_the_flags_physically_with_the_worst_value_not_a_list_of_seeds(tmp_path):
    fid = tmp_path / "lvl"
    (fid / "tables").mkdir(parents=True)
    pd.DataFrame({"case": ["a/seed1", "a/seed2", "b/seed1"], "status": ["completed"] * 3,
                  "mass_floor_rel": [0, 0, 0], "mass_corrected_rel": [0.5, 0.6, 0.1],
                  "mass_corrected_throughflow": [0.02, 0.05, 0.001], "density_deviation_max": [0.4, 0.9, 0.1]}
                 ).to_csv(fid / "tables" / "run_health.csv", index=False)
    config = {"cases": {n: {"particles": {"concentration": 0.3}} for n in ("a", "b")}}
    rows = [{"case": "a", "status": "completed", "flags": "unhealthy, not steady"},
            {"case": "b", "status": "completed", "flags": "none"}]
    text = findings.why(["a", "b"], rows, fid, config)
    assert text.startswith("1 of 2 cases are flagged (1 unhealthy, 1 not steady).")
    assert "0.05 of the mass through the pipe (`a/seed2`)" in text and "0.9 (`a/seed2`)" in text
    assert "seed 1:" not in text and findings.UNHEALTHY_EFFECT["rotation"] in text
    assert findings.why(["b"], rows, fid, config) == "None of the 1 cases is flagged by the run-health diagnostics."
    # a case that did not complete is named by its status, as the figure and the claims name it
    rows += [{"case": "c", "status": "unstable (seed 3: unstable)", "flags": "none"},
             {"case": "d", "status": "not run", "flags": "none"}]
    text = findings.why(["a", "c", "d"], rows, fid, config, kind="orientation")
    assert text.endswith("Unstable: `c`; Not run: `d` (left out of the figure's bars and of the claims).")
    assert findings.UNHEALTHY_EFFECT["orientation"] in text


def test_fig3_shows_a_dilute_and_a_dense_case_of_cylinders_and_of_cubes():
    config = {"cases": {
        "flow": {"reynolds": 9.4},
        "cyl16_c30": {"reynolds": 9.4, "particles": {"shape": "cylinder", "diameter_mm": 16, "length_mm": 16,
                                                     "concentration": 0.3}},
        "cyl8_c50_re26": {"reynolds": 26, "particles": {"shape": "cylinder", "diameter_mm": 8, "length_mm": 8,
                                                        "concentration": 0.5}},
        "cyl8_c30": {"reynolds": 9.4, "particles": {"shape": "cylinder", "diameter_mm": 8, "length_mm": 8,
                                                    "concentration": 0.3}},
        "cyl8_c50": {"reynolds": 9.4, "particles": {"shape": "cylinder", "diameter_mm": 8, "length_mm": 8,
                                                    "concentration": 0.5}},
        "cyl8_c30_nocoll": {"reynolds": 9.4, "collisions": False,
                            "particles": {"shape": "cylinder", "diameter_mm": 8, "length_mm": 8, "concentration": 0.1}},
        "cube8_c50": {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 8, "concentration": 0.5}},
        "cube8_c30": {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 8, "concentration": 0.3}}}}
    assert fig3_cases(config) == ["cyl8_c30", "cyl8_c50", "cube8_c30", "cube8_c50"]


def test_claim_appendix_is_one_line_per_claim_linking_the_csv(tmp_path):
    fid = tmp_path / "lvl"
    fid.mkdir()
    pd.DataFrame({"claim": [1, 2], "verdict": ["reproduced", "inconclusive"], "values": ["v1; rest", "v2 (x); y"],
                  "deciding": ["pooled D = 1", None], "carried_by": ["3 of 4 significant", None]}
                 ).to_csv(fid / "claims.csv", index=False)
    lines = findings.claim_lines(fid, "../claims.csv")
    assert lines == ["Claim 1, **reproduced**: pooled D = 1; 3 of 4 significant ([claims.csv](../claims.csv), row 1).",
                     "Claim 2, **inconclusive**: v2 ([claims.csv](../claims.csv), row 2)."]


def test_the_methods_effect_on_rotation_is_the_median_and_range_of_each_controls_measured_shifts(tmp_path):
    (tmp_path / "robustness").mkdir()
    pd.DataFrame({"control": ["Ma/2"] * 5 + ["gap"], "case": ["a", "a", "b", "b", "s", "a"],
                  "observable": ["omega", "omega", "omega", "angle", "omega", "omega"],
                  "shift": [-0.10, -0.30, 0.04, 5.0, -0.8, 0.5],
                  "sensitivity": [False] * 4 + [True, False]}).to_csv(tmp_path / "robustness" / "shifts.csv",
                                                                      index=False)
    text = findings.method_sensitivity(tmp_path)
    # the angle shift (degrees) is not a rotation rate, the sensitivity case s no verdict's case;
    # Ma/2's median of -10, -30, +4 % is -10 %
    assert text.endswith("Ma/2 -10 % (-30 to +4 %, 2 cases); gap +50 % (+50 to +50 %, 1 case).")
    assert findings.method_sensitivity(tmp_path / "none") is None
    # a shifts table that predates the column is an error, not a quiet inclusion
    pd.read_csv(tmp_path / "robustness" / "shifts.csv").drop(columns="sensitivity").to_csv(
        tmp_path / "robustness" / "shifts.csv", index=False)
    with pytest.raises(ValueError, match="sensitivity"):
        findings.method_sensitivity(tmp_path)


def test_provenance_counts_each_levels_commits_names_dirty_runs_and_the_reruns_bit_identity(tmp_path):
    from lbmpipe.reproduction import provenance as P

    config = {"cases": {"flow": {"reynolds": 9.4},
                        "cyl": {"reynolds": 9.4, "particles": {"shape": "cylinder", "diameter_mm": 8,
                                                               "length_mm": 16, "concentration": 0.3}}},
              "fidelities": {"base": {"seeds": 2}}}
    cases = tmp_path / "base" / "cases"
    for run, commit in (("flow", "a1"), ("cyl/seed1", "b2"), ("cyl/seed2", "c3-dirty")):
        (cases / run).mkdir(parents=True)
        (cases / run / "summary.json").write_text(json.dumps({"status": "completed",
                                                              "provenance": {"git_commit": commit}}))
    (tmp_path / "base" / "reruns.csv").write_text(
        "run,old_commit,new_commit,last_frame_identical,force_identical\n"
        "cyl/seed1,x9-dirty,b2,False,False\n")
    text = P.provenance_text(config, ["base"], tmp_path / "base")
    assert "the 3 runs of the levels in this document come from clean commits but 1, made on a tree" in text
    assert "`base` 3." in text
    assert "0 reproduce their first run bit for bit, 1 replace a first run made on a dirty tree" in text
    assert "2 runs are still their first run" in text
    # a run that names no commit is an error naming the file, never a run left out
    (cases / "flow" / "summary.json").write_text(json.dumps({"status": "completed"}))
    with pytest.raises(ValueError, match="flow/summary.json: no git_commit recorded"):
        P.provenance_text(config, ["base"], tmp_path / "base")


def test_the_committed_documents_runs_all_come_from_clean_commits():
    from lbmpipe.reproduction import provenance as P
    from lbmpipe.reproduction.literate import _document_levels

    config = yaml.safe_load((REPO / "config.yaml").read_text())
    text = P.provenance_text(config, _document_levels(config, "credible"), REPO / "results" / "credible")
    assert "come from clean commits;" in text, text
