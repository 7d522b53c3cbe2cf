"""Plots a reader has to be able to read: titled, one colour per series that matters, labels and
legends inside the figure and off the data, units on every axis, classes shown as classes."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pytest

from vmehil.analysis.report import HEATMAP_METRICS, IN_BAND_LABEL, bode_figure, sweep_heatmaps
from vmehil.analysis.tuning import margins_summary
from vmehil.commands.calibrate import pot_residuals_figure


def _pot_joints(n: int) -> dict:
    ver = [{"angle_deg": a, "before_arcmin": 40.0 + a / 10, "residual_arcmin": 1.0 + a / 100} for a in (-90, 0, 90)]
    return {f"j{k + 1}": {"verification": ver} for k in range(n)}


def test_pot_residuals_has_a_title_one_colour_per_joint_and_legends_off_the_axes() -> None:
    fig = pot_residuals_figure(_pot_joints(7), "jpl-arm (seed 0)")
    assert "Pot calibration" in fig._suptitle.get_text()
    fig.canvas.draw()
    for ax in fig.axes:
        colours = [line.get_color() for line in ax.get_lines()]
        assert len(colours) == 7 and len(set(colours)) == 7  # j1 and j6 no longer share blue
        legend = ax.get_legend()
        assert legend is not None
        box, axes_box = legend.get_window_extent(), ax.get_window_extent()
        assert box.x0 >= axes_box.x1  # beside the axes, covering no data
        assert ax.get_ylabel().endswith("(arcmin)") and ax.get_title()
    # the same joint has the same colour before and after
    before, after = fig.axes
    assert [x.get_color() for x in before.get_lines()] == [x.get_color() for x in after.get_lines()]
    plt.close(fig)


def test_bode_gain_margin_labels_are_inside_the_magnitude_axes() -> None:
    from emulators.presets import resolve_rig
    from vmehil.analysis.rigparams import load_joint

    cfg = load_joint(resolve_rig("jpl-arm"), 1).cfg  # what `vmehil tune bode` draws: both have a GM
    fig = bode_figure(cfg, margins_summary(cfg))
    mag = fig.axes[0]
    fig.canvas.draw()
    labels = [t for t in mag.texts if t.get_text().startswith("GM")]
    assert len(labels) == 2
    axes_box = mag.get_window_extent()
    for t in labels:
        box = t.get_window_extent()
        assert axes_box.y0 <= box.y0 and box.y1 <= axes_box.y1, t.get_text()
        assert axes_box.x0 <= box.x0 and box.x1 <= axes_box.x1, t.get_text()
    plt.close(fig)


def test_run_report_axes_all_carry_units(tmp_path, monkeypatch) -> None:
    from vmehil.cli import main
    from vmehil.reports import run_report

    labels: list[str] = []

    def keep_labels(fig, path, *args, **kw):
        labels.extend(a.get_ylabel() for a in fig.axes)
        return []

    monkeypatch.setattr(run_report, "save_figure", keep_labels)
    assert main(["run", "--duration", "0.4", "--quiet", "--report", str(tmp_path)]) in (0, 1)
    assert "Kp effective (s⁻²)" in labels
    unitless = [lab for lab in labels if lab and "(" not in lab and lab != "integrators"]
    assert not unitless, unitless


@pytest.mark.parametrize("settle,label", [(0.0, IN_BAND_LABEL), (0.008, "0.008"), (None, "—")])
def test_settling_map_shows_in_band_from_start_as_its_own_class(settle, label) -> None:
    rows = [{"kp": 100.0, "kvi": 1000.0, "stable": True, "sampled_stable": True, "phase_margin_deg": 40.0,
             "lc_amplitude_deg": 0.5, "rms_tracking_error_deg": 0.1, "settling_time_s": settle},
            {"kp": 120.0, "kvi": 1000.0, "stable": True, "sampled_stable": True, "phase_margin_deg": 40.0,
             "lc_amplitude_deg": 0.5, "rms_tracking_error_deg": 0.1, "settling_time_s": 0.5}]
    fig = sweep_heatmaps(rows, "kp", "kvi", "t")
    axes = dict(zip((k for k, _, _ in HEATMAP_METRICS), fig.axes, strict=False))
    cells = {round(t.get_position()[0]): t.get_text() for t in axes["settling_time_s"].texts}
    assert cells == {0: label, 1: "0.5"}
    # the other maps never use the settling class
    assert all(IN_BAND_LABEL not in t.get_text() for k, a in axes.items() if k != "settling_time_s" for t in a.texts)
    plt.close(fig)


def test_a_metric_with_no_value_anywhere_says_why_and_draws_no_colour_bar() -> None:
    # no point had a cycle: the map showed a −0.1…+0.1 colour bar and grey cells nobody explained
    rows = [{"kp": kp, "kvi": 1000.0, "stable": True, "sampled_stable": True, "phase_margin_deg": 40.0,
             "lc_amplitude_deg": None, "rms_tracking_error_deg": 0.1, "settling_time_s": 0.5} for kp in (100.0, 120.0)]
    fig = sweep_heatmaps(rows, "kp", "kvi", "t")
    axes = dict(zip((k for k, _, _ in HEATMAP_METRICS), fig.axes, strict=False))
    assert len(fig.axes) == 4 + 3  # four maps, a colour bar for the three with values
    lc = axes["lc_amplitude_deg"]
    assert any("no point has a value here" in t.get_text() and "no limit cycle" in t.get_text() for t in lc.texts)
    assert lc.get_title().endswith("grey —: no limit cycle")
    assert "grey" not in axes["phase_margin_deg"].get_title()  # every cell has a value there
    plt.close(fig)


def test_bode_phase_margin_labels_sit_on_no_arrow() -> None:
    from emulators.presets import resolve_rig
    from vmehil.analysis.rigparams import load_joint

    cfg = load_joint(resolve_rig("jpl-arm"), 1).cfg  # crossovers 6.7 and 7.2 Hz: the two arrows side by side
    fig = bode_figure(cfg, margins_summary(cfg))
    phase = fig.axes[1]
    fig.canvas.draw()
    labels = [t for t in phase.texts if t.get_text().startswith("PM")]
    arrows_x = [phase.transData.transform((a.xy[0], -180.0))[0] for a in phase.texts if not a.get_text()]
    assert len(labels) == 2 and len(arrows_x) == 2
    for t in labels:
        box = t.get_window_extent()
        assert not any(box.x0 - 1 <= x <= box.x1 + 1 for x in arrows_x), t.get_text()
    plt.close(fig)


@pytest.mark.slow  # the describing-function prediction of `tune limit-cycle --predict-only` (≈ 3 s of CPU)
def test_nyquist_frequency_labels_do_not_overlap(tmp_path, monkeypatch) -> None:
    # the fixed 1, 3 and 10 Hz labels sat in a heap at the origin of df_nyquist.png
    from vmehil.analysis import report
    from vmehil.cli import main

    figures: dict = {}

    def keep(fig, directory, stem):
        figures[stem] = fig
        return []

    monkeypatch.setattr(report, "save_figure_both", keep)
    assert main(["tune", "limit-cycle", "--predict-only", "--report", str(tmp_path)]) == 0
    fig = figures["df_nyquist"]
    fig.canvas.draw()
    ax = fig.axes[0]
    boxes = [t.get_window_extent() for t in ax.texts if t.get_text().endswith(" Hz")]
    assert len(boxes) >= 2
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            assert not a.overlaps(b)
    for f in figures.values():
        plt.close(f)
