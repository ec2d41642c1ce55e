"""``sim2real study``: the whole sim-to-real loop on an embedded default, in one command.

Stages (each prints its progress and time):

1. **twin** - the "real" robot: a twin of the task with held-out parameters, sensor noise and actuator
   latency from the bundled profile (``sim2real/data/study/<task>/study.yaml``), one
   :class:`~sim2real.conditions.Condition`. Its excitation logs are recorded through the very environment the
   evaluation scores it on (:func:`sim2real.twin.record_condition`). The report reveals it only in an appendix.
2. **sysid** - the twin's logs fitted with :func:`sysid.fit` (independent
   multi-starts run one after another in this process, the lowest cost wins), turned into a *calibrated, randomised*
   simulator: each fitted value rounded to ``digits`` significant digits and randomised by
   ``max(relative_width, 2 stderr / estimate)`` around it, the fitted action latency and sensor noise,
   plus the profile's ``keep`` randomisation (what the fit does not cover).
3. **policies** - a nominal, a randomised, a calibrated and an ADR policy trained with the profile's ``agent``
   (ADR: automatic domain randomisation from the nominal point, the profile's ``adr`` section), loaded from the
   checkpoints the package ships when they were trained under exactly the same configuration (``manifest.json``
   holds the ``sim2real train`` command that reproduces each and its wall and CPU time), trained otherwise; plus
   the task's scripted baseline.
4. **evaluate** - every policy on the nominal sim, the randomised sim, the calibrated sim, the ADR policy's
   final ranges, the twin, and one-parameter sweeps and a two-parameter grid: the profile becomes an ordinary
   evaluation spec (:meth:`StudyProfile.spec_config` -> :func:`sim2real.spec.load_spec` -> ``EvaluationSpec.run``).
5. **report** - :class:`sim2real.report.GapReport` written to ``OUT/report.html``, ``report.md``,
   ``report.json`` and ``figures/``, next to the fit (``sysid/fit.json``) and the calibrated config.

Everything goes to a staging folder first and is moved into place at the end, so Ctrl-C or an error leaves
no half-written study. ``out`` is checked before any work: it must be a new or empty folder, because an existing
folder that holds anything is never overwritten, emptied or deleted (without ``out``, the first free
``sim2real-study``, ``sim2real-study-2``, ... is used). The same seed reproduces ``report.json`` bitwise
(wall-clock times are kept out of it), on either backend.

Modules: :mod:`~sim2real.study.profile` (profiles, budgets, the spec), :mod:`~sim2real.study.fitting` (twin logs,
fits, the calibrated simulator), :mod:`~sim2real.study.policies` (shipped or trained checkpoints),
:mod:`~sim2real.study.run` (stages, staging folder, backends), :mod:`~sim2real.study.summary`.

Example (the CI-sized budget, in a temporary folder):

    >>> from sim2real.study import BUDGETS
    >>> BUDGETS["quick"].episodes, BUDGETS["standard"].episodes
    (4, 128)
"""

from __future__ import annotations

from sim2real.study.fitting import calibrated_effects
from sim2real.study.policies import ROLES, prepare_checkpoints, write_manifest
from sim2real.study.profile import BUDGETS, DEFAULT_TASK, PROFILES, Budget, StudyProfile, load_profile, study_tasks
from sim2real.study.run import DEFAULT_OUT, StudyResult, run_study
from sim2real.study.summary import study_summary

__all__ = [
    "BUDGETS",
    "DEFAULT_OUT",
    "DEFAULT_TASK",
    "PROFILES",
    "ROLES",
    "Budget",
    "StudyProfile",
    "StudyResult",
    "calibrated_effects",
    "load_profile",
    "prepare_checkpoints",
    "run_study",
    "study_summary",
    "study_tasks",
    "write_manifest",
]
