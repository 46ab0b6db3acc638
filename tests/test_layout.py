"""The package's floor plan, checked from its source with the ast module.

Stages along the pipeline, lowest first; a module may import its own stage and the ones before it, never a
later one.  No module (nor a script) imports a private name of another module.
"""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "servofmu"
STAGES = [
    {"servofmu.version", "servofmu.errors", "servofmu.locks", "servofmu.runtime", "servofmu.claims", "servofmu.fileio",
     "servofmu.integrity", "servofmu.text_digest", "servofmu.display", "servofmu.api_checks"},
    {"servofmu.model", "servofmu.fmu_models"},
    {"servofmu.fmu"},
    {"servofmu.simulation"},
    {"servofmu.measurement"},
    {"servofmu.broadband"},
    {"servofmu.identification"},
    {"servofmu.baselines"},
    {"servofmu.selection"},
    {"servofmu.control"},
    {"servofmu.tuning"},
    {"servofmu.validation"},
    {"servofmu.output"},
    {"servofmu.commands"},
    {"servofmu.api"},
    {"servofmu.cli", "servofmu.__main__"},
]


def stage_of(module: str) -> int | None:
    """The stage of a module (by its longest matching prefix), None for the package root."""
    for i, names in enumerate(STAGES):
        if any(module == n or module.startswith(n + ".") for n in names):
            return i
    assert module == "servofmu", f"{module} is in no stage: add it to STAGES"
    return None


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path, root: Path = ROOT):
    """(line, imported module, imported names) of every import in ``path``, relative ones resolved."""
    return imports_of_tree(ast.parse(path.read_text()), path, root)


def package_files():
    return sorted(p for p in PACKAGE.rglob("*.py")) + sorted((ROOT / "fmu_models").glob("*.py"))


def test_the_stage_order_is_stated_for_every_module():
    for path in package_files():
        if path.parent == ROOT / "fmu_models":
            continue
        stage_of(module_name(path))


