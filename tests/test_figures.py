"""Figures: every figure is written from the aggregated tables, and a case that is missing or
not packable is marked where its bars would be instead of silently disappearing."""

import json

import numpy as np
import pandas as pd
import pytest

from lbmpipe.reproduction import figures as F
from lbmpipe.reproduction import snapshots as snap
from lbmpipe.reproduction import statistics as S
from lbmpipe.particles.rigid import quat_from_axis_angle

FIG_STEMS = ["fig4_cylinders_re26", "fig5_cubes8_concentration", "fig6_cubes24_reynolds", "fig7a_shape_re9.4",
             "fig7b_shape_re26", "fig8_cylinder_orientation", "fig9_cube_orientation", "fig10_profiles"]


def _texts(fig) -> str:
    """All text drawn in a figure: titles, labels, legends, annotations."""
    out = []
    for t in fig.findobj(match=lambda a: hasattr(a, "get_text")):
        out.append(t.get_text())
    return "\n".join(out)


@pytest.fixture
def captured(monkeypatch):
    """Record the text of every figure passed to ``save``, then save it as usual."""
    seen = {}
    real = F.save

    def spy(fig, stem):
        seen[str(stem).rsplit("/", 1)[-1]] = _texts(fig)
        return real(fig, stem)

    monkeypatch.setattr(F, "save", spy)
    return seen


def _synthetic_tables(fid):
    """Aggregated tables of a small synthetic study: all cases the figures use, except that
    16x24 mm cylinders at Re 26 are missing (not run) and 24 mm cubes at Re 26 are unpackable."""
    rng = np.random.default_rng(0)
    av, orient = [], []
    specs = []
    for re in (9.4, 26.0):
        for d, ln in ((8, 8), (8, 16), (16, 16), (16, 24)):
            specs.append(("cylinder", f"{d}x{ln} mm", d, ln, np.nan, 0.3, re))
        for e in (8, 16, 24):
            specs.append(("cube", f"{e} mm", np.nan, np.nan, e, 0.3, re))
    specs.append(("cube", "8 mm", np.nan, np.nan, 8, 0.5, 9.4))
    for shape, label, d, ln, e, c, re in specs:
        if shape == "cylinder" and label == "16x24 mm" and re == 26.0:
            continue  # not run: absent from every table
        case = f"{shape}{label.replace(' mm', '')}_c{int(c * 100)}_re{re:g}"
        unpackable = shape == "cube" and label == "24 mm" and re == 26.0
        status = "unpackable" if unpackable else "completed"
        w = np.full(3, np.nan) if unpackable else rng.uniform(0.2, 2.0, 3)
        ci = np.full(3, np.nan) if unpackable else 0.1 * w
        av.append({"case": case, "shape": shape, "size_label": label, "diameter_mm": d, "length_mm": ln,
                   "edge_mm": e, "concentration": c, "reynolds": re, "collisions": True, "status": status,
                   "concentration_achieved": 0.28 if unpackable else c, "n_particles": 0 if unpackable else 10,
                   "samples": 0 if unpackable else 50, "omega_x": w[0], "omega_y": w[1], "omega_z": w[2],
                   "ci_x": ci[0], "ci_y": ci[1], "ci_z": ci[2]})
        for kind, hi, nb in S.ORIENTATION_KINDS[shape]:
            edges = np.linspace(0, hi, nb + 1)
            f = np.full(nb, np.nan) if unpackable else rng.dirichlet(np.ones(nb))
            for k in range(nb):
                orient.append({"case": case, "shape": shape, "size_label": label, "concentration": c, "reynolds": re,
                               "collisions": True, "status": status, "kind": kind, "bin_lo_deg": edges[k],
                               "bin_hi_deg": edges[k + 1], "fraction": f[k], "ci95": 0.02 if not unpackable else np.nan})
    (fid / "tables").mkdir(parents=True)
    pd.DataFrame(av).to_csv(fid / "tables" / "angular_velocity.csv", index=False)
    pd.DataFrame(orient).to_csv(fid / "tables" / "orientation.csv", index=False)
    r = np.linspace(0.5, 24.5, 13)
    for case, u in (("flow_re26", 0.32 * (1 - (r / 25) ** 2)), ("cylinder16x16_c30_re26", 0.2 + 0 * r)):
        (fid / "cases" / case).mkdir(parents=True)
        pd.DataFrame({"r_mm": r, "uz_m_s": u, "uz_poiseuille_m_s": 0.32 * (1 - (r / 25) ** 2),
                      "nodes": 8}).to_csv(fid / "cases" / case / "profile.csv", index=False)


