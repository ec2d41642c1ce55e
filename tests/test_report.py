"""The gap report: reproducible numbers that match the metrics, safe self-contained HTML, atomic files."""

from __future__ import annotations

import base64
import dataclasses
import io
import json
import re
import warnings
from html.parser import HTMLParser
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import PIL.Image
import pytest
from scipy import stats

import sim2real as s2r
import sim2real.report.files as report_files
from sim2real import metrics
from sim2real.agents import ReachController
from sim2real.evaluation import Evaluation, evaluate, grid, measured, nominal, randomized, real, sweep
from sim2real.report import GapReport, stream
from sysid.result import FitResult

EVIL = "<script>alert(1)</script>"
HIDDEN_ADDRESS = "body_mass[upper_arm]"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def robot_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    # unequal counts (5 vs 3) and a policy the robot never ran
    path = tmp_path_factory.mktemp("csv") / "robot.csv"
    rows = ["policy,return,success"]
    rows += [f"reach,{-9.0 - 0.3 * i},{int(i % 2)}" for i in range(5)]
    rows += [f"slow,{-10.0 - 0.2 * i},0" for i in range(3)]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.fixture(scope="module")
def evaluation(robot_csv: Path) -> Evaluation:
    conditions = [
        nominal(),
        randomized([s2r.Damping(scale=s2r.Uniform(0.5, 2.0))]),
        real([s2r.Damping(scale=1.5)], params={HIDDEN_ADDRESS: 2.345}),
        *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [0.5, 1.0, 1.5]),
        *grid(
            {"effect": {"type": "Damping", "scale": 1.0}, "field": "scale", "values": [0.5, 2.0]},
            {"effect": {"type": "ActuatorGain", "scale": 1.0}, "field": "scale", "values": [0.5, 1.0]},
        ),
        measured(robot_csv, name="robot"),
    ]
    policies = {"reach": ReachController(), "slow": ReachController(kp=0.3), EVIL: ReachController(kp=0.6)}
    return evaluate(policies, "sim2real/arm-reach", conditions, episodes=4, seed=0, max_steps=20)


@pytest.fixture(scope="module")
def report(evaluation: Evaluation) -> GapReport:
    return GapReport.build(evaluation, rng=0, title="Study <b>&", notes=("note with <i>tags</i>",))


@pytest.fixture(scope="module")
def positive() -> Evaluation:
    """Synthetic positive returns (radii are defined) with paired rows, 12 runs, built without an env."""
    conditions = (
        nominal(),
        real(params={HIDDEN_ADDRESS: 2.0}),
        *sweep({"type": "Damping", "scale": 1.0}, "scale", [0.5, 1.0, 2.0, 3.0]),
    )
    rng = np.random.default_rng(7)
    base = rng.normal(100.0, 5.0, 12)
    returns = {}
    for k, policy in enumerate(("a", "b", "c")):
        shift = 10.0 * k
        returns[policy] = {
            "sim": base + shift,
            "real": base + shift - 15.0 + rng.normal(0.0, 2.0, 12),
            "Damping.scale=0.5": base + shift - 5.0,
            "Damping.scale=1": base + shift,
            "Damping.scale=2": base + shift - 10.0 - 5.0 * k,
            "Damping.scale=3": base + shift - 60.0,
        }
    return Evaluation(
        task="synthetic",
        seed=3,
        episodes=12,
        max_steps=None,
        policies=("a", "b", "c"),
        conditions=conditions,
        returns=returns,
        successes={},
        lengths={},
        draws={},
    )


class _Checker(HTMLParser):
    VOID: ClassVar[set[str]] = {
        "area",
        "base",
        "br",
        "col",
        "embed",
        "hr",
        "img",
        "input",
        "link",
        "meta",
        "source",
        "track",
        "wbr",
    }

    def __init__(self) -> None:
        super().__init__()
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.images: list[dict[str, str | None]] = []
        self.tags: set[str] = set()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.add(tag)
        if tag == "img":
            self.images.append(dict(attrs))
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag: str) -> None:
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1:]}")
        else:
            self.stack.pop()


# ----------------------------------------------------------------------------------------------- numbers


