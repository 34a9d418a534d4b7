"""The import graph between ``teleop``, ``estimator`` and ``haptics``, read from the source.

Every module is parsed with :mod:`ast`, never imported. Counted as imports: ``import x`` and
``from x import y`` anywhere in a module (top level, inside functions, under ``TYPE_CHECKING``),
relative ones resolved, plus *dynamic* ones: a string literal that is exactly a project module
path (``"pkg.mod"`` or ``"pkg.mod:Class"``), as in the CLI command tables and backend tables.

Layers (the rules tested):

``teleop`` (the shared base: every module of ``teleop`` except ``teleop.system``)
    imports neither ``estimator`` nor ``haptics``, statically or dynamically, and does not
    statically import ``teleop.system``. Its CLI command table (strings) is the one way in
    to the system commands.
``haptics``
    imports the base only.
``estimator``
    imports the base, and ``haptics`` outside its run time (``estimator.evaluation.metrics``
    scores estimates with the display's own mapping, ``haptics.mapping``); ``haptics`` never
    imports ``estimator``.
``teleop.system``
    the commands that tie the three together: may import anything; nothing but the base's
    command table refers to it.

So the static package graph is a chain with no cycle: teleop.system -> estimator -> haptics -> teleop.

Inside ``estimator``, layers by lifecycle:

the run time (every estimator module outside the two below: the service, fits, perception, inference)
    imports neither ``estimator.training`` nor ``estimator.evaluation`` (its CLI command table,
    ``estimator.cli``, names their command modules as strings: the one way in), nor ``haptics``,
    nor a training or plotting library (torch, onnx, onnxscript, matplotlib), even inside a function.
``estimator.evaluation``
    imports the run time; never ``estimator.training``.
``estimator.training``
    imports the run time and ``estimator.evaluation`` (a model's scores, a fine-tune's comparison).

Beside the graph, each live process's command module is imported in a fresh interpreter: training
(torch, onnx) and plotting (matplotlib) never load in a live service, nor the packages it does not run.
"""

from __future__ import annotations

import ast
import functools
import json
import subprocess
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGES = ("teleop", "estimator", "haptics")
SYSTEM = "teleop.system"

#: The package-level imports allowed besides a package importing itself: (importer, imported).
ALLOWED = frozenset({
    ("estimator", "teleop"),
    ("haptics", "teleop"),
    ("estimator", "haptics"),
    (SYSTEM, "teleop"),
    (SYSTEM, "estimator"),
    (SYSTEM, "haptics"),
})
#: Allowed only as a dynamic (string) import: the base's CLI command table naming system commands.
ALLOWED_DYNAMIC = frozenset({("teleop", SYSTEM)})

#: The estimator's layers by lifecycle besides its run time: subpackage -> layer name.
ESTIMATOR_LAYERS = {"estimator.training": "training", "estimator.evaluation": "evaluation"}
#: The imports between the estimator's layers allowed besides a layer importing itself: (importer, imported).
ESTIMATOR_ALLOWED = frozenset({
    ("evaluation", "runtime"),
    ("training", "runtime"),
    ("training", "evaluation"),
})
#: The estimator's CLI command table: the one run-time module that names training and evaluation
#: modules, as strings only.
ESTIMATOR_CLI = "estimator.cli"
#: Libraries of training and plotting that the estimator's run time never imports.
NOT_AT_RUN_TIME = ("torch", "onnx", "onnxscript", "matplotlib")


@dataclass(frozen=True)
class Import:
    module: str  # the importing module, e.g. "teleop.cli"
    path: str  # its file, relative to the repository
    line: int
    target: str  # the imported module, e.g. "estimator.training.samples"
    dynamic: bool = False  # a string module path, not an import statement

    def __str__(self) -> str:
        how = "names the module path" if self.dynamic else "imports"
        return f"{self.path}:{self.line} ({self.module}) {how} {self.target}"


# ---------------------------------------------------------------------------- collecting


