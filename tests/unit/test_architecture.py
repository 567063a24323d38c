"""The import graph of pbc/ (every `import`, lazy ones included, read with `ast`): no circle, and no module
importing one further down the data flow (docs/architecture.md)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import tomllib

PKG = Path(__file__).resolve().parents[2] / "pbc"

# The data flow, lowest first; a module may import its own stage or an earlier one. The longest matching
# prefix names a module's stage. The ground floor (pbc.core) reads and writes files only.
STAGES = [
    # pbc.pretrained finds the shipped models (files only); pbc.pretrained.pack is a job
    ("pbc.core", "pbc.pretrained"),
    # geometry's own floors: mesh operations, units and the one OBJ reader/writer; the body; the cage; the
    # garments (which sit on a body and are cut by a cage); the shrink-wrap of a garment onto a body; the report
    ("pbc.geometry", "pbc.geometry.meshops", "pbc.geometry.units", "pbc.geometry.meshio"),
    ("pbc.geometry.body",),
    ("pbc.geometry.cage",),
    ("pbc.geometry.garment",),
    ("pbc.geometry.shrinkwrap",),
    ("pbc.geometry.inspect",),
    ("pbc.sim",),
    # motion capture in (clips, retargeting, joint ranges): below data, so a dataset's poses can come from clips
    ("pbc.motion",),
    ("pbc.pixels",),
    ("pbc.data",),
    ("pbc.models",),
    ("pbc.stitch",),
    ("pbc.inference",),
    ("pbc.jobs", "pbc.jobs.writers"),
    ("pbc.jobs.train", "pbc.jobs.evaluate", "pbc.jobs.edit", "pbc.jobs.view", "pbc.jobs.predict",
     "pbc.pretrained.pack"),
    # an outfit's job writes as pbc predict does (its guard, its sheet frames)
    ("pbc.jobs.outfit",),
    ("pbc.jobs.report",),
    ("pbc.jobs.sweeps", "pbc.jobs.robustness", "pbc.jobs.garment_fit", "pbc.jobs.main"),
    # the entry floor: every command (pbc.cli) and the `python -m pbc.X` aliases that hand over to it
    ("pbc", "pbc.train", "pbc.generate", "pbc.evaluate", "pbc.predict", "pbc.edit", "pbc.sweeps", "pbc.report",
     "pbc.main", "pbc.cli", "pbc.__main__"),
]
# the library stages: no command lives there (the entry floor, pbc.cli, holds them all)
LIBRARY = ("pbc.core", "pbc.geometry", "pbc.sim", "pbc.pixels", "pbc.data", "pbc.models", "pbc.stitch", "pbc.motion",
           "pbc.inference", "pbc.jobs")
# pbc/'s top level holds the package's own files and the `python -m pbc.X` aliases; everything else is in a stage
MAX_TOP_LEVEL_MODULES = 10


def module_name(path: Path) -> str:
    parts = path.relative_to(PKG.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def main_guard(tree: ast.Module) -> ast.If | None:
    """The module's `if __name__ == "__main__":` block, if any."""
    for node in tree.body:
        if (isinstance(node, ast.If) and isinstance(node.test, ast.Compare)
                and isinstance(node.test.left, ast.Name) and node.test.left.id == "__name__"):
            return node
    return None


def import_graph() -> dict[str, set[str]]:
    """{module: the pbc modules it imports}, from the source alone (nothing is imported). The imports of a
    `python -m pbc.X` alias's main guard (it hands over to the entry floor) are not dependencies."""
    modules = {module_name(p): p for p in PKG.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        deps = set()
        tree = ast.parse(path.read_text(), str(path))
        guard = main_guard(tree)
        if guard is not None:
            tree.body.remove(guard)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                # `from pbc.x import y`: y is a submodule when such a file exists, else a name in pbc.x
                targets = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules else node.module
                           for a in node.names]
            else:
                continue
            deps |= {t for t in targets if t.startswith("pbc.") and t in modules and t != name}
        graph[name] = deps
    return graph