def test_make_figures_writes_every_figure_and_marks_missing_and_unpackable_cases(tmp_path, captured):
    fid = tmp_path / "smoke"
    _synthetic_tables(fid)
    paths = F.make_figures(fid, "smoke")
    names = {p.name for p in paths}
    for stem in FIG_STEMS:
        for ext in ("pdf", "png"):
            assert f"{stem}.{ext}" in names
            assert (fid / "figures" / f"{stem}.{ext}").stat().st_size > 1000
    assert "not run" in captured["fig4_cylinders_re26"]  # 16x24 at Re 26 absent from the table
    assert "not packable" in captured["fig6_cubes24_reynolds"]  # 24 mm cubes at Re 26
    assert "not packable" in captured["fig7b_shape_re26"] and "not in study" in captured["fig7b_shape_re26"]
    assert "not run" in captured["fig8_cylinder_orientation"]
    assert "not packable" in captured["fig9_cube_orientation"]
    assert "not packable" not in captured["fig5_cubes8_concentration"]
    for stem in FIG_STEMS:
        assert "smoke" in captured[stem]  # the fidelity level is named
    assert "rad/s" in captured["fig4_cylinders_re26"] and "(deg" in captured["fig8_cylinder_orientation"]
    assert "m/s" in captured["fig10_profiles"] and "(mm)" in captured["fig10_profiles"]
    assert set(FIG_STEMS) <= set(F.FIGURE_CAPTIONS)


def test_make_figures_without_any_table_still_draws_every_figure_marked_not_run(tmp_path, captured):
    paths = F.make_figures(tmp_path / "empty", "quick")
    assert len(paths) == 2 * len(FIG_STEMS)
    for stem in FIG_STEMS:
        assert "not run" in captured[stem], stem


def test_velocity_profiles_keeps_its_signature_and_draws_each_parabola(tmp_path, captured):
    r = np.linspace(0.5, 24.5, 5)
    p = tmp_path / "profile.csv"
    pd.DataFrame({"r_mm": r, "uz_m_s": 1 - (r / 25) ** 2, "uz_poiseuille_m_s": 1 - (r / 25) ** 2,
                  "nodes": 4}).to_csv(p, index=False)
    out = F.velocity_profiles({"flow_re9.4": p}, tmp_path / "fig10_profiles", title="t")
    assert [q.name for q in out] == ["fig10_profiles.pdf", "fig10_profiles.png"]
    assert "flow_re9.4: Hagen-Poiseuille" in captured["fig10_profiles"]


def _snapshot_case(case_dir, shape, n, status="completed"):
    case_dir.mkdir(parents=True)
    rows = []
    for t in (0.0, 0.1):
        for i in range(n if status == "completed" else 0):
            q = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), 0.3 * i)
            rows.append({"t_s": t, "id": i, "x_mm": 10.0 * np.cos(i), "y_mm": 10.0 * np.sin(i), "z_mm": 20.0 * i + 10,
                         "qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3]})
    pd.DataFrame(rows, columns=["t_s", "id", "x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz"]).to_parquet(
        case_dir / "particles.parquet", index=False)
    st = pd.DataFrame({"id": np.arange(n), "shape": shape, "diameter_mm": 8.0 if shape == "cylinder" else np.nan,
                       "length_mm": 16.0 if shape == "cylinder" else np.nan,
                       "edge_mm": 8.0 if shape == "cube" else np.nan, "density_kg_m3": 1000.0, "fixed": False})
    st.to_csv(case_dir / "particles_static.csv", index=False)
    (case_dir / "summary.json").write_text(json.dumps({"status": status}))


def test_snapshots_draw_one_png_per_particle_case_including_unpackable(tmp_path):
    fid = tmp_path / "smoke"
    _snapshot_case(fid / "cases" / "cyl_re9.4", "cylinder", 4)
    _snapshot_case(fid / "cases" / "cube", "cube", 3)
    _snapshot_case(fid / "cases" / "cube_hc", "cube", 3, status="unpackable")
    cases = {"flow_re26": {"reynolds": 26},
             "cyl_re9.4": {"reynolds": 9.4, "particles": {"shape": "cylinder", "diameter_mm": 8, "length_mm": 16,
                                                          "concentration": 0.3}},
             "cube": {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 8, "concentration": 0.3}},
             "cube_hc": {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 8, "concentration": 0.5}}}
    out = snap.snapshots(fid, cases)
    assert [p.name for p in out] == ["fig3_cyl_re9.4.png", "fig3_cube.png", "fig3_cube_hc.png"]
    assert all(p.stat().st_size > 1000 for p in out)


