"""The designer's services in one namespace (``from mtplan.explore import design as d``).

Each service is its own module; this one only gathers their public names for the web
application, the command line and scripts:

- :mod:`~mtplan.explore.state`: a design (the whole state of one browser tab), its set-up
  and the field that sizes each error source;
- :mod:`~mtplan.explore.info`: the controls and help the page draws for a procedure;
- :mod:`~mtplan.explore.prediction`: the first-order prediction, the identifiability and
  the cost guard;
- :mod:`~mtplan.explore.trust`: the spot check that decides which numbers may be shown;
- :mod:`~mtplan.explore.tolerances`: the acceptance figures of the entered tolerances;
- :mod:`~mtplan.explore.results`: everything the page shows for a design;
- :mod:`~mtplan.explore.sensitivity`: U over a lever's range;
- :mod:`~mtplan.explore.studies`: a design written as a study file and read back.
"""

from __future__ import annotations

from mtplan.explore.info import (GLOSSARY, explain, glossary, help_text, procedure_info,
                                 procedures_info, sliders)
from mtplan.explore.prediction import (CURVE_SECONDS, LIVE_MEMORY, LIVE_SECONDS, TooCostly,
                                       compute_prediction, guard_cost, identify,
                                       identify_cached, predict, prediction_cost,
                                       trial_seconds)
from mtplan.explore.results import budget_table, evaluate, source_inputs
from mtplan.explore.sensitivity import lever_values, sensitivity
from mtplan.explore.state import (K, field_problems, normalise, setup_of, source_fields,
                                  whole)
from mtplan.explore.studies import design_from_study, plan_vary, study_toml
from mtplan.explore.tolerances import risk_curve, tolerance_prior
from mtplan.explore.trust import check, known_spot, resolution_steps, spot_check, trust

__all__ = ["K", "procedures_info", "procedure_info", "normalise", "setup_of", "evaluate",
           "sensitivity", "study_toml", "design_from_study", "source_fields", "lever_values",
           "glossary", "explain", "help_text", "sliders", "GLOSSARY", "field_problems",
           "plan_vary", "whole", "check", "trust", "spot_check", "known_spot",
           "resolution_steps", "prediction_cost", "guard_cost", "TooCostly", "predict",
           "compute_prediction", "identify", "identify_cached", "trial_seconds",
           "LIVE_MEMORY", "LIVE_SECONDS", "CURVE_SECONDS", "budget_table", "source_inputs",
           "risk_curve", "tolerance_prior"]
