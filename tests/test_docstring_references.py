"""Sphinx cross-references in the project's sources point at names that exist.

Every ``:mod:``, ``:func:``, ``:class:``, ``:meth:``, ``:data:``, ``:attr:``, ``:exc:`` and ``:obj:``
role (``~`` and ``text <target>`` forms included, a role may wrap over lines) whose target is a
dotted name in ``teleop``, ``estimator`` or ``haptics`` is resolved: the longest importable module
prefix is imported (each module once), then the rest is looked up with ``getattr``. A last part
``getattr`` misses is still accepted when it is an annotated or dataclass field of the class (or
module), or is assigned as ``self.<name>`` in the class source (instance attributes). A module that
cannot be imported because an optional library is missing skips its references. Relative targets
(``:meth:`.read```, ``:func:`segment_grasp```) are out of scope.

The files are read as text (a regex, no parsing), so references in comments count too.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import inspect
import re
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGES = ("teleop", "estimator", "haptics")
#: The folders scanned: the packages, plus the benchmarks and tests that document against them.
SOURCE_DIRS = (*PACKAGES, "benchmarks", "tests")
#: Libraries that take seconds to import: a module importing one at its top level is read (its
#: syntax tree) rather than imported, which keeps this test fast.
HEAVY = ("torch", "onnx", "onnxscript", "matplotlib")
ROLES = ("mod", "func", "class", "meth", "data", "attr", "exc", "obj")

_ROLE = re.compile(r":(?:py:)?(" + "|".join(ROLES) + r"):`([^`]+)`")
_EXPLICIT = re.compile(r"^(.*?)<([^<>]+)>\s*$", re.DOTALL)
_PROJECT_TARGET = re.compile(r"^(?:" + "|".join(PACKAGES) + r")(?:\.\w+)+$|^(?:"
                             + "|".join(PACKAGES) + r")$")


@dataclass(frozen=True)
class Reference:
    path: str  # relative to the repository root
    line: int
    role: str
    target: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.role} {self.target}"


class _Skip(Exception):
    """The target's module needs an optional library that is not installed."""


def references_in(text: str, path: str) -> list[Reference]:
    """The project-absolute cross-references in one file's text."""
    found = []
    for match in _ROLE.finditer(text):
        role, content = match.group(1), match.group(2)
        explicit = _EXPLICIT.match(content)
        target = explicit.group(2) if explicit else content
        target = re.sub(r"\s+", "", target).lstrip("~!").removesuffix("()")
        if not _PROJECT_TARGET.match(target):
            continue  # relative, or outside the project
        line = text.count("\n", 0, match.start()) + 1
        found.append(Reference(path, line, f":{role}:", target))
    return found


def project_references() -> list[Reference]:
    this = Path(__file__).resolve()
    refs: list[Reference] = []
    for folder in SOURCE_DIRS:
        for file in sorted((REPO / folder).rglob("*.py")):
            if file.resolve() == this:
                continue
            rel = file.relative_to(REPO).as_posix()
            refs.extend(references_in(file.read_text(encoding="utf-8"), rel))
    return refs


@cache
def _module_spec(name: str):
    """The spec of module ``name`` (its parent packages imported, not it); ``None`` if none."""
    try:
        return importlib.util.find_spec(name)
    except ModuleNotFoundError as exc:
        missing = exc.name or ""
        if missing == name or name.startswith(missing + "."):
            return None  # a parent is not a package (an attribute, or a broken reference)
        raise _Skip(f"{name} needs {missing}") from exc
    except ValueError:
        return None


@cache
def _heavy_tree(name: str) -> ast.Module | None:
    """The syntax tree of module ``name`` when it imports a :data:`HEAVY` library at top level."""
    spec = _module_spec(name)
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        return None
    source = Path(spec.origin).read_text(encoding="utf-8")
    heavy = "|".join(HEAVY)
    if not re.search(rf"^(?:import|from)\s+(?:{heavy})\b", source, re.MULTILINE):
        return None
    return ast.parse(source)


