"""The designer's cost guard: what it takes to learn its models, and to answer for every
field that sizes the work at its largest allowed value.

For each procedure, in a fresh process (imports included): the seconds its size model and
its default estimator's path and time take to learn (what the server does at start, in the
background: :func:`mtplan.explore.prediction.learn_costs`); then, once learnt, for every
count field (an int's value, a list's length: the field records'
:attr:`~mtplan.models.fields.FieldInfo.count`) at its largest allowed value, alone and all
together, the wall and CPU milliseconds of the guard itself (the size estimate and the
prediction's cost estimate, before anything is computed) and its verdict.

    python benchmarks/bench_cost_guard.py [PROCEDURE ...]
"""

from __future__ import annotations

import subprocess
import sys

CHILD = r"""
import sys, time
from mtplan._validate import InvalidInput
from mtplan.explore.prediction import guard_cost, learn_costs
from mtplan.explore.size import probe_value, size_problem
from mtplan.models import get
from mtplan.models.protocol import fields_info, make

name = sys.argv[1]
proc = get(name)
t = time.perf_counter()
learn_costs([name])
print(f"{name}: learnt in {time.perf_counter() - t:.2f} s")
est = proc.estimator(None)[0]
counts = [f for f in fields_info(proc.Setup) if f.count and not f.file]
cases = [(f.name, {f.name: probe_value(f, f.largest)}) for f in counts]
cases.append(("all together", {f.name: probe_value(f, f.largest) for f in counts}))
for label, values in cases:
    try:
        setup = make(proc.Setup, values, owner=name)
    except InvalidInput as exc:
        print(f"  {label:22s} refused by its field or a rule: {exc.problems[0][:70]}")
        continue
    wall, cpu = time.perf_counter(), time.thread_time()
    _, problem = size_problem(proc, setup.as_dict())
    verdict = "refused by size" if problem else "within size"
    if not problem:
        try:
            guard_cost(proc, setup, est)
            verdict = "computed"
        except InvalidInput:
            verdict = "refused by cost"
    print(f"  {label:22s} {1e3 * (time.perf_counter() - wall):7.1f} ms wall "
          f"{1e3 * (time.thread_time() - cpu):7.1f} ms CPU  {verdict}")
"""


def main(argv=None) -> int:
    from mtplan.models import registry

    names = list(argv if argv is not None else sys.argv[1:]) or list(registry())
    for name in names:
        subprocess.run([sys.executable, "-c", CHILD, name], check=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