@pytest.mark.parametrize("shape", ["cylinder", "cube"])
def test_snapshot_has_few_ticks_on_the_short_axes_and_the_colour_bar_beside_the_pipe(tmp_path, shape):
    import matplotlib.pyplot as plt

    _snapshot_case(tmp_path / "case", shape, 5)
    fig = snap.snapshot_figure(tmp_path / "case", title="case")
    ax, cax = fig.axes[0], fig.axes[-1]
    renderer = fig.canvas.get_renderer()
    fig.canvas.draw()
    # the x and y axes are foreshortened to a fifth of the pipe's height: five labels there
    # collided, three fit (mplot3d does not report where it draws tick labels, so count them)
    shown = {axis.axis_name: [t.get_text() for t in axis.get_ticklabels() if t.get_visible() and t.get_text()]
             for axis in (ax.xaxis, ax.yaxis, ax.zaxis)}
    assert 2 <= len(shown["x"]) <= 3 and 2 <= len(shown["y"]) <= 3 and len(shown["z"]) >= 3, shown
    # no empty band: the colour bar starts within 8 % of the figure width of the z axis's label
    z_right = ax.zaxis.get_tightbbox(renderer).x1 / fig.bbox.width
    bar_left = cax.get_window_extent(renderer).x0 / fig.bbox.width
    assert cax is not ax and 0.0 < bar_left - z_right < 0.08
    plt.close(fig)


def test_cylinder_mesh_is_closed_around_its_axis_and_cube_faces_lie_on_the_cube():
    side, caps = snap._cylinder_faces(8.0, 16.0, n=12)
    assert side.shape == (12, 4, 3) and caps.shape == (2, 12, 3)
    np.testing.assert_allclose(np.hypot(side[..., 0], side[..., 1]), 4.0)
    np.testing.assert_allclose(np.abs(side[..., 2]), 8.0)
    (cube,) = snap._cube_faces(8.0)
    assert cube.shape == (6, 4, 3)
    # each face has one coordinate pinned at +-4 and spans the other two
    assert np.all(np.sum(np.isclose(np.abs(cube), 4.0), axis=2) == 3)
    np.testing.assert_allclose(np.sort(cube.reshape(-1, 3).max(axis=0)), [4.0, 4.0, 4.0])


# ------------------------------------------------------------------------------------------------
# isotropic reference, flagged cases, the layout of Fig. 9

@pytest.mark.parametrize("kind", ["cyl_axis_angle", "cube_axis_angle", "cube_projected_angle"])
def test_isotropic_bin_fractions_equal_those_of_random_orientations_through_the_angle_definitions(kind):
    # Haar-uniform rotations: normalised 4-D Gaussian quaternions, through the same angle code as the runs
    n = 200_000
    q = np.random.default_rng(7).normal(size=(n, 4))
    hi = {k: h for kinds in S.ORIENTATION_KINDS.values() for k, h, _ in kinds}[kind]
    edges = np.linspace(0.0, hi, 10)
    ref = S.isotropic_bin_fractions(kind, edges)
    counts = np.histogram(S.orientation_angles(kind, q), edges)[0] / n
    assert ref.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.abs(counts - ref) < 5.0 * np.sqrt(ref * (1 - ref) / n)), (counts, ref)