@cache
def _import(name: str):
    """Module ``name`` imported; raises :class:`_Skip` when it needs a missing library."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        missing = exc.name or ""
        if missing.split(".")[0] in PACKAGES:
            raise  # a project module importing a project module that is gone: report it
        raise _Skip(f"{name} needs {missing}") from exc


def _static_lookup(tree: ast.Module, parts: list[str]) -> bool:
    """``parts`` defined in a module's syntax tree: top-level names, then class members."""
    body: list[ast.stmt] = tree.body
    cls: ast.ClassDef | None = None
    for k, part in enumerate(parts):
        found = None
        for node in body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                names = [node.name]
            elif isinstance(node, ast.Assign):
                names = [t.id for t in node.targets if isinstance(t, ast.Name)]
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                names = [node.target.id]
            elif isinstance(node, ast.Import | ast.ImportFrom):
                names = [(a.asname or a.name).split(".")[0] for a in node.names]
            else:
                continue
            if part in names:
                found = node
        if found is None:
            last_in_class = cls is not None and k == len(parts) - 1
            return last_in_class and bool(re.search(rf"\bself\.{re.escape(part)}\b",
                                                   ast.unparse(cls)))
        if k < len(parts) - 1:
            if not isinstance(found, ast.ClassDef):
                return False
            cls, body = found, found.body
    return True


def _has_member(owner: object, name: str) -> bool:
    """``getattr`` misses instance attributes and annotation-only fields: look for those too."""
    classes = inspect.getmro(owner) if inspect.isclass(owner) else (owner,)
    for cls in classes:
        if name in getattr(cls, "__annotations__", {}) or name in getattr(
                cls, "__dataclass_fields__", {}):
            return True
    if inspect.isclass(owner):
        for cls in classes:
            if getattr(cls, "__module__", "").split(".")[0] not in PACKAGES:
                continue
            try:
                source = inspect.getsource(cls)
            except (OSError, TypeError):
                continue
            if re.search(rf"\bself\.{re.escape(name)}\b", source):
                return True
    return False


def resolve(target: str) -> str | None:
    """``None`` when ``target`` resolves, else why not; raises :class:`_Skip` for a module that
    needs a missing optional library."""
    parts = target.split(".")
    try:
        # The longest module prefix, found without importing it (only its parent packages).
        i = 0
        while i < len(parts):
            spec = _module_spec(".".join(parts[:i + 1]))
            if spec is None:
                break
            i += 1
            if spec.submodule_search_locations is None:
                break  # a module, not a package: the rest are attributes
        if i == 0:
            return f"no module {parts[0]!r}"
        module_name, rest = ".".join(parts[:i]), parts[i:]
        if not rest:
            return None
        tree = _heavy_tree(module_name)
        if tree is not None:
            return None if _static_lookup(tree, rest) else (
                f"{module_name} (read, not imported) defines no {'.'.join(rest)}")
        obj = _import(module_name)
        for j, attr in enumerate(rest, start=i):
            if hasattr(obj, attr):
                obj = getattr(obj, attr)
            elif j == len(parts) - 1 and _has_member(obj, attr):
                return None
            else:
                return f"{'.'.join(parts[:j])} has no {attr!r}"
        return None
    except _Skip:
        raise
    except Exception as exc:  # noqa: BLE001 - any import failure is a finding
        return f"{type(exc).__name__}: {exc}"


def test_docstring_references_resolve():
    refs = project_references()
    assert refs, "no cross-references found: the scan is broken"
    broken, skipped = [], []
    for ref in refs:
        try:
            why = resolve(ref.target)
        except _Skip as skip:
            skipped.append(f"{ref} ({skip})")
            continue
        if why:
            broken.append(f"{ref}  [{why}]")
    assert not broken, f"{len(broken)} of {len(refs)} cross-references are broken:\n" + "\n".join(
        broken)


@pytest.mark.parametrize("target", [
    "teleop.no_such_module.x",
    "teleop.settings.no_such_name_anywhere",
    "estimator.no_such_module",
    "estimator.training.finetune.no_such_function",  # a torch module: read, not imported
    "estimator.training.finetune.fine_tune.no_such_attribute",
])
def test_made_up_targets_are_reported(target):
    assert resolve(target) is not None


def test_scanner_reads_every_form():
    text = (":func:`teleop.settings.load_settings`\n"
            ":meth:`~teleop.a.B.c` and :class:`words\n <estimator.x.Y>`\n"
            ":func:`segment_grasp` :meth:`.read` :obj:`numpy.ndarray`\n")
    refs = references_in(text, "f.py")
    assert [(r.line, r.role, r.target) for r in refs] == [
        (1, ":func:", "teleop.settings.load_settings"),
        (2, ":meth:", "teleop.a.B.c"),
        (2, ":class:", "estimator.x.Y"),
    ]
    assert resolve("teleop.settings.load_settings") is None
    assert resolve("estimator.training.finetune.fine_tune") is None