@pytest.mark.parametrize("path", package_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_module_imports_a_later_stage(path):
    if path.parent == ROOT / "fmu_models":
        return
    here = module_name(path)
    mine = stage_of(here)
    if mine is None:  # the package root: the public API, which names every stage
        return
    for line, module, names in imports(path):
        if not module.startswith("servofmu"):
            continue
        targets = [f"{module}.{n}" for n in names] if module == "servofmu" else [module]
        for target in targets:
            theirs = stage_of(target)
            assert theirs is not None, f"{path.relative_to(ROOT)}:{line}: {here} imports the package root " \
                                       f"({target}), which stands above every stage"
            assert theirs <= mine, f"{path.relative_to(ROOT)}:{line}: {here} (stage {mine}) imports {target} " \
                                   f"(stage {theirs}), a later stage"


@pytest.mark.parametrize("path", package_files() + sorted((ROOT / "scripts").glob("*.py")),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_no_private_name_of_another_module_is_imported(path):
    here = module_name(path) if path.is_relative_to(PACKAGE) else None
    for line, module, names in imports(path):
        if not module.startswith("servofmu") or module == here:
            continue
        private = [n for n in names if n.startswith("_") and not n.startswith("__")]
        assert not private, f"{path.relative_to(ROOT)}:{line}: imports the private {', '.join(private)} of {module}"
        assert not any(part.startswith("_") and not part.startswith("__") for part in module.split(".")), \
            f"{path.relative_to(ROOT)}:{line}: imports the private module {module}"


def test_the_checks_see_a_violation(tmp_path):
    """The checks above can fail: a model module importing the output stage and a private name is caught."""
    probe = tmp_path / "servofmu" / "model" / "probe.py"
    probe.parent.mkdir(parents=True)
    probe.write_text("from ..output.report import make_report\nfrom ..identification.criterion import _weighted\n")
    found = [(m, names) for _, m, names in imports(probe, root=tmp_path)]
    assert found == [("servofmu.output.report", ["make_report"]), ("servofmu.identification.criterion", ["_weighted"])]
    assert stage_of(found[0][0]) > stage_of("servofmu.model.probe")


def module_imports() -> dict[str, set[str]]:
    """module -> the servofmu modules it imports (at its top or in a function; ``from X import y`` names the
    submodule X.y where y is one)."""
    modules = {module_name(p) for p in package_files()}
    out = {}
    for path in package_files():
        edges = out.setdefault(module_name(path), set())
        for _, module, names in imports(path):
            if module.startswith("servofmu"):
                subs = {f"{module}.{n}" for n in names if f"{module}.{n}" in modules}
                edges.update(subs if subs and len(subs) == len(names) else {module} | subs)
    return out


def test_no_two_modules_import_each_other():
    """No circle of two modules, not even through an import inside a function (fileio and integrity were one)."""
    edges = module_imports()
    pairs = sorted({tuple(sorted((a, b))) for a in edges for b in edges[a] if a != b and a in edges.get(b, ())})
    assert pairs == []


def circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The circles of the import graph ``edges``: its strongly connected sets of more than one module (Tarjan's
    algorithm, iterative), each sorted."""
    index, low, on, stack, found, counter = {}, {}, set(), [], [], 0
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            node, targets = work[-1]
            target = next(targets, None)
            if target is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    group = []
                    while not group or group[-1] != node:
                        group.append(stack.pop())
                        on.discard(group[-1])
                    if len(group) > 1:
                        found.append(sorted(group))
            elif target not in index:
                index[target] = low[target] = counter
                counter += 1
                stack.append(target)
                on.add(target)
                work.append((target, iter(sorted(edges.get(target, ())))))
            elif target in on:
                low[node] = min(low[node], index[target])
    return found


def test_no_circle_of_any_length():
    """No circle through any number of modules either (a within-stage arrow that runs back up makes one), imports
    inside functions and under TYPE_CHECKING counted."""
    assert circles(module_imports()) == []


def test_the_circle_check_sees_a_circle_of_three():
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"a"}}
    assert circles(edges) == [["a", "b", "c"]]
    assert circles({**edges, "c": {"d"}}) == []


# What runs a command's work: the stages' entry points, searches and loop simulations.  output/ draws pages of
# what they computed and exports; it imports none of them at run time (a type under TYPE_CHECKING is no import).
RUNS_A_COMMAND = {"servofmu.tuning.run", "servofmu.tuning.search", "servofmu.tuning.check",
                  "servofmu.control.compensation", "servofmu.control.cosim", "servofmu.simulation.closed_loop",
                  "servofmu.simulation.fmpy_runs", "servofmu.validation.run", "servofmu.identification.run",
                  "servofmu.identification.identifier", "servofmu.identification.search", "servofmu.selection.run",
                  "servofmu.selection.fitting", "servofmu.selection.terms",
                  "servofmu.measurement.measure", "servofmu.commands.select", "servofmu.commands.demo",
                  "servofmu.commands.roundtrip"}
def runtime_imports(path: Path, root: Path = ROOT) -> set[str]:
    """The servofmu modules ``path`` imports at run time (``from X import y`` names X.y too), leaving out the
    blocks under ``if TYPE_CHECKING:``."""
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            node.body = []
    out = set()
    for _, module, names in imports_of_tree(tree, path, root):
        out |= {module} | {f"{module}.{n}" for n in names}
    return out


def imports_of_tree(tree, path: Path, root: Path):
    """:func:`imports` of an already parsed (and pruned) tree."""
    package = module_name(path, root).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, []
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:
                module = ".".join(package[:len(package) - node.level + 1] + ([node.module] if node.module else []))
            yield node.lineno, module, [a.name for a in node.names]


@pytest.mark.parametrize("path", sorted((PACKAGE / "output").glob("*.py")), ids=lambda p: p.name)
def test_output_runs_no_command(path):
    """output/ holds pages, figures and exports: the work of every command is in its stage, a run written with its
    page (select_with_report), an export measured again (remeasure) and the demo in the commands stage above."""
    found = sorted(runtime_imports(path) & RUNS_A_COMMAND)
    assert not found, f"{path.relative_to(ROOT)} imports {', '.join(found)}, which run a command's work"


def test_the_output_check_sees_a_command_run(tmp_path):
    """The check fails on a page module that runs the tuning (as output/tune_report.py did), not on a type."""
    probe = tmp_path / "servofmu" / "output" / "probe.py"
    probe.parent.mkdir(parents=True)
    probe.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ..validation.run import x\n"
                     "from ..tuning.run import Tuning, tune_axis\nfrom ..control import compensation\n")
    assert runtime_imports(probe, root=tmp_path) & RUNS_A_COMMAND == {"servofmu.tuning.run",
                                                                      "servofmu.control.compensation"}


def test_the_tune_defaults_are_written_once():
    """TuneOptions holds tune's defaults; the command line's literal copy (for a numpy-free --help) is compared
    with it in tests/test_cli_options.py.  No other module names them again: no keyword, field or dict entry of
    max_sensitivity, particles or iterations with a default's value, no default stroke or speed."""
    from servofmu.tuning.search import TuneOptions

    defaults = {n: getattr(TuneOptions(), n) for n in ("max_sensitivity", "particles", "iterations")}
    homes = {PACKAGE / "tuning" / "search.py", PACKAGE / "tuning" / "task.py", PACKAGE / "cli" / "tune.py"}
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path in homes:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            pairs = []
            if isinstance(node, ast.keyword):
                pairs = [(node.arg, node.value)]
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                pairs = [(node.target.id, node.value)]
            elif isinstance(node, ast.Dict):
                pairs = [(k.value, v) for k, v in zip(node.keys, node.values) if isinstance(k, ast.Constant)]
            elif isinstance(node, ast.Assign):
                names = [t.id for t in node.targets if isinstance(t, ast.Name)]
                if {"DEFAULT_STROKE", "DEFAULT_SPEED"} & set(names):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {names}")
            found += [f"{path.relative_to(ROOT)}:{v.lineno}: {name} = {v.value!r}" for name, v in pairs
                      if name in defaults and isinstance(v, ast.Constant) and v.value == defaults[name]]
    assert found == []


def test_every_subpackage_is_in_the_wheel():
    """pyproject's package list names every folder of the package (a new stage, validation, was one to add)."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {module_name(p) for p in PACKAGE.rglob("__init__.py")}
    assert found - listed == set()
