"""mtplan: Monte Carlo uncertainty and test-plan designer for machine-tool metrology.

Three layers for three users: library functions (:mod:`mtplan.uncertainty`,
:mod:`mtplan.models`), study and plan objects (:mod:`mtplan.plans`), and the
``mtplan`` command line. Heavy modules are imported lazily so that the command
line starts quickly.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