def test_nearest_cube_axis_reference_is_continuous_where_the_cells_start_to_bound_it():
    eps = 1e-7
    lo, hi = S.isotropic_cdf("cube_axis_angle", [45.0 - eps, 45.0 + eps])
    assert hi - lo < 1e-6
    assert S.isotropic_cdf("cube_axis_angle", S.CUBE_MAX_AXIS_ANGLE_DEG) == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.diff(S.isotropic_cdf("cube_axis_angle", np.linspace(0, 55, 200))) >= 0)


@pytest.fixture
def drawn(monkeypatch):
    """Per saved figure: the y-values of its dashed reference segments per axes, the y-limits per
    axes, whether any bar is hatched, and all its text."""
    seen = {}
    real = F.save

    def spy(fig, stem):
        from matplotlib.collections import LineCollection
        from matplotlib.patches import Rectangle

        refs, ylims, hatched = [], [], False
        for ax in fig.axes:
            segs = [c.get_segments() for c in ax.collections if isinstance(c, LineCollection)
                    and "isotropic" in str(c.get_label())]
            refs.append([s[0][1] for seg in segs for s in seg])
            ylims.append(ax.get_ylim())
            hatched |= any(p.get_hatch() for p in ax.patches if isinstance(p, Rectangle))
        seen[str(stem).rsplit("/", 1)[-1]] = {"refs": refs, "ylims": ylims, "hatched": hatched,
                                              "text": _texts(fig)}
        return real(fig, stem)

    monkeypatch.setattr(F, "save", spy)
    return seen


def test_orientation_figures_draw_the_isotropic_fraction_of_each_plotted_bin(tmp_path, drawn):
    fid = tmp_path / "smoke"
    _synthetic_tables(fid)
    F.make_figures(fid, "smoke")
    cyl = S.isotropic_bin_fractions("cyl_axis_angle", np.linspace(0, 90, 10))
    for refs in drawn["fig8_cylinder_orientation"]["refs"]:
        assert np.allclose(refs, cyl)
    cube = {len(r) and round(r[0], 6) for r in drawn["fig9_cube_orientation"]["refs"]}
    projected = S.isotropic_bin_fractions("cube_projected_angle", np.linspace(0, 45, 10))
    axis = S.isotropic_bin_fractions("cube_axis_angle", np.linspace(0, S.CUBE_MAX_AXIS_ANGLE_DEG, 10))
    assert np.allclose(projected, 1 / 9)
    assert cube == {round(projected[0], 6), round(axis[0], 6)}
    # one legend entry for the isotropic reference of both angles (a legend entry is a Text in a TextArea)
    assert drawn["fig9_cube_orientation"]["text"].count("isotropic") == 2


def test_fig9_intervals_of_a_fraction_lie_in_0_1_and_an_empty_bin_of_a_locked_case_keeps_a_width(tmp_path, drawn):
    # a case locked in two bins across its packings: 0.53 +- 1.62 and 0.47 +- 1.6, empty bins +- 0
    frac = np.array([0.533, 0.467] + [0.0] * 7)
    ci = np.array([1.62, 1.60] + [0.0] * 7)
    err = F._fraction_errors(frac, ci)
    lo, hi = frac - err[0], frac + err[1]
    assert (lo >= 0).all() and (hi <= 1).all()
    assert (hi[2:] > 0.3).all()  # an empty bin of a case with almost no independent samples: wide, not zero
    # a well-measured histogram keeps intervals close to its own half-widths
    frac = np.full(9, 1 / 9)
    err = F._fraction_errors(frac, np.full(9, 0.01))
    assert np.allclose(err, 0.01, rtol=0.05)
    fid = tmp_path / "smoke"
    _synthetic_tables(fid)
    t = pd.read_csv(fid / "tables" / "orientation.csv")
    locked = (t["size_label"] == "24 mm") & (t["reynolds"] == 9.4)
    t.loc[locked, "fraction"] = np.where(t.loc[locked, "bin_lo_deg"] == 0.0, 1.0, 0.0)
    t.loc[locked, "ci95"] = np.where(t.loc[locked, "bin_lo_deg"] == 0.0, 1.5, 0.0)
    F.cube_orientation(t, fid / "figures" / "fig9_cube_orientation")
    assert all(y[1] <= 1.15 + 1e-9 for y in drawn["fig9_cube_orientation"]["ylims"])
    assert "Wilson" in drawn["fig9_cube_orientation"]["text"]