def stage(module: str) -> int:
    best = None
    for i, prefixes in enumerate(STAGES):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and (best is None or len(p) > best[1]):
                best = (i, len(p))
    assert best is not None, f"{module} has no stage: add it to STAGES (and to docs/architecture.md)"
    return best[0]


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1 = on the stack, 2 = done
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state and (c := visit(m)):
                return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state and (c := visit(n)):
            return c
    return None


def test_graph_is_read():
    g = import_graph()
    # a sanity floor so an empty graph cannot pass: the trainer imports the DataModule and the module
    assert {"pbc.data.datamodule", "pbc.models.module"} <= g["pbc.jobs.train"]
    assert "pbc.pixels.target" in g["pbc.data.datamodule"]


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_no_import_runs_back_up_the_pipeline():
    g = import_graph()
    upward = [f"{a} (stage {stage(a)}) imports {b} (stage {stage(b)})" for a, deps in sorted(g.items())
              for b in sorted(deps) if stage(b) > stage(a)]
    assert not upward, "imports running back up the data flow:\n  " + "\n  ".join(upward)


def test_the_checks_catch_a_cycle_and_an_upward_import():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None
    assert stage("pbc.pixels.preview") < stage("pbc.data.dataset")
    assert stage("pbc.geometry.meshops") < stage("pbc.geometry.body.base") < stage("pbc.geometry.cage.auto") \
        < stage("pbc.geometry.garment.tshirt") < stage("pbc.geometry.shrinkwrap")


def test_the_top_level_holds_only_the_package_and_the_command_aliases():
    top = sorted(p.stem for p in PKG.glob("*.py"))
    assert len(top) <= MAX_TOP_LEVEL_MODULES, f"{len(top)} modules at pbc/'s top level: {top}; move them into a stage"
    for name in set(top) - {"__init__", "__main__"}:
        tree = ast.parse((PKG / f"{name}.py").read_text())
        defs = [n for n in tree.body if not isinstance(n, ast.Expr | ast.If)]
        assert not defs and main_guard(tree) is not None, \
            f"pbc/{name}.py is an alias of `python -m pbc.{name}`: a docstring and the main guard only"


def test_a_package_door_is_not_imported_by_its_own_modules():
    """A package's __init__ that imports its own modules (a door: pbc.geometry.body, pbc.geometry.garment) must
    not be imported by them: half-initialised packages are the import cycles the stage check cannot see."""
    g = import_graph()
    doors = {m for m, deps in g.items() if any(d.startswith(m + ".") for d in deps)}
    bad = [f"{a} imports its package's door {b}" for a, deps in g.items() for b in deps
           if b in doors and a.startswith(b + ".")]
    assert not bad, "\n".join(bad)


def test_commands_live_on_the_entry_floor():
    """No library stage holds a command; a `python -m pbc.X` alias only hands over to pbc.cli."""
    for path in sorted(PKG.rglob("*.py")):
        name = module_name(path)
        guard = main_guard(ast.parse(path.read_text(), str(path)))
        if guard is None:
            continue
        assert not name.startswith(LIBRARY), f"{name} (a library stage) has a __main__ block: move it to pbc/cli"
        if name.startswith("pbc.cli") or name == "pbc.__main__":
            continue
        calls = [n.func for n in ast.walk(guard) if isinstance(n, ast.Call)]
        assert [getattr(c, "id", None) for c in calls] == ["run_as_module"], \
            f"{name}'s __main__ block must only call pbc.cli.run_as_module (the command lives in pbc/cli)"


# Imports sit at the top of a module. An import inside a function is kept only where a heavy optional
# dependency justifies it (newton/warp, matplotlib, lightning off the module's main path), and its line says
# why: `# noqa: PLC0415 - <the reason, in a few words>` (ruff's PLC0415, selected in pyproject.toml, enforces
# the placement; this test the reason).
LAZY_MARK = "noqa: PLC0415 - "
LAZY_REASON_WORDS = 3


