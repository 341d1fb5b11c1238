"""What an accredited certificate states, from the study's [laboratory] table.

ISO/IEC 17025 asks the report for who authorised it (7.8.2.1 o) and, for a non-standard
method, the laboratory's own procedure and its validation (7.2.2); EA-4/02 words the
uncertainty statement; ILAC-P8 governs a report issued under an accreditation. A study
that declares no accreditation gets "not accredited", said plainly, and no ILAC-P8
statement. Formatting only.
"""

from __future__ import annotations

__all__ = ["accreditation_text", "signatory_text", "lab_procedure_text", "ilac_p8_text",
           "uncertainty_statement"]


def accreditation_text(lab: dict) -> str:
    """The accreditation status as the cover states it."""
    if lab.get("accredited"):
        return f"accredited: {lab.get('accreditation', '')}"
    if lab.get("accredited") is False:
        return ("not accredited: issued under no accreditation, without an accreditation "
                "symbol")
    extra = f" ({lab['accreditation']})" if lab.get("accreditation") else ""
    return f"not stated in the study{extra}: the report claims no accreditation"


def signatory_text(lab: dict) -> str:
    """The named signatory and function, or what is missing."""
    name, function = lab.get("signatory"), lab.get("signatory_function")
    if not name:
        return "not named in the study"
    return f"{name}, {function}" if function else f"{name} (function not stated)"


def lab_procedure_text(lab: dict, procedure: str) -> str:
    """"laboratory procedure LP-1 rev. 2, validated in VR-7" of a non-standard method
    (ISO/IEC 17025 7.2.2), or what the study leaves out."""
    entry = (lab.get("procedures") or {}).get(procedure, {})
    ident = entry.get("id") or "not stated"
    valid = entry.get("validation") or "not stated"
    return (f"laboratory procedure {ident} (a non-standard method, ISO/IEC 17025 7.2.2); "
            f"validation: {valid}")


def ilac_p8_text(lab: dict) -> str:
    """The ILAC-P8 statement where accreditation is declared, else ""."""
    if not lab.get("accredited"):
        return ""
    return (f"This report is issued under the accreditation {lab.get('accreditation', '')} "
            "in accordance with ILAC-P8: the accreditation covers the tests named in the "
            "laboratory's scope of accreditation; results outside it are marked as such, and "
            "the accreditation body's symbol is used only on reports of accredited tests.")


def uncertainty_statement(coverage: float = 0.95) -> str:
    """The uncertainty statement of EA-4/02 M:2022 (its section 5), with the coverage that
    each U really has in place of the normal distribution's "approximately 95 %"
    (:mod:`mtplan.uncertainty.coverage`)."""
    return ("The reported expanded uncertainty of measurement U is stated as the standard "
            "uncertainty of measurement multiplied by the coverage factor k = 2, the U that "
            "the decision rules use (ISO 14253-1). The coverage probability that U has is not "
            "assumed: beside each U is the fraction of the value's own distribution (Monte "
            "Carlo or posterior) within ± U, which is about 95 % only for a near-normal one "
            "(more for an output dominated by rectangular inputs, less for a heavy-tailed "
            "one). The standard uncertainty of measurement has been determined in accordance "
            "with EA-4/02 M:2022, here by the Monte Carlo method of JCGM 101:2008 (or, where "
            "stated, from the Bayesian posterior of the readings); the "
            f"{100 * coverage:.0f} % interval printed is that of the values' own "
            "distribution.")
