"""The package's import structure: no import circle anywhere in ``hysteresis_lab``, and the
loop package runs no command (its checks and its diagnosis read run folders and arrays; the
console app runs the loop, in-process from a script: `hysteresis_lab.cli.loop.run_fresh_loop`).

Read from the source with `ast`, imports inside functions included (a lazy import still ties
two modules into one circle)."""

from __future__ import annotations

import ast
from pathlib import Path

import hysteresis_lab

SRC = Path(hysteresis_lab.__file__).resolve().parents[1]
#: modules that start or replace processes
PROCESS_MODULES = ("subprocess", "multiprocessing", "pty")
#: ``os`` functions that start or replace processes (by prefix)
PROCESS_CALLS = ("system", "popen", "exec", "spawn", "fork", "posix_spawn")
#: what the loop's pure analysis may not import: the layers that run fits and commands
ABOVE_DIAGNOSIS = ("hysteresis_lab.cli", "hysteresis_lab.workflows", "hysteresis_lab.fitting",
                   "hysteresis_lab.lightning_trainer", "hysteresis_lab.api",
                   "hysteresis_lab.loop.driver", "hysteresis_lab.loop.checks")


def modules(src: Path, package: str) -> dict[str, Path]:
    """Every module of ``package`` under ``src`` by dotted name (a package by its own name)."""
    found = {}
    for file in (src / package.replace(".", "/")).rglob("*.py"):
        parts = list(file.relative_to(src).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        found[".".join(parts)] = file
    return found


def imported_names(file: Path) -> set[str]:
    """The dotted names ``file`` imports, anywhere in it (``from a import b``: ``a.b``)."""
    names = set()
    for node in ast.walk(ast.parse(file.read_text(), filename=str(file))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def import_graph(src: Path, package: str) -> dict[str, set[str]]:
    """Module -> the modules of ``package`` it imports (a name resolves to its longest
    module prefix: ``from a import f`` is ``a``, ``from a import b`` the module ``a.b``)."""
    known = modules(src, package)

    def module_of(name: str) -> str | None:
        while name and name not in known:
            name = name.rpartition(".")[0]
        return name or None

    return {
        name: {m for n in imported_names(file) if (m := module_of(n)) and m != name}
        for name, file in known.items()
    }


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, edges = work[-1]
            for nxt in edges:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph.get(nxt, ())))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    group = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        group.append(member)
                        if member == node:
                            break
                    if len(group) > 1:
                        found.append(sorted(group))
    return found


def process_uses(file: Path) -> list[str]:
    """Where ``file`` imports a process module or calls an ``os`` process function."""
    tree = ast.parse(file.read_text(), filename=str(file))
    uses = [f"{file.name}:{node.lineno}: imports {name}"
            for node in ast.walk(tree) if isinstance(node, ast.Import | ast.ImportFrom)
            for name in ([a.name for a in node.names] if isinstance(node, ast.Import)
                         else [node.module or ""])
            if name.split(".")[0] in PROCESS_MODULES]
    uses += [f"{file.name}:{node.lineno}: calls os.{node.func.attr}"
             for node in ast.walk(tree)
             if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
             and isinstance(node.func.value, ast.Name) and node.func.value.id == "os"
             and node.func.attr.startswith(PROCESS_CALLS)]
    uses += [f"{file.name}:{node.lineno}: imports os.{alias.name}"
             for node in ast.walk(tree)
             if isinstance(node, ast.ImportFrom) and node.module == "os"
             for alias in node.names if alias.name.startswith(PROCESS_CALLS)]
    return uses


def test_the_package_has_no_import_circle():
    graph = import_graph(SRC, "hysteresis_lab")
    assert "hysteresis_lab.loop.driver" in graph and graph["hysteresis_lab.models.io"]
    assert circles(graph) == []


def test_the_loop_package_runs_no_command():
    files = modules(SRC, "hysteresis_lab.loop")
    assert {"hysteresis_lab.loop.checks", "hysteresis_lab.loop.diagnosis.ranking"} <= set(files)
    assert [use for file in files.values() for use in process_uses(file)] == []


def test_the_loop_diagnosis_imports_nothing_that_runs_fits_or_commands():
    graph = import_graph(SRC, "hysteresis_lab")
    pure = {name: deps for name, deps in graph.items()
            if name.startswith("hysteresis_lab.loop.diagnosis")}
    assert "hysteresis_lab.loop.diagnosis.ranking" in pure
    assert {name: sorted(d for d in deps if d.startswith(ABOVE_DIAGNOSIS))
            for name, deps in pure.items()} == {name: [] for name in pure}


def test_the_checks_find_a_lazy_circle_and_a_command(tmp_path):
    """What the tests above look for, planted in a package of two modules."""
    package = tmp_path / "planted"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("from planted.b import g\n\ndef f():\n    return g()\n")
    (package / "b.py").write_text(
        "import os\n\ndef g():\n    from planted import a\n    os.system('true')\n"
        "    return a\n\ndef h():\n    import subprocess\n    return subprocess\n")
    graph = import_graph(tmp_path, "planted")
    assert circles(graph) == [["planted.a", "planted.b"]]
    assert process_uses(package / "b.py") == ["b.py:9: imports subprocess",
                                              "b.py:5: calls os.system"]
    assert process_uses(package / "a.py") == []
