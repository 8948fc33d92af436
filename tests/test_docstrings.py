"""Every public function, class and method of the algorithm core has a numpydoc docstring.

Public: the name does not start with ``_`` and it is defined in the module (module level, or a method of a class
defined there; functions nested in functions are private). Required:

* a summary line (the docstring's first line is not empty);
* for a function or method that takes parameters (``self``/``cls`` not counted): a ``Parameters`` section
  (or ``Other Parameters``) that names each of them (``*args``/``**kwargs`` by their bare names too);
* for one that returns something (a return annotation other than ``None``/``NoReturn``, or, without annotation,
  a ``return <value>``): a ``Returns`` section; a generator needs ``Yields`` instead.

Properties need a summary line only (numpydoc documents them like attributes); ``typing.overload`` stubs are
skipped. The failure message lists every offender as ``module:line name: what's missing``.
"""

from __future__ import annotations

import ast
import inspect
import re
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "oacli"
CORE_PACKAGES = ("model", "geometry", "sets", "control", "planning", "excitation", "estimation", "sim")
CORE_MODULES = ("types.py", "trajectory.py", "reference.py", "metrics.py", "solver.py")

_SECTION = re.compile(r"^\s*(?P<name>[A-Z][A-Za-z ]+)\n\s*-{3,}\s*$", re.MULTILINE)


def core_files() -> list[Path]:
    """The core's source files, sorted."""
    files = [p for pkg in CORE_PACKAGES for p in (ROOT / pkg).rglob("*.py")]
    files += [ROOT / name for name in CORE_MODULES]
    return sorted(files)


@dataclass(frozen=True)
class Gap:
    """One documentation gap."""

    module: str
    line: int
    name: str
    missing: str

    def __str__(self) -> str:
        return f"{self.module}:{self.line} {self.name}: {self.missing}"


def _sections(doc: str) -> dict[str, str]:
    """Numpydoc sections of a cleaned docstring: title -> body (up to the next section)."""
    matches = list(_SECTION.finditer(doc))
    out = {}
    for i, m in enumerate(matches):
        end = matches[i + 1].start() if i + 1 < len(matches) else len(doc)
        out[m.group("name").strip()] = doc[m.end() : end]
    return out


def _documented_names(body: str) -> set[str]:
    """Parameter names of a Parameters section: the entries' heads ``a, b : type`` or ``*args``."""
    names: set[str] = set()
    for line in body.splitlines():
        if not line.strip() or line[:1].isspace():
            continue
        head = line.split(" : ", 1)[0].strip()
        names.update(part.strip().lstrip("*") for part in head.split(","))
    return names


def _decorator_names(node: ast.FunctionDef | ast.AsyncFunctionDef) -> set[str]:
    names = set()
    for dec in node.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        if isinstance(target, ast.Attribute):
            names.add(target.attr)
        elif isinstance(target, ast.Name):
            names.add(target.id)
    return names


def _own_nodes(node: ast.AST) -> list[ast.AST]:
    """The nodes of a function's body, without those of nested functions, lambdas and classes."""
    out = []
    stack = list(ast.iter_child_nodes(node))
    while stack:
        child = stack.pop()
        if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda | ast.ClassDef):
            continue
        out.append(child)
        stack.extend(ast.iter_child_nodes(child))
    return out