def test_json_is_bitwise_reproducible_and_rng_moves_intervals(evaluation: Evaluation, report: GapReport) -> None:
    again = GapReport.build(evaluation, rng=0, title="Study <b>&", notes=("note with <i>tags</i>",))
    assert again.to_json() == report.to_json()
    assert again == report
    json.loads(report.to_json())  # strict JSON (no NaN)
    other = GapReport.build(evaluation, rng=1, title="Study <b>&", notes=("note with <i>tags</i>",))
    g0, g1 = report.gap("reach"), other.gap("reach")
    assert g0.absolute.value == g1.absolute.value and g0.absolute.low != g1.absolute.low
    # a Generator is drawn from once; the seed it gave replays the report
    first = GapReport.build(evaluation, rng=np.random.default_rng(5))
    assert first.to_json() == GapReport.build(evaluation, rng=np.random.default_rng(5)).to_json()
    assert GapReport.build(evaluation, rng=first.rng_seed).to_json() == first.to_json()


def test_values_match_direct_metric_calls(evaluation: Evaluation, report: GapReport) -> None:
    data = json.loads(report.to_json())
    options: dict[str, Any] = {"confidence": 0.95, "num_resamples": 2000}
    sim, target = evaluation.returns["reach"]["sim"], evaluation.returns["reach"]["real"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", metrics.FewSamplesWarning)
        direct = metrics.gap(
            np.column_stack([sim, target]), paired=True, rng=stream(0, "gap", "reach", "sim", "real"), **options
        )
        (mean,) = metrics.mean(sim[:, None], rng=stream(0, "mean", "reach", "sim"), **options)
        (rate,) = metrics.success_rate(evaluation.successes["reach"]["sim"][:, None].astype(float))
    (entry,) = [g for g in data["gaps"] if g["policy"] == "reach" and g["reference"] == "sim"]
    assert entry["paired"] is True and entry["target"] == "real"
    assert entry["absolute"] == dataclasses.asdict(direct.absolute)
    assert entry["relative"] == dataclasses.asdict(direct.relative)
    (stat,) = [s for s in data["stats"] if s["policy"] == "reach" and s["condition"] == "sim"]
    assert stat["mean"] == dataclasses.asdict(mean)
    assert stat["success"] == dataclasses.asdict(rate)
    assert stat["worst"] == float(sim.min())
    assert report.stats_for("reach", "sim").mean == mean


def test_few_samples_warnings_are_collected_not_lost(evaluation: Evaluation) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        built = GapReport.build(evaluation, rng=0)
    assert not [w for w in caught if issubclass(w.category, metrics.FewSamplesWarning)]
    assert any(w.startswith("FewSamplesWarning: gap: 4 runs") for w in built.warnings)
    assert "Warnings" in built.to_markdown()


def test_measured_target_with_unequal_counts(evaluation: Evaluation) -> None:
    built = GapReport.build(evaluation, target="robot", rng=0)
    g = built.gap("reach", "sim", "robot")
    assert (g.paired, g.n_reference, g.n_target) == (False, 4, 5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", metrics.FewSamplesWarning)
        direct = metrics.unpaired_gap(
            evaluation.returns["reach"]["sim"],
            evaluation.returns["reach"]["robot"],
            rng=stream(0, "gap", "reach", "sim", "robot"),
        )
    assert g.absolute == direct.absolute and g.relative == direct.relative
    assert built.gap("slow", "randomized", "robot").n_target == 3
    with pytest.raises(KeyError, match="no gap for policy"):
        built.gap(EVIL, "sim", "robot")  # the robot never ran it
    assert any(EVIL in note and "robot" in note for note in built.skipped)
    # agreement needs >= 3 policies on both conditions
    assert all(a.srcc is None and ">= 3 policies" in a.note for a in built.agreement)
    assert [(i.x, i.y) for i in built.improvements] == [("reach", "slow")]
    assert built.stats_for("reach", "robot").success is not None


def test_unpaired_gap_extends_gap_to_unequal_counts() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(10.0, 1.0, (15, 2))
    a = metrics.gap(x, paired=False, rng=3, num_resamples=1000)
    b = metrics.unpaired_gap(x[:, 0], x[:, 1], rng=3, num_resamples=1000)
    assert a == b  # bitwise, same draws in the same order
    c = metrics.unpaired_gap(x[:, 0], x[:12, 1] - 2.0, statistic="iqm", rng=3, num_resamples=1000)
    assert (c.paired, c.absolute.n, c.statistic) == (False, 27, "iqm")
    assert c.absolute.low < c.absolute.value < c.absolute.high
    with pytest.raises(ValueError, match=r"`target` must be a 1-D array of runs.*Received shape \(2, 2\)"):
        metrics.unpaired_gap([1.0, 2.0], [[1.0, 2.0], [3.0, 4.0]], rng=0)
    with pytest.warns(metrics.FewSamplesWarning, match="gap: 3 runs"):
        metrics.unpaired_gap(np.arange(20.0), [1.0, 2.0, 3.0], rng=0, num_resamples=1000)


def test_robustness_radius_and_agreement_match_metrics(positive: Evaluation) -> None:
    built = GapReport.build(positive, rng=2, fraction=0.8, num_resamples=1000)
    names = [c.name for c in positive.conditions if c.kind == "sweep"]
    options: dict[str, Any] = {"confidence": 0.95, "num_resamples": 1000}
    for policy in positive.policies:
        curve = built.curve(policy, "Damping.scale")
        direct = metrics.robustness_radius(
            [0.5, 1.0, 2.0, 3.0],
            positive.table(policy, names),
            nominal=1.0,
            fraction=0.8,
            paired=True,
            rng=stream(2, "radius", policy, "Damping.scale"),
            **options,
        )
        assert curve.radius == direct and curve.note == ""
        assert curve.threshold == pytest.approx(0.8 * direct.nominal_return)
        assert curve.values == (0.5, 1.0, 2.0, 3.0) and len(curve.points) == 4
    sims = np.column_stack([positive.returns[p]["sim"] for p in positive.policies])
    reals = np.column_stack([positive.returns[p]["real"] for p in positive.policies])
    (agreement,) = built.agreement
    assert agreement.srcc == metrics.srcc(sims, reals, rng=stream(2, "srcc", "sim", "real"), **options)
    assert agreement.mmrv == metrics.mmrv(sims, reals, rng=stream(2, "mmrv", "sim", "real"), **options)
    assert [(i.x, i.y) for i in built.improvements] == [("a", "b"), ("a", "c"), ("b", "c")]
    assert built.randomized is None and any("no randomized condition" in s for s in built.skipped)
    assert "robustness_damping-scale" in built.figure_names()


def test_non_positive_nominal_return_skips_the_radius_with_a_note(report: GapReport) -> None:
    curve = report.curve("reach", "ActuatorGain.scale")
    assert curve.radius is None and "not positive" in curve.note
    assert len(curve.points) == 3
    assert any("no robustness radius of 'reach'" in s for s in report.skipped)
    heat = [g for g in report.grids if g.policy == "reach"]
    assert len(heat) == 1 and heat[0].x == (0.5, 1.0, 2.0) and heat[0].y == (0.5, 1.0)
    assert heat[0].values[1][1] == pytest.approx(report.stats_for("reach", "sim").mean.value)


def test_iqm_statistic_flows_into_gaps_curves_and_heatmaps(evaluation: Evaluation) -> None:
    built = GapReport.build(evaluation, statistic="iqm", rng=0)
    heat = next(g for g in built.grids if g.policy == "slow")
    assert heat.statistic == "iqm" and heat.values[1][1] == pytest.approx(built.stats_for("slow", "sim").iqm.value)
    g = built.gap("slow")
    assert g.statistic == "iqm"
    iqm_sim, iqm_real = built.stats_for("slow", "sim").iqm.value, built.stats_for("slow", "real").iqm.value
    assert g.absolute.value == pytest.approx(iqm_sim - iqm_real)
    assert built.curve("slow", "ActuatorGain.scale").points[1].value == pytest.approx(iqm_sim)
    # every IQM of the report is rliable's, scipy.stats.trim_mean on the same runs (one condition: shape (n, 1))
    assert iqm_sim == stats.trim_mean(evaluation.returns["slow"]["sim"][:, None], 0.25, axis=0)[0]
    for c in (c for c in evaluation.conditions if c.sweep == heat.grid):
        runs = np.asarray(evaluation.returns["slow"][c.name])[:, None]
        assert heat.values[heat.x.index(c.value[0])][heat.y.index(c.value[1])] == stats.trim_mean(runs, 0.25, axis=0)[0]


def test_summary_names_the_gap_per_policy(report: GapReport) -> None:
    text = report.summary()
    assert re.search(r"'reach' (loses|gains) [\d.]+% \[[-\d.]+%, [-\d.]+%\] from sim to real", text)
    assert "from randomized to real" in text
    assert text.splitlines()[1:] and report.to_dict()["summary"] == text


def test_argument_errors(evaluation: Evaluation) -> None:
    with pytest.raises(
        ValueError, match=r"`reference` must be one of the conditions .* Received 'simm'. Close matches: \['sim'\]"
    ):
        GapReport.build(evaluation, reference="simm")
    with pytest.raises(ValueError, match=r"`randomized` must differ from `target`. Received 'robot' for both"):
        GapReport.build(evaluation, randomized="robot", target="robot")
    with pytest.raises(ValueError, match=r"`statistic` must be one of 'mean', 'iqm'. Received 'median'"):
        GapReport.build(evaluation, statistic="median")
    with pytest.raises(ValueError, match=r"`fraction` must be in \(0, 1\]. Received 1.5"):
        GapReport.build(evaluation, fraction=1.5)
    with pytest.raises(TypeError, match=r"`contact_sheet` must be a ContactSheet .* Received an array of shape"):
        GapReport.build(evaluation, contact_sheet=np.zeros((4, 4), dtype=np.uint8))
    with pytest.raises(TypeError, match=r"`evaluation` must be a sim2real\.evaluation\.Evaluation\. Received dict"):
        GapReport.build({})  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="`fit` must be a sysid FitResult"):
        GapReport.build(evaluation, fit="fit.json")  # type: ignore[arg-type]


# ----------------------------------------------------------------------------------------------- rendering


@pytest.fixture(scope="module")
def full(evaluation: Evaluation) -> GapReport:
    fit = FitResult.from_estimates({HIDDEN_ADDRESS: (2.3, 0.05), "dof_damping[elbow_pitch]": (1.2, 0.01)})
    # A short trace so the fit figure has something to draw (a fit read back from JSON has none and no figure).
    t = np.linspace(0.0, 1.0, 50)
    fit = dataclasses.replace(
        fit,
        true_params={HIDDEN_ADDRESS: 2.345},
        channels=("qpos[elbow_pitch]",),
        trace_time=t,
        trace_measured=np.sin(t)[:, None],
        trace_predicted=np.sin(t)[:, None] + 0.01,
        fit_percent={"qpos[elbow_pitch]": 98.0},
    )
    image = np.zeros((20, 30, 3), dtype=np.uint8)
    image[:, :15] = 200
    sheet = s2r.ContactSheet(frames=image[None], params=({},), image=image, path=None)
    return GapReport.build(evaluation, fit=fit, contact_sheet=sheet, rng=0, title=f"T {EVIL}", notes=(EVIL,))


def test_figures_are_deterministic_pngs(full: GapReport) -> None:
    figures = full.figures()
    assert (
        list(figures)
        == full.figure_names()
        == [
            "returns",
            "robustness_actuatorgain-scale",
            "heatmap_damping-scale-x-actuatorgain-scale",
            "sysid_fit",
            "contact_sheet",
        ]
    )
    assert all(png.startswith(PNG_MAGIC) and b"matplotlib" not in png.lower() for png in figures.values())
    for png in figures.values():
        PIL.Image.open(io.BytesIO(png)).verify()  # a valid PNG
    sheet = np.asarray(PIL.Image.open(io.BytesIO(figures["contact_sheet"])).convert("RGB"))
    assert sheet.shape == (20, 30, 3) and (sheet == full.contact_sheet).all()
    assert dataclasses.replace(full).figures() == figures  # a fresh render (no cache) gives the same bytes


def test_html_is_well_formed_self_contained_and_escaped(full: GapReport) -> None:
    page = full.to_html()
    checker = _Checker()
    checker.feed(page)
    checker.close()
    assert checker.errors == [] and checker.stack == []
    assert not checker.tags & {"script", "link", "iframe", "object"}
    assert not re.search(r"(src|href)\s*=\s*['\"]?(https?:|//)", page)
    figures = full.figures()
    assert len(checker.images) == len(figures)
    for image, (name, png) in zip(checker.images, figures.items(), strict=True):
        src = image["src"] or ""
        assert image["alt"] == name and src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1], validate=True) == png
    assert EVIL not in page and "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    markdown = full.to_markdown(figure_dir="figures")
    assert EVIL not in markdown and not re.search(r"(?<!\\)<", markdown)  # every < backslash-escaped
    assert all(f"(figures/{name}.png)" in markdown for name in figures)
    assert "figures/" not in full.to_markdown()
    assert "System identification</h2>" in page and "<td>[2.202, 2.398]</td>" in page  # the fit's 95% interval