def unexplained_lazy_imports(source: str, filename: str) -> list[str]:
    """'file:line: the import' for each import inside a function or method whose first line lacks
    `# noqa: PLC0415 - ` and a reason of at least LAZY_REASON_WORDS words."""
    lines = source.splitlines()
    found = set()
    for fn in ast.walk(ast.parse(source, filename)):
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.Import | ast.ImportFrom):
                _, mark, reason = lines[node.lineno - 1].partition(LAZY_MARK)
                if not mark or len(reason.split()) < LAZY_REASON_WORDS:
                    found.add(node.lineno)
    return [f"{filename}:{n}: {lines[n - 1].strip()}" for n in sorted(found)]


def test_lazy_imports_say_why():
    bad = []
    for path in sorted(PKG.rglob("*.py")):
        bad += unexplained_lazy_imports(path.read_text(), str(path.relative_to(PKG.parent)))
    assert not bad, ("imports inside a function without a reason: move each to the top of its module, or, for a "
                     f"heavy optional dependency off the main path, end its line with `# {LAZY_MARK}<why>`:\n  "
                     + "\n  ".join(bad))


def test_the_lazy_import_check_catches_an_unexplained_one():
    source = ("import os\n"                                                            # 1: top level
              "def f():\n"
              "    import json\n"                                                      # 3: no reason
              "    from pathlib import Path  # noqa: PLC0415\n"                        # 4: no reason
              "    import csv  # noqa: PLC0415 - slow\n"                               # 5: too short
              "    import torch  # noqa: PLC0415 - torch loads in seconds; only here\n"  # 6: fine
              "    return json, Path, csv, torch, os\n"
              "class A:\n"
              "    async def m(self):\n"
              "        def inner():\n"
              "            import re\n"                                                # 11: nested, no reason
              "            return re\n"
              "        return inner\n"
              "if __name__ == '__main__':\n"
              "    import sys\n")                                                      # 15: not in a function
    found = unexplained_lazy_imports(source, "x.py")
    assert [f.split(": ")[0] for f in found] == ["x.py:3", "x.py:4", "x.py:5", "x.py:11"]
    assert found[0] == "x.py:3: import json"


def test_test_files_have_one_name_across_the_tiers():
    # pytest imports test files by basename (no packages under tests/): two tiers holding test_x.py stop the
    # whole run at collection ("import file mismatch"), as the first CI of a tests/unit + tests/integration pair did
    names = [p.name for p in (PKG.parent / "tests").rglob("test_*.py")]
    assert len(names) == len(set(names)), sorted({n for n in names if names.count(n) > 1})


# a citation of an outside tracker ("issue" and a number) says nothing to a reader of the code; say what it does
TRACKER_CITATION = re.compile(r"\bissues?\s*#?\s*\d+", re.IGNORECASE)
CITATION_DIRS = ("pbc", "conf", "tests", "bench")


def tracker_citations(text: str, filename: str) -> list[str]:
    return [f"{filename}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)}"
            for m in TRACKER_CITATION.finditer(text)]


def test_no_tracker_citations():
    root = PKG.parent
    found = []
    for d in CITATION_DIRS:
        for path in sorted((root / d).rglob("*")):
            if path.suffix in (".py", ".yaml", ".md", ".json") and path.is_file() and "pretrained" not in path.parts:
                found += tracker_citations(path.read_text(errors="replace"), str(path.relative_to(root)))
    assert not found, "say what the code does instead of citing a tracker:\n  " + "\n  ".join(found)


def test_the_citation_check_catches_one():
    cite = "Issue"  # the examples are built, so this file holds none itself
    text = f"ok\n# see {cite} #12 and {cite.lower()}s 3\nthe {cite.lower()} was 4 mm\n"
    assert tracker_citations(text, "a.py") == [f"a.py:2: {cite} #12", f"a.py:2: {cite.lower()}s 3"]


def test_every_package_ships_in_the_wheel():
    """A package missing from pyproject's list works in a checkout and is absent from the wheel."""
    listed = set(tomllib.loads((PKG.parent / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    missing = sorted({module_name(p) for p in PKG.rglob("__init__.py")} - listed)
    assert not missing, f"add to [tool.setuptools] packages in pyproject.toml: {missing}"