def module_files(root: Path, packages: Iterable[str] = PACKAGES) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` file under each package folder of ``root``."""
    files = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            files[".".join(parts)] = path
    return files


def _resolve_relative(module: str, is_package: bool, level: int, name: str | None) -> str:
    base = module.split(".") if is_package else module.split(".")[:-1]
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join([*base, *([name] if name else [])])


def _module_path_in(text: str, known: Iterable[str]) -> str | None:
    """``text`` as a project module (``"pkg.mod"`` or ``"pkg.mod:attr"``), or None."""
    name = text.partition(":")[0]
    return name if name in known and "." in name else None


def collect_imports(root: Path, packages: Iterable[str] = PACKAGES, of: Iterable[str] | None = None) -> list[Import]:
    """Every import (static and dynamic) of a project package made by a module under ``root``;
    with ``of``, the (static) imports of those top-level packages instead, e.g. ``("torch",)``."""
    packages = tuple(packages)
    wanted = packages if of is None else tuple(of)
    files = module_files(root, packages)
    found = []
    for module, path in files.items():
        rel = str(path.relative_to(root))
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=rel)
        for node in ast.walk(tree):
            targets: list[str] = []
            dynamic = False
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                source = (_resolve_relative(module, path.name == "__init__.py", node.level, node.module)
                          if node.level else node.module or "")
                # ``from pkg import sub`` imports the submodule ``pkg.sub`` when there is one.
                subs = [f"{source}.{a.name}" for a in node.names if f"{source}.{a.name}" in files]
                targets = subs or [source]
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                target = _module_path_in(node.value, files)
                targets, dynamic = ([target], True) if target else ([], False)
            for target in targets:
                if target.split(".")[0] in wanted:
                    found.append(Import(module, rel, node.lineno, target, dynamic))
    return sorted(found, key=lambda i: (i.path, i.line, i.target))


@functools.cache
def project_imports(of: tuple[str, ...] | None = None) -> tuple[Import, ...]:
    """:func:`collect_imports` of the project, parsed once per worker for all the tests that read it."""
    return tuple(collect_imports(REPO, of=of))


# ---------------------------------------------------------------------------- the rules


def layer(module: str) -> str:
    """The layer of a module: ``teleop.system``, or its top package (``teleop`` being the base)."""
    if module == SYSTEM or module.startswith(SYSTEM + "."):
        return SYSTEM
    return module.split(".")[0]


def layering_violations(imports: Iterable[Import]) -> list[str]:
    """One line per import that crosses layers in a way :data:`ALLOWED` does not allow."""
    bad = []
    for imp in imports:
        edge = (layer(imp.module), layer(imp.target))
        if edge[0] == edge[1] or edge in ALLOWED or (imp.dynamic and edge in ALLOWED_DYNAMIC):
            continue
        bad.append(f"{imp}: {edge[0]} may not depend on {edge[1]}")
    return bad


def estimator_layer(module: str) -> str | None:
    """The estimator layer of a module (``runtime``, ``training``, ``evaluation``); None outside ``estimator``."""
    if module.split(".")[0] != "estimator":
        return None
    return next((name for package, name in ESTIMATOR_LAYERS.items()
                 if module == package or module.startswith(package + ".")), "runtime")


def estimator_violations(imports: Iterable[Import]) -> list[str]:
    """One line per import of an estimator module that crosses its layers in a way
    :data:`ESTIMATOR_ALLOWED` does not allow, or by which its run time depends on ``haptics``."""
    bad = []
    for imp in imports:
        source, target = estimator_layer(imp.module), estimator_layer(imp.target)
        if source is None:
            continue
        if target is None:
            if source == "runtime" and layer(imp.target) == "haptics":
                bad.append(f"{imp}: the estimator's run time may not depend on haptics")
            continue
        if source == target or (source, target) in ESTIMATOR_ALLOWED:
            continue
        if imp.dynamic and imp.module == ESTIMATOR_CLI:
            continue
        bad.append(f"{imp}: estimator {source} may not depend on estimator {target}")
    return bad


def package_cycles(imports: Iterable[Import]) -> list[str]:
    """Each cycle among the layers through static imports, with the imports that close it."""
    edges: dict[str, dict[str, Import]] = {}
    for imp in imports:
        a, b = layer(imp.module), layer(imp.target)
        if a != b and not imp.dynamic:
            edges.setdefault(a, {}).setdefault(b, imp)
    cycles, seen = [], set()

    def walk(node: str, stack: list[str]) -> None:
        for nxt in sorted(edges.get(node, {})):
            if nxt in stack:
                cycle = stack[stack.index(nxt):] + [nxt]
                key = frozenset(zip(cycle, cycle[1:], strict=False))
                if key not in seen:
                    seen.add(key)
                    hops = "; ".join(str(edges[x][y]) for x, y in zip(cycle, cycle[1:], strict=False))
                    cycles.append(f"{' -> '.join(cycle)} (through: {hops})")
            else:
                walk(nxt, [*stack, nxt])

    for start in sorted(edges):
        walk(start, [start])
    return cycles


def _report(title: str, problems: list[str]) -> str:
    return f"{title}:\n  " + "\n  ".join(problems)


# ---------------------------------------------------------------------------- the project


def test_the_project_has_the_modules_the_rules_speak_of():
    files = module_files(REPO)
    assert {"teleop.system", "teleop.system.demo", "teleop.clikit", "estimator.errors", "haptics.errors"} <= set(files)
    assert len(project_imports()) > 50


def test_the_shared_base_imports_neither_estimator_nor_haptics():
    bad = [f"{imp}" for imp in project_imports()
           if layer(imp.module) == "teleop" and layer(imp.target) in ("estimator", "haptics")]
    assert not bad, _report("the shared base (teleop outside teleop.system) imports", bad)


def test_every_import_across_packages_is_an_allowed_one():
    bad = layering_violations(project_imports())
    assert not bad, _report("imports across layers that the layering does not allow", bad)


def test_no_import_cycle_between_the_packages():
    cycles = package_cycles(project_imports())
    assert not cycles, _report("import cycles between the packages", cycles)


def test_the_estimators_layers_by_lifecycle():
    imports = project_imports()
    layers = {estimator_layer(imp.module) for imp in imports}
    assert {"runtime", "training", "evaluation"} <= layers
    bad = estimator_violations(imports)
    assert not bad, _report("imports across the estimator's layers (run time <- evaluation <- training)", bad)


@pytest.mark.slow
def test_the_estimator_run_time_imports_no_training_or_plotting_library():
    bad = [f"{imp}" for imp in project_imports(tuple(NOT_AT_RUN_TIME)) if estimator_layer(imp.module) == "runtime"]
    assert not bad, _report("the estimator's run time imports", bad)
    assert project_imports(("torch",)), "the training imports torch: the check reads third-party imports"


def test_the_cli_kit_catches_one_error_base():
    from estimator.errors import EstimatorError, SampleError
    from haptics.errors import HapticsError, MappingError
    from teleop.errors import ComplianceTeleopError, MessageRejected, TeleopError

    for error in (TeleopError, EstimatorError, HapticsError, SampleError, MappingError, MessageRejected):
        assert issubclass(error, ComplianceTeleopError), error
    kit = [imp for imp in project_imports() if imp.module == "teleop.clikit"]
    assert {imp.target for imp in kit} == {"teleop.errors"}, [str(i) for i in kit]


# ---------------------------------------------------------------------------- the checks can fail


def _tree(root: Path, files: Mapping[str, str]) -> Path:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


BAD_TREE = {
    "teleop/__init__.py": "",
    "teleop/errors.py": "class ComplianceTeleopError(Exception):\n    pass\n",
    "teleop/bad_top.py": "from estimator.samples import save_sample\n",
    "teleop/sub/__init__.py": "",
    "teleop/sub/bad_inner.py": "def f():\n    from ..system import demo\n    import haptics.mapping\n",
    "teleop/bad_table.py": 'COMMANDS = {"x": ("estimator.samples", "help")}\n',
    "teleop/bad_system.py": "from teleop.system import demo\n",
    "teleop/cli.py": 'COMMANDS = {"demo": ("teleop.system.demo", "help")}\n',
    "teleop/system/__init__.py": "",
    "teleop/system/demo.py": "from . import helper\nimport estimator.samples\nimport haptics.mapping\n",
    "teleop/system/helper.py": "",
    "estimator/__init__.py": "",
    "estimator/samples.py": "from teleop.errors import ComplianceTeleopError\n",
    "estimator/cli.py": 'COMMANDS = {"train": ("estimator.training.train", "help")}\n',
    "estimator/bad_up.py": "def f():\n    from estimator.training import train\n",
    "estimator/bad_table.py": 'METRICS = "estimator.evaluation.metrics:summarise"\n',
    "estimator/bad_display.py": "import haptics.mapping\n",
    "estimator/bad_torch.py": "def f():\n    import torch.nn\n",
    "estimator/evaluation/__init__.py": "",
    "estimator/evaluation/metrics.py": "from estimator import samples\nfrom haptics import mapping\n",
    "estimator/evaluation/bad_down.py": "from ..training.train import fit\n",
    "estimator/training/__init__.py": "",
    "estimator/training/train.py": "import torch\nfrom estimator.evaluation import metrics\nimport estimator.samples\n",
    "haptics/__init__.py": "",
    "haptics/mapping.py": "from teleop.errors import ComplianceTeleopError\n",
    "haptics/bad_back.py": "def f():\n    from estimator import samples\n",
}


def test_collect_imports_finds_every_kind_of_import(tmp_path):
    got = {(i.module, i.target, i.dynamic) for i in collect_imports(_tree(tmp_path, BAD_TREE))}
    assert ("teleop.bad_top", "estimator.samples", False) in got
    # function level, relative (resolved) and absolute
    assert ("teleop.sub.bad_inner", "teleop.system.demo", False) in got
    assert ("teleop.sub.bad_inner", "haptics.mapping", False) in got
    assert ("teleop.bad_table", "estimator.samples", True) in got
    assert ("teleop.bad_system", "teleop.system.demo", False) in got
    assert ("teleop.system.demo", "teleop.system.helper", False) in got
    assert ("haptics.bad_back", "estimator.samples", False) in got
    assert ("estimator.evaluation.bad_down", "estimator.training.train", False) in got
    assert ("estimator.bad_table", "estimator.evaluation.metrics", True) in got
    torch = {(i.module, i.target) for i in collect_imports(tmp_path, of=NOT_AT_RUN_TIME)}
    assert torch == {("estimator.bad_torch", "torch.nn"), ("estimator.training.train", "torch")}


def test_the_rules_fail_on_a_bad_tree_and_name_the_module_and_import(tmp_path):
    imports = collect_imports(_tree(tmp_path, BAD_TREE))
    bad = layering_violations(imports)
    text = "\n".join(bad)
    for needle in (
        "teleop/bad_top.py:1 (teleop.bad_top) imports estimator.samples",
        "teleop/sub/bad_inner.py:2 (teleop.sub.bad_inner) imports teleop.system.demo",
        "teleop/sub/bad_inner.py:3 (teleop.sub.bad_inner) imports haptics.mapping: teleop may not depend on haptics",
        "teleop/bad_table.py:1 (teleop.bad_table) names the module path estimator.samples",
        "teleop/bad_system.py:1 (teleop.bad_system) imports teleop.system.demo",
        "haptics/bad_back.py:2 (haptics.bad_back) imports estimator.samples: haptics may not depend on estimator",
    ):
        assert needle in text, text
    # Allowed: system importing everything, the CLI table naming a system command, estimator -> haptics.
    assert not any(s in text for s in ("(teleop.system.demo)", "(teleop.cli)", "(estimator.evaluation.metrics)")), text
    with_cycle = "\n".join(package_cycles(imports))
    assert "estimator -> haptics -> estimator" in with_cycle or "haptics -> estimator -> haptics" in with_cycle
    assert "(haptics.bad_back) imports estimator.samples" in with_cycle
    assert "teleop -> estimator -> teleop" in with_cycle or "estimator -> teleop -> estimator" in with_cycle


def test_the_estimator_rules_fail_on_a_bad_tree_and_name_the_module_and_import(tmp_path):
    text = "\n".join(estimator_violations(collect_imports(_tree(tmp_path, BAD_TREE))))
    for needle in (
        "estimator/bad_up.py:2 (estimator.bad_up) imports estimator.training.train: "
        "estimator runtime may not depend on estimator training",
        "estimator/bad_table.py:1 (estimator.bad_table) names the module path estimator.evaluation.metrics: "
        "estimator runtime may not depend on estimator evaluation",
        "estimator/bad_display.py:1 (estimator.bad_display) imports haptics.mapping: "
        "the estimator's run time may not depend on haptics",
        "estimator/evaluation/bad_down.py:1 (estimator.evaluation.bad_down) imports estimator.training.train: "
        "estimator evaluation may not depend on estimator training",
    ):
        assert needle in text, text
    # Allowed: the command table naming a training module, training -> evaluation -> run time, evaluation -> haptics.
    assert not any(s in text for s in ("(estimator.cli)", "(estimator.training.train)",
                                       "(estimator.evaluation.metrics)", "(haptics.")), text


def test_the_rules_pass_a_clean_tree(tmp_path):
    clean = {k: v for k, v in BAD_TREE.items() if "/bad_" not in k}
    imports = collect_imports(_tree(tmp_path, clean))
    assert layering_violations(imports) == []
    assert estimator_violations(imports) == []
    assert package_cycles(imports) == []


@pytest.mark.slow
@pytest.mark.parametrize(("module", "absent"), [
    # The service reads calibrations; fitting them (and the press sets they are fitted on) is tooling.
    ("estimator.service_cli", ("torch", "matplotlib", "onnx", "haptics", "estimator.training", "estimator.evaluation",
                               "estimator.perception.calibration_fit", "estimator.perception.presses")),
    ("teleop.node_cli", ("torch", "matplotlib", "estimator", "haptics")),
    ("haptics.service_cli", ("torch", "matplotlib", "estimator")),
    ("haptics.operate_cli", ("torch", "matplotlib", "estimator")),
])
def test_a_live_process_loads_only_what_it_runs(module, absent):
    # A fresh interpreter, as the process starts: training and plotting never load in a live service.
    code = ("import importlib, json, sys; importlib.import_module(sys.argv[1]); "
            "print(json.dumps(sorted(sys.modules)))")
    done = subprocess.run([sys.executable, "-c", code, module], capture_output=True, text=True, timeout=120, check=True)
    loaded = json.loads(done.stdout)
    found = sorted({a for a in absent for name in loaded if name == a or name.startswith(a + ".")})
    assert not found, f"{module} loads {found}"