def test_hidden_twin_configuration_only_in_the_appendix(full: GapReport) -> None:
    page = full.to_html()
    markdown = full.to_markdown()
    for text, heading in ((page, "Appendix: the real target</h2>"), (markdown, "## Appendix: the real target")):
        cut = text.index(heading)
        assert cut > len(text) // 2
        assert "2.345" not in text[:cut] and "2.345" in text[cut:]
        assert '"Constant", "value": 1.5' not in text[:cut].replace("&quot;", '"')
        assert "(in the appendix)" in text[:cut]
    data = full.to_dict()
    appendix = json.dumps(data.pop("appendix"))
    assert "2.345" in appendix and HIDDEN_ADDRESS in appendix
    assert "2.345" not in json.dumps(data)
    (hidden,) = [c for c in data["evaluation"]["conditions"] if c["name"] == "real"]
    assert hidden["hidden"] is True and "config" not in hidden and "draws" not in hidden


# ----------------------------------------------------------------------------------------------- files


def test_write_produces_exactly_the_files(tmp_path: Path, report: GapReport) -> None:
    out = tmp_path / "nested" / "report"
    files = report.write(out)
    names = report.figure_names()
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) == sorted(
        ["report.html", "report.json", "report.md", *(f"figures/{n}.png" for n in names)]
    )
    assert [p.name for p in (tmp_path / "nested").iterdir()] == ["report"]  # no temporary directory left
    assert files.json.read_text() == report.to_json()
    assert files.figures == tuple(out / "figures" / f"{n}.png" for n in names)
    assert files.html.read_text().startswith("<!doctype html>")
    # writing again into the existing directory replaces the files and leaves other files alone
    (out / "mine.txt").write_text("keep")
    report.write(out)
    assert (out / "mine.txt").read_text() == "keep"
    assert [p.name for p in (tmp_path / "nested").iterdir()] == ["report"]


