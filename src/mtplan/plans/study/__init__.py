"""Studies: what a report covers, read from a TOML file and computed in one go.

A study names procedures, their base set-ups, sweeps, planning targets, tolerances with
their acceptance rules and optionally measured readings, and carries the header of the
document a customer receives. Four modules do its four jobs:

- :mod:`~mtplan.plans.study.schema`: :func:`load_study` validates the whole file and lists
  every problem at once (the file's keys are shown there);
- :mod:`~mtplan.plans.study.runner`: :func:`run_study` computes every result (Monte Carlo,
  GUM budget, sweeps, plan, measured data, verdicts, advice) in stages on worker processes
  into a :class:`StudyResult` that the reports render without computing anything;
- :mod:`~mtplan.plans.study.cache`: :func:`run_study_cached` keeps results under
  :func:`study_cache_key`, the hash of everything they depend on;
- :mod:`~mtplan.plans.study.provenance`: what a result's numbers came from;

and :mod:`~mtplan.plans.study.temperature_log` reads a log of the ambient temperature that
``[conditions]`` names.
"""

from mtplan.plans.study.cache import CACHE_KEEP, run_study_cached, study_cache_key
from mtplan.plans.study.runner import ProcedureOutcome, StudyResult, run_study
from mtplan.plans.study.schema import (
    CONDITION_CHECKS,
    CONDITION_EFFECTS,
    CONDITION_KEYS,
    HEADER_KEYS,
    INSTRUMENT_KINDS,
    LARGER_U,
    REQUIREMENT_KEYS,
    UNHONOURED_STANDARDS,
    ProcedureStudy,
    Study,
    load_study,
    machine_serials,
)

__all__ = ["Study", "ProcedureStudy", "StudyResult", "HEADER_KEYS", "load_study", "run_study",
           "run_study_cached", "study_cache_key"]
