"""No test asserts on wall time: a loaded machine makes a test slow, never wrong (speed belongs to benchmarks/)."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent
#: The clocks of the ``time`` module; ``time.sleep`` and the like are no clock.
CLOCKS = {
    "perf_counter",
    "perf_counter_ns",
    "time",
    "time_ns",
    "monotonic",
    "monotonic_ns",
    "process_time",
    "process_time_ns",
    "thread_time",
    "thread_time_ns",
}


def _clock_names(tree: ast.Module) -> tuple[set[str], set[str]]:
    """The names the module gives the ``time`` module and the clocks imported from it."""
    modules, clocks = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules |= {a.asname or a.name for a in node.names if a.name == "time"}
        elif isinstance(node, ast.ImportFrom) and node.module == "time":
            clocks |= {a.asname or a.name for a in node.names if a.name in CLOCKS}
    return modules, clocks


def _reads_clock(node: ast.AST, modules: set[str], clocks: set[str], tainted: set[str]) -> bool:
    """Whether ``node`` calls a clock or uses a name holding a clock reading (or a difference of them)."""
    for sub in ast.walk(node):
        if isinstance(sub, ast.Call):
            f = sub.func
            if isinstance(f, ast.Attribute) and f.attr in CLOCKS and isinstance(f.value, ast.Name):
                if f.value.id in modules:
                    return True
            if isinstance(f, ast.Name) and f.id in clocks:
                return True
        if isinstance(sub, ast.Name) and sub.id in tainted:
            return True
        if isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name) and f"self.{sub.attr}" in tainted:
            return True
    return False


def _targets(target: ast.AST) -> set[str]:
    names = set()
    for sub in ast.walk(target):
        if isinstance(sub, ast.Name):
            names.add(sub.id)
        elif isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name) and sub.value.id == "self":
            names.add(f"self.{sub.attr}")
    return names


def _is_check(node: ast.AST) -> ast.AST | None:
    """The expression a check judges: an ``assert``'s test, a unittest ``assert*`` call's arguments, or the
    condition of an ``if`` whose body fails the test (``raise``, ``pytest.fail``)."""
    if isinstance(node, ast.Assert):
        return node.test
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr.startswith("assert"):
        return ast.Tuple(elts=[*node.args, *(k.value for k in node.keywords)], ctx=ast.Load())
    if isinstance(node, ast.If):
        fails = any(
            isinstance(s, ast.Raise)
            or (
                isinstance(s, ast.Expr)
                and isinstance(s.value, ast.Call)
                and isinstance(s.value.func, ast.Attribute)
                and s.value.func.attr == "fail"
            )
            for s in node.body
        )
        return node.test if fails else None
    return None


def timing_checks(source: str) -> list[int]:
    """Line numbers of the checks in ``source`` that judge a clock reading or an elapsed time."""
    tree = ast.parse(source)
    modules, clocks = _clock_names(tree)
    if not modules and not clocks:
        return []
    tainted: set[str] = set()
    assigns = [n for n in ast.walk(tree) if isinstance(n, (ast.Assign, ast.AugAssign, ast.AnnAssign, ast.NamedExpr))]
    while True:  # names holding clock readings, and names computed from them, to a fixed point
        before = len(tainted)
        for n in assigns:
            if n.value is not None and _reads_clock(n.value, modules, clocks, tainted):
                for t in n.targets if isinstance(n, ast.Assign) else [n.target]:
                    tainted |= _targets(t)
        if len(tainted) == before:
            break
    found = []
    for node in ast.walk(tree):
        judged = _is_check(node)
        if judged is not None and _reads_clock(judged, modules, clocks, tainted):
            found.append(node.lineno)
    return sorted(found)


def test_no_test_judges_wall_time():
    found = []
    for path in sorted(TESTS.rglob("*.py")):
        if "data" in path.relative_to(TESTS).parts:
            continue
        found += [f"{path.relative_to(TESTS)}:{line}" for line in timing_checks(path.read_text())]
    assert found == [], "wall-time checks (move them to a benchmark under benchmarks/): " + ", ".join(found)


BAD = [
    "import time\nt = time.perf_counter()\nrun()\nassert time.perf_counter() - t < 30\n",
    "import time\nt0 = time.time()\nrun()\nelapsed = time.time() - t0\nassert elapsed < 10, elapsed\n",
    "from time import monotonic as clock\nstart = clock()\nrun()\nassert clock() - start >= 0.2\n",
    "import time as t\ndef test():\n    a = t.monotonic_ns()\n    run()\n    took = (t.monotonic_ns() - a) / 1e9\n"
    "    seconds = round(took, 1)\n    assert seconds < 5\n",
    "import time\nclass T:\n    def setUp(self):\n        self.t0 = time.perf_counter()\n"
    "    def test(self):\n        self.assertLess(time.perf_counter() - self.t0, 1.0)\n",
    "import time, pytest\nt = time.time()\nrun()\nif time.time() - t > 60:\n    pytest.fail('too slow')\n",
    "import time\nt = time.time()\nrun()\nif (d := time.time() - t) > 60:\n    raise AssertionError(d)\n",
]
GOOD = [
    "import time\ndeadline = time.time() + 60\nwhile time.time() < deadline and not done():\n    time.sleep(0.05)\n"
    "assert done()\n",
    "import time\nos.utime(lock, (time.time() - 60, time.time() - 60))\nassert is_stale(lock)\n",
    "import time\ntime.sleep(0.02)\nassert stamps == before\n",
    "seconds = plan.seconds\nassert seconds < 10 * 60\n",  # an estimate, no clock read
]


def test_the_scan_catches_wall_time_checks():
    for source in BAD:
        assert timing_checks(source), source
    for source in GOOD:
        assert timing_checks(source) == [], source