@pytest.mark.parametrize("fail_on", ["report.md", "report.json"])
def test_interrupted_write_leaves_no_report(
    tmp_path: Path, report: GapReport, monkeypatch: pytest.MonkeyPatch, fail_on: str
) -> None:
    real_write = report_files.atomic_write

    def flaky(path: object, content: object, **kwargs: object) -> None:
        if Path(str(path)).name == fail_on:
            raise KeyboardInterrupt
        real_write(path, content, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(report_files, "atomic_write", flaky)
    with pytest.raises(KeyboardInterrupt):
        report.write(tmp_path / "out")
    assert list(tmp_path.iterdir()) == []


def test_interrupted_rewrite_keeps_the_previous_report(
    tmp_path: Path, report: GapReport, monkeypatch: pytest.MonkeyPatch
) -> None:
    report.write(tmp_path / "out")
    before = (tmp_path / "out" / "report.json").read_text()

    def broken(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(report_files, "atomic_write", broken)
    with pytest.raises(OSError, match="disk full"):
        report.write(tmp_path / "out")
    assert (tmp_path / "out" / "report.json").read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_fit_read_back_from_json_gives_the_table_but_no_figure(evaluation: Evaluation) -> None:
    fit = FitResult.from_estimates({HIDDEN_ADDRESS: (2.3, 0.05)})
    back = FitResult.from_json(fit.to_json())
    np.testing.assert_allclose(back.ci95, fit.ci95)
    report = GapReport.build(evaluation, fit=back, rng=0)
    assert "sysid_fit" not in report.figure_names()
    assert HIDDEN_ADDRESS in report.to_html()