def test_a_cube_case_locked_in_one_bin_does_not_flatten_the_other_sizes_in_fig9(tmp_path, drawn):
    fid = tmp_path / "smoke"
    _synthetic_tables(fid)
    t = pd.read_csv(fid / "tables" / "orientation.csv")
    locked = (t["size_label"] == "24 mm") & (t["reynolds"] == 9.4)
    t.loc[locked, "fraction"] = np.where(t.loc[locked, "bin_lo_deg"] == 0.0, 1.0, 0.0)
    F.cube_orientation(t, fid / "figures" / "fig9_cube_orientation")
    ylims = drawn["fig9_cube_orientation"]["ylims"][:12]  # 3 sizes x 4 panels, then nothing else
    tops = np.array([y[1] for y in ylims]).reshape(3, 4)
    assert tops[2].min() >= 1.0  # the locked 24 mm row shows its bar whole
    assert tops[0].max() < 0.6 and tops[1].max() < 0.6  # the 8 and 16 mm rows keep their own scale


def test_flagged_cases_from_tables_or_stats_are_hatched_and_named_in_every_figure_showing_them(tmp_path, drawn):
    fid = tmp_path / "smoke"
    _synthetic_tables(fid)
    pd.DataFrame({"case": ["cylinder16x16_c30_re26"], "flags": ["unhealthy"]}).to_csv(
        fid / "tables" / "health.csv", index=False)
    (fid / "cases" / "cube24_c30_re9.4").mkdir(parents=True)
    (fid / "cases" / "cube24_c30_re9.4" / "stats.json").write_text(json.dumps({"flags": {"locked": True}}))
    assert F.read_case_flags(fid) == {"cylinder16x16_c30_re26": ["unhealthy"], "cube24_c30_re9.4": ["locked"]}
    F.make_figures(fid, "smoke")
    for stem in ("fig4_cylinders_re26", "fig7b_shape_re26", "fig8_cylinder_orientation", "fig10_profiles"):
        assert "unhealthy" in drawn[stem]["text"], stem
    for stem in ("fig6_cubes24_reynolds", "fig7a_shape_re9.4", "fig9_cube_orientation"):
        assert "locked" in drawn[stem]["text"] and drawn[stem]["hatched"], stem
    for stem in ("fig5_cubes8_concentration",):
        assert "flagged" not in drawn[stem]["text"] and not drawn[stem]["hatched"]


def test_case_flags_read_a_flags_column_and_true_flag_columns():
    row = pd.Series({"case": "c", "flags": "frozen; locked", "flag_unhealthy": True, "flag_jammed": False})
    assert F.case_flags(row) == ["frozen", "locked", "unhealthy"]
    assert F.case_flags(pd.Series({"case": "c", "flags": np.nan})) == []


def test_report_captions_are_the_figure_captions_and_say_the_experimental_data_are_not_drawn():
    from pathlib import Path

    report = Path(__file__).resolve().parents[1] / "workflow" / "report"
    for stem in FIG_STEMS:  # Figs. 4-10 (the pipeline's figures rule)
        # the report's reStructuredText escapes |Omega| (a substitution reference otherwise)
        rst = (report / f"{stem}.rst").read_text(encoding="utf-8").strip()
        assert rst.replace("\\|", "|") == F.FIGURE_CAPTIONS[stem], stem
    for stem in ("fig4_cylinders_re26", "fig8_cylinder_orientation", "fig9_cube_orientation"):
        assert "Zitoun et al. 2001" in F.FIGURE_CAPTIONS[stem] and "not drawn" in F.FIGURE_CAPTIONS[stem]


def test_snapshot_gallery_tiles_the_snapshots_present_and_writes_nothing_without_any(tmp_path):
    figs = tmp_path / "figures"
    figs.mkdir()
    for case in ("a", "b", "c"):
        F.plt.imsave(figs / f"fig3_{case}.png", np.full((20, 10, 3), 0.5))
    out = snap.snapshot_gallery(tmp_path, ["a", "missing", "b", "c"], ncols=2)
    assert out == figs / "fig3_gallery.png" and out.is_file()
    assert snap.snapshot_gallery(tmp_path, ["missing"], tmp_path / "none.png") is None
    assert not (tmp_path / "none.png").exists()
