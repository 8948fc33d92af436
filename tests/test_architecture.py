"""The package's layering: no import cycle between oacli modules, and an algorithm core that stays free of the CLI,
the recorders and the run-folder I/O.

Imports are read from the source with :mod:`ast` (module level and inside functions alike: a cycle through a lazy
import is still a cycle), ``from package import name`` counts as an import of the submodule when ``name`` is one,
otherwise of the package. The core is {model, geometry, sets, control, planning, excitation, estimation, sim} and
the modules types, trajectory, reference, metrics, status and solver; it must not import typer, rerun, mcap or foxglove,
nor oacli.io, oacli.stages, oacli.commands or oacli.cli, directly or through another oacli module (importing a
module also runs its parent packages' ``__init__``, so those count too). A second check imports the whole core in
a fresh interpreter and looks at ``sys.modules``.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORE = ("model", "geometry", "sets", "control", "planning", "excitation", "estimation", "sim", "types", "trajectory",
        "reference", "metrics", "status", "solver")
FORBIDDEN_LIBRARIES = ("typer", "rerun", "mcap", "foxglove")
FORBIDDEN_OACLI = ("oacli.io", "oacli.stages", "oacli.commands", "oacli.cli")


def module_files(package_dir: Path) -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, is_package) for every ``.py`` file below ``package_dir``."""
    out = {}
    for path in sorted(package_dir.rglob("*.py")):
        parts = list(path.relative_to(package_dir.parent).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        out[".".join(parts)] = (path, is_package)
    return out


def import_graph(package_dir: Path) -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """Imports of every module of the package: (internal edges module -> modules, external top-level names)."""
    modules = module_files(package_dir)
    top = package_dir.name

    def resolve(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    internal: dict[str, set[str]] = {}
    external: dict[str, set[str]] = {}
    for name, (path, is_package) in modules.items():
        deps: set[str | None] = set()
        libs: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.split(".")[0] == top:
                        deps.add(resolve(alias.name))
                    else:
                        libs.add(alias.name.split(".")[0])
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = name.split(".") if is_package else name.split(".")[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    source = ".".join(base + ([node.module] if node.module else []))
                else:
                    source = node.module or ""
                if source.split(".")[0] != top:
                    libs.add(source.split(".")[0])
                    continue
                for alias in node.names:
                    sub = f"{source}.{alias.name}"
                    deps.add(sub if sub in modules else resolve(source))
        deps.discard(None)
        deps.discard(name)
        internal[name] = {d for d in deps if d is not None}
        external[name] = libs - {"__future__"}
    return internal, external


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted; sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def path_to(graph: dict[str, set[str]], start: str, goal: str) -> list[str]:
    """One import chain start -> ... -> goal (breadth first)."""
    previous = {start: start}
    queue = [start]
    while queue:
        v = queue.pop(0)
        if v == goal:
            chain = [v]
            while chain[-1] != start:
                chain.append(previous[chain[-1]])
            return chain[::-1]
        for w in sorted(graph.get(v, ())):
            if w not in previous:
                previous[w] = v
                queue.append(w)
    return []


def with_parent_packages(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """Importing ``a.b.c`` runs ``a/__init__`` and ``a/b/__init__`` too: add those edges."""
    out = {}
    for name, deps in graph.items():
        extra = set()
        for dep in deps | {name}:
            parts = dep.split(".")
            extra.update(".".join(parts[:i]) for i in range(1, len(parts)))
        out[name] = (deps | extra) - {name}
    return out


def core_modules(graph: dict[str, set[str]]) -> list[str]:
    return sorted(m for m in graph if m.split(".")[1:2] and m.split(".")[1] in CORE)


def test_no_import_cycle_between_oacli_modules():
    internal, _ = import_graph(ROOT / "oacli")
    assert len(internal) > 100  # the whole package was read
    found = cycles(internal)
    assert not found, "import cycles (each group imports itself through the others):\n" + "\n".join(
        " -> ".join([*c, c[0]]) if len(c) == 2 else ", ".join(c) for c in found
    )


def test_core_imports_no_cli_recorder_or_io_even_indirectly():
    internal, external = import_graph(ROOT / "oacli")
    graph = with_parent_packages(internal)
    core = core_modules(graph)
    assert {m.split(".")[1] for m in core} == set(CORE)
    problems = []
    for module in core:
        reached = {module}
        queue = [module]
        while queue:
            for dep in graph[queue.pop()]:
                if dep not in reached:
                    reached.add(dep)
                    queue.append(dep)
        for dep in sorted(reached):
            if any(dep == f or dep.startswith(f + ".") for f in FORBIDDEN_OACLI):
                problems.append(" -> ".join(path_to(graph, module, dep)))
            for lib in sorted(external[dep] & set(FORBIDDEN_LIBRARIES)):
                problems.append(" -> ".join(path_to(graph, module, dep)) + f" imports {lib}")
    assert not problems, "the core reaches the CLI, a recorder or the run-folder I/O:\n" + "\n".join(problems)


LAYERS = ("oacli.io", "oacli.stages", "oacli.mission", "oacli.campaign", "oacli.report", "oacli.commands",
          "oacli.cli")
"""The I/O and orchestration layers, lowest first: each may import the ones before it (and the core), never one
after it (``oacli plots`` redraws from a run folder through the stages' config readers, so it is a stage module,
:mod:`oacli.stages.replot`; the mission's recording is the mission's, :mod:`oacli.mission.recording`; ``oacli report``
reads missions and campaigns, so it sits above both, and the commands call it after a run)."""


def _layer(module: str) -> int | None:
    return next((i for i, p in enumerate(LAYERS) if module == p or module.startswith(p + ".")), None)


def test_io_and_orchestration_layers_import_only_downwards():
    internal, _ = import_graph(ROOT / "oacli")
    upward = sorted(f"{m} -> {d}" for m, deps in internal.items() for d in deps
                    if _layer(m) is not None and _layer(d) is not None and _layer(d) > _layer(m))
    assert not upward, "imports that run up the layers " + " < ".join(LAYERS) + ":\n" + "\n".join(upward)


def test_controllers_do_not_import_the_simulator():
    """The simulator runs controllers (the protocol and its step type live in oacli.types), not the reverse."""
    internal, _ = import_graph(ROOT / "oacli")
    sideways = sorted(f"{m} -> {d}" for m, deps in internal.items() if m.startswith("oacli.control")
                      for d in deps if d == "oacli.sim" or d.startswith("oacli.sim."))
    assert not sideways, sideways


def test_core_loads_without_cli_recorder_or_io_modules():
    """Import every core module in a fresh interpreter; none of the forbidden modules may be loaded."""
    internal, _ = import_graph(ROOT / "oacli")
    code = (
        "import importlib, json, sys\n"
        f"for name in {core_modules(internal)!r}:\n"
        "    importlib.import_module(name)\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          check=True)
    loaded = json.loads(proc.stdout)
    assert "oacli.control.mpc" in loaded and "oacli.excitation.design" in loaded
    bad = [m for m in loaded
           if m.split(".")[0] in FORBIDDEN_LIBRARIES or any(m == f or m.startswith(f + ".") for f in FORBIDDEN_OACLI)]
    assert not bad, f"loaded by the core: {bad}"


# -- the checks themselves can fail ------------------------------------------------------------------------------


def _write(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root / "pkg"


def test_the_checker_finds_cycles_through_packages_relative_and_lazy_imports(tmp_path):
    pkg = _write(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/a.py": "from pkg.sub import b\n",
        "pkg/sub/__init__.py": "from .c import thing\n",
        "pkg/sub/b.py": "def f():\n    from ..d import g\n",
        "pkg/sub/c.py": "import numpy\nthing = 1\n",
        "pkg/d.py": "import pkg.a\nimport typer\n",
        "pkg/e.py": "from pkg.sub import thing\n",
    })
    internal, external = import_graph(pkg)
    assert internal["pkg.a"] == {"pkg.sub.b"}
    assert internal["pkg.sub.b"] == {"pkg.d"}
    assert internal["pkg.sub"] == {"pkg.sub.c"}
    assert internal["pkg.e"] == {"pkg.sub"}
    assert external["pkg.d"] == {"typer"} and external["pkg.sub.c"] == {"numpy"}
    assert cycles(internal) == [["pkg.a", "pkg.d", "pkg.sub.b"]]
    assert path_to(internal, "pkg.a", "pkg.d") == ["pkg.a", "pkg.sub.b", "pkg.d"]
    assert "pkg.sub" in with_parent_packages(internal)["pkg.a"]
    del internal["pkg.d"]
    assert cycles(internal) == []
