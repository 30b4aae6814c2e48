"""The package's shape: no import cycle, each shared fact defined in one module.

These read the source (AST and text), not the running code: a second definition of a
constant or an import that closes a cycle fails here before it confuses a reader.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "usb2rc"


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def imports_of(path: Path, known: set[str]) -> set[str]:
    """Every usb2rc module this one imports, at any depth in the file (lazy imports too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        found |= {name for name in names if name in known}
    return found


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while (w := stack.pop()) != v:
                component.append(w)
            if component:
                found.append(sorted([v, *component]))

    for v in graph:
        if v not in index:
            visit(v)
    return found


def test_no_import_cycle_in_the_package() -> None:
    mods = modules()
    graph = {name: imports_of(path, set(mods)) - {name} for name, path in mods.items()}
    assert cycles(graph) == []


def definitions(pattern: str) -> list[str]:
    """`module: line` for every line of the package that matches `pattern`."""
    rx = re.compile(pattern)
    return [
        f"{module_name(path)}: {line.strip()}"
        for path in modules().values()
        for line in path.read_text().splitlines()
        if rx.search(line)
    ]


def test_the_node_layout_is_defined_once() -> None:
    axis_literal = r"\(\s*\"x\",\s*\"y\",\s*\"z\",\s*\"slider\""
    assert len(definitions(axis_literal)) == 1, definitions(axis_literal)
    for name in ("AXIS_NAMES", "AXIS_COUNT", "NODE_BUTTONS", "GROUP1_BUTTONS", "HAT1_SHIFT"):
        assert len(definitions(rf"^{name}\s*[:=]")) == 1, definitions(rf"^{name}\s*[:=]")
    highest = definitions(r"^\s*[A-Z_]*NODE_ID[A-Z_]*\s*[:=]\s*(254|0xFE)\b")
    assert highest == [], "the highest Node-ID is STARTUP_NODE_ID - 1, in config/layout.py"


def test_usage_numbers_live_in_usages_only() -> None:
    """A usage written as a number (0xPPPPUUUU of pages 1, 2 or 9) outside hid/usages.py."""
    numbers = r"0x000[129][0-9A-Fa-f]{4}\b"
    outside = [d for d in definitions(numbers) if not d.startswith("usb2rc.hid.usages:")]
    comments_only = [d for d in outside if not d.split(": ", 1)[1].startswith("#")]
    # descriptor.py's docstrings quote examples; code lines may not define usages.
    code = [d for d in comments_only if re.search(r"=\s*" + numbers, d)]
    assert code == [], code


def test_one_device_filter() -> None:
    """Whether a top-level collection is a joystick is decided by one function."""
    filters = definitions(r"^def (is_usable_usage|is_joystick_like)\b")
    assert filters == ["usb2rc.hid.usages: def is_joystick_like(application: int) -> bool:"]


def package_of(module: str) -> str:
    """A module's package as the package-level graph counts it: `usb2rc.<sub-package>`, or
    the module itself when it sits at the top level."""
    return ".".join(module.split(".")[:2])


def package_graph() -> dict[str, set[str]]:
    """Which package imports which (lazy imports too), packages as the nodes."""
    mods = modules()
    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        package = package_of(name)
        found = {package_of(dep) for dep in imports_of(path, set(mods))}
        graph.setdefault(package, set()).update(found - {package})
    return graph


# The middle of the pipeline: the session interface, the driver and the links; one session
# package per protocol; the wiring that builds them. Before issue 21 `outputs/wiring.py`
# imported the scheduler, which imported `outputs.channels`: outputs <-> scheduler.
PIPELINE_MIDDLE = ("usb2rc.lines", "usb2rc.protocols", "usb2rc.wiring")


def test_no_package_level_loop_runs_through_the_lines_sessions_or_wiring() -> None:
    loops = [loop for loop in cycles(package_graph()) if set(loop) & set(PIPELINE_MIDDLE)]
    assert loops == []


def test_the_output_registry_imports_no_session_link_or_driver() -> None:
    """The registry sits below the config model (which reads it): the running output is
    built above both, by `usb2rc.wiring`, which has a build function for each entry."""
    from usb2rc.outputs import PROTOCOLS

    from usb2rc.wiring import BUILDERS

    assert not package_graph()["usb2rc.outputs"] & {*PIPELINE_MIDDLE, "usb2rc.daemon"}
    assert list(BUILDERS) == list(PROTOCOLS)


@pytest.mark.xfail(
    strict=True,
    reason="config_model imports the output registry, whose package also holds the channels "
    "(which read the node state): the config/ move at the end of issue 21 cuts it",
)
def test_no_package_level_cycle_at_all() -> None:
    assert cycles(package_graph()) == []
