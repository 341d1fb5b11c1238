"""A design as a study file that ``mtplan report`` accepts (:func:`study_toml`), and a design
read back from one (:func:`design_from_study`)."""

from __future__ import annotations

import json
import math
import tomllib

from mtplan._validate import InvalidInput
from mtplan.explore.state import K, json_value, normalise, refuse_files, setup_of, source_fields
from mtplan.explore.tolerances import PRIOR_TEXT
from mtplan.models import get, registry
from mtplan.models.protocol import parse_fields

__all__ = ["plan_vary", "study_toml", "design_from_study"]


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return json.dumps(str(v))  # a TOML basic string is a JSON string


def _inline(d: dict) -> str:
    return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in d.items()) + " }"


def plan_vary(proc, design) -> dict:
    """The planner's ranges of a design, each parsed into its field's kind."""
    out = {}
    for field, text in design["vary"].items():
        parts = [s for s in (text.split("|") if "|" in text else text.split(",")) if s.strip()]
        out[field] = [json_value(parse_fields(proc.Setup, {field: p}, owner=proc.name)[field])
                      for p in parts]
    return out


def study_toml(design: dict, *, title: str | None = None) -> str:
    """The design as a study file that ``mtplan report`` accepts.

    Every set-up field is stated (so the report's set-up is the page's whatever the
    defaults become), the estimator, the planner's targets and ranges, and one
    acceptance table per toleranced measurand. Raises InvalidInput for a design the
    procedure refuses.
    """
    design = normalise(design)
    proc, setup = setup_of(design)
    est, _ = proc.estimator(design["estimator"])
    values = {k: json_value(v) for k, v in setup.as_dict().items() if v is not None}
    lines = [
        "# A set-up designed in `mtplan explore`; `mtplan report` computes and writes it.",
        f"title = {_toml_value(title or f'Test plan: {proc.title}')}",
        f"seed = {int(design['seed'])}",
        f"trials = {int(design['trials'])}",
        "",
        "[[procedure]]",
        f"name = {_toml_value(proc.name)}",
        f"label = {_toml_value(proc.title)}",
        f"estimators = {_toml_value([est])}",
        f"setup = {_inline(values)}",
    ]
    targets = {}
    for k, v in design["targets"].items():
        try:
            targets[k] = float(v)  # bounds on U = k u, with k stated below
        except (TypeError, ValueError):
            continue
    vary = plan_vary(proc, design) if design["vary"] else {}
    if targets and vary:
        lines += ["", "  [procedure.plan]", f"  targets = {_inline(targets)}",
                  f"  vary = {_inline(vary)}", f"  k = {K!r}"]
    for name, tol in design["tolerances"].items():
        entry = {"measurand": name}
        for key in ("lower", "upper"):
            if tol.get(key) not in (None, ""):
                entry[key] = float(tol[key])
        if "lower" not in entry and "upper" not in entry:
            continue
        if PRIOR_TEXT.match(str(tol.get("prior") or "")):  # an uploaded CSV stays here
            entry["prior"] = tol["prior"].strip()
        entry["rule"] = (tol.get("rule") or "simple").strip()
        lines += ["", "  [[procedure.acceptance]]"]
        lines += [f"  {k} = {_toml_value(v)}" for k, v in entry.items()]
    return "\n".join(lines) + "\n"


def _text(v) -> str:
    """A set-up value as the page's box shows it (25.0 -> '25', a list comma-separated)."""
    if isinstance(v, list | tuple):
        return ",".join(_text(x) for x in v)
    if isinstance(v, float):
        return format(v, ".15g")
    return str(v)


def design_from_study(text: str, procedure: str | None = None) -> dict:
    """A design from a study file's text (its first procedure, or the one named).

    Raises InvalidInput when the text is not TOML, names no procedure, or holds a set-up
    the procedure refuses.
    """
    from mtplan.plans.study import load_study

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InvalidInput([f"The study is not valid TOML: {exc}"]) from None
    if "procedure" in data and "setup" in data and not isinstance(data["procedure"], list):
        data = {"procedure": [{"name": data["procedure"], "setup": data["setup"]}],
                **{k: v for k, v in data.items() if k in ("seed", "trials")}}
    entries = data.get("procedure") or []
    if isinstance(entries, dict):
        entries = [entries]
    if procedure is not None:
        entries = [e for e in entries if e.get("name") == procedure] or entries
    if not entries:
        raise InvalidInput(["The study names no [[procedure]]."])
    e = {k: v for k, v in entries[0].items() if k != "readings"}  # set-ups, not measurements
    if e.get("name") in registry() and isinstance(e.get("setup"), dict):
        refuse_files(get(e["name"]), e["setup"])
    study = load_study({**{k: v for k, v in data.items() if k != "procedure"},
                        "title": data.get("title", "study"), "procedure": [e]})
    ps = study.procedures[0]
    design = {
        "procedure": ps.name,
        "setup": {k: _text(v) for k, v in ps.setup.as_dict().items() if v is not None},
        "estimator": ps.estimators[0],
        "tolerances": {a["measurand"]: {k: a.get(k) for k in ("lower", "upper", "prior", "rule")
                                        if a.get(k) is not None}
                       for a in ps.acceptance},
        "seed": study.seed,
        "trials": ps.trials or study.trials or 10_000,
    }
    for source, f in source_fields(ps.procedure).items():  # a source at 0 is switched off
        if design["setup"].get(f) in ("0", "0.0"):
            design.setdefault("off", []).append(source)
            del design["setup"][f]  # on again at its default size
    if ps.plan:
        k = float(ps.plan.get("k", 1.0))
        design["targets"] = {m: float(v) * K / k for m, v in ps.plan.get("targets", {}).items()}
        design["vary"] = {f: ",".join(str(x) for x in vs)
                          for f, vs in ps.plan.get("vary", {}).items()}
    return normalise(design)