def _returns_value(node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    if node.returns is not None:
        ann = ast.unparse(node.returns).strip("'\"")
        return ann not in ("None", "NoReturn", "typing.NoReturn", "Never", "typing.Never")
    return any(
        isinstance(n, ast.Return) and n.value is not None
        and not (isinstance(n.value, ast.Constant) and n.value.value is None)
        for n in _own_nodes(node)
    )


def _is_generator(node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    return any(isinstance(n, ast.Yield | ast.YieldFrom) for n in _own_nodes(node))


def _parameters(node: ast.FunctionDef | ast.AsyncFunctionDef, is_method: bool) -> list[str]:
    a = node.args
    names = [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    if a.vararg is not None:
        names.append(a.vararg.arg)
    if a.kwarg is not None:
        names.append(a.kwarg.arg)
    if is_method and "staticmethod" not in _decorator_names(node) and names and names[0] in ("self", "cls"):
        names = names[1:]
    return names


def _check_function(
    module: str, node: ast.FunctionDef | ast.AsyncFunctionDef, qualname: str, is_method: bool
) -> list[Gap]:
    decorators = _decorator_names(node)
    if "overload" in decorators:
        return []
    doc = ast.get_docstring(node)
    if not doc or not doc.strip().splitlines()[0].strip():
        return [Gap(module, node.lineno, qualname, "docstring with a summary line")]
    if "property" in decorators or "cached_property" in decorators or "setter" in decorators:
        return []
    doc = inspect.cleandoc(doc)
    sections = _sections(doc)
    missing = []
    params = _parameters(node, is_method)
    if params:
        body = sections.get("Parameters", "") + "\n" + sections.get("Other Parameters", "")
        if "Parameters" not in sections and "Other Parameters" not in sections:
            missing.append("Parameters section")
        else:
            undocumented = [p for p in params if p not in _documented_names(body)]
            if undocumented:
                missing.append("Parameters entries for " + ", ".join(undocumented))
    if _is_generator(node):
        if "Yields" not in sections:
            missing.append("Yields section")
    elif _returns_value(node) and "Returns" not in sections:
        missing.append("Returns section")
    return [Gap(module, node.lineno, qualname, "; ".join(missing))] if missing else []


def _check_class(module: str, node: ast.ClassDef, prefix: str = "") -> list[Gap]:
    qualname = prefix + node.name
    gaps = []
    doc = ast.get_docstring(node)
    if not doc or not doc.strip().splitlines()[0].strip():
        gaps.append(Gap(module, node.lineno, qualname, "docstring with a summary line"))
    for child in node.body:
        if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef) and not child.name.startswith("_"):
            gaps += _check_function(module, child, f"{qualname}.{child.name}", is_method=True)
        elif isinstance(child, ast.ClassDef) and not child.name.startswith("_"):
            gaps += _check_class(module, child, prefix=qualname + ".")
    return gaps


def docstring_gaps(path: Path) -> list[Gap]:
    """Every gap of one source file of the package."""
    module = ".".join(path.relative_to(ROOT.parent).with_suffix("").parts)
    return gaps_in_source(path.read_text(encoding="utf-8"), module)


def gaps_in_source(source: str, module: str) -> list[Gap]:
    """Every gap of one module's source text."""
    tree = ast.parse(source, filename=module)
    gaps: list[Gap] = []
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not node.name.startswith("_"):
            gaps += _check_function(module, node, node.name, is_method=False)
        elif isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
            gaps += _check_class(module, node)
    return gaps


def test_core_files_found():
    files = core_files()
    assert len(files) > 40
    assert all(p.is_file() for p in files)


def test_every_public_callable_has_a_numpydoc_docstring():
    gaps = [gap for path in core_files() for gap in docstring_gaps(path)]
    assert not gaps, f"{len(gaps)} public functions/classes/methods lack numpydoc parts:\n" + "\n".join(map(str, gaps))


# -- the checker itself ----------------------------------------------------------------------------------------

_GOOD = '''
def f(a, *args, b=1, **kwargs) -> int:
    """Summary.

    Parameters
    ----------
    a, b : int
        Numbers.
    *args, **kwargs
        More.

    Returns
    -------
    int
    """
    return a


def g():
    """Nothing in, nothing out."""


class C:
    """A class."""

    def m(self, x: float) -> None:
        """Set.

        Parameters
        ----------
        x : float
        """

    @property
    def p(self) -> int:
        """A property."""
        return 1

    def gen(self):
        """Numbers.

        Yields
        ------
        int
        """
        yield 1

    def _private(self, y):
        return y


def _hidden(z):
    return z
'''

_BAD = '''
def no_doc(a):
    return a


def no_params(a) -> float:
    """Summary.

    Returns
    -------
    float
    """


def partial(a, b):
    """Summary.

    Parameters
    ----------
    a : int
    """


def no_returns(a):
    """Summary.

    Parameters
    ----------
    a : int
    """
    def inner():
        return 1
    return a + inner()


class D:
    def gen(self):
        """Numbers."""
        yield 1
'''


@pytest.mark.parametrize(("source", "expected"), [
    (_GOOD, []),
    (_BAD, [
        "m:2 no_doc: docstring with a summary line",
        "m:6 no_params: Parameters section",
        "m:15 partial: Parameters entries for b",
        "m:24 no_returns: Returns section",
        "m:36 D: docstring with a summary line",
        "m:37 D.gen: Yields section",
    ]),
])
def test_checker_on_known_sources(source, expected):
    assert [str(gap) for gap in gaps_in_source(source, "m")] == expected
