"""Journey 2 (a 7-DoF arm with a tendon gripper): what the gap report says about a fit that is not ok."""

from __future__ import annotations

import dataclasses

import sim2real as s2r
from sim2real.agents import ReachController
from sim2real.evaluation import evaluate, nominal, real
from sim2real.report import GapReport
from sysid.quality import FitQuality
from sysid.result import FitResult

REASON = "residuals far from white in 7 of 18 channels (worst qvel[j1]: Ljung–Box p=5e-05 < 0.001/18)"


def test_a_fit_that_is_not_ok_says_so_in_the_report() -> None:
    # Before: `sysid fit` exited 4 ("the fit is not ok") and `--force` exported it, but the report's System
    # identification section showed the estimates with nothing saying the fit had failed its checks.
    fit = FitResult.from_estimates({"dof_damping[shoulder_pitch]": (2.3, 0.05)})
    bad = dataclasses.replace(fit, quality=FitQuality(reasons=(REASON,)))
    assert not bad.ok
    evaluation = evaluate(
        {"reach": ReachController()},
        "sim2real/arm-reach",
        [nominal(), real([s2r.Damping(scale=1.5)])],
        episodes=2,
        seed=0,
        max_steps=5,
    )
    report = GapReport.build(evaluation, fit=bad, rng=0)
    assert report.fit_warnings[0] == f"the fit is NOT OK: {REASON}"
    assert "fit warning: the fit is NOT OK: residuals far from white in 7 of 18 channels" in report.to_markdown()
    clean = GapReport.build(evaluation, fit=fit, rng=0)
    assert not any("NOT OK" in w for w in clean.fit_warnings)
