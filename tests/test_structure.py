"""The package's shape: no import cycle, each shared fact defined in one module.

These read the source (AST and text), not the running code: a second definition of a
constant or an import that closes a cycle fails here before it confuses a reader.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

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


def reached_from(start: str) -> set[str]:
    """Every usb2rc module `start` imports, directly or through others."""
    mods = modules()
    known = set(mods)
    seen: set[str] = set()
    todo = [start]
    while todo:
        name = todo.pop()
        for dep in imports_of(mods[name], known) - seen:
            seen.add(dep)
            todo.append(dep)
    return seen


def test_the_output_registry_imports_no_session_link_or_driver() -> None:
    """The registry sits above the codecs and below the config file reader (which reads
    it): the running output is built above both, by `usb2rc.wiring`, which has a build
    function for each entry. Nothing the registry imports, at any depth, is a session, a
    link, the driver, the wiring or the daemon."""
    from usb2rc.outputs import PROTOCOLS
    from usb2rc.wiring import BUILDERS

    running = [
        name
        for name in reached_from("usb2rc.outputs")
        if name.startswith(("usb2rc.lines", "usb2rc.wiring", "usb2rc.daemon"))
        or name.endswith((".session", ".engine"))
    ]
    assert running == []
    assert list(BUILDERS) == list(PROTOCOLS)


def test_no_package_level_cycle_at_all() -> None:
    """Packages stack as the pipeline: config below the codecs and sessions, the output
    registry above both, the config file reader (`usb2rc.configfile`) above the registry."""
    assert cycles(package_graph()) == []


def test_the_config_names_the_crsf_address_bytes_the_codec_sends() -> None:
    """config/output_options.py sits below the codecs, so it writes the two bytes out."""
    from usb2rc.config.output_options import CRSF_ADDRESSES
    from usb2rc.protocols.crsf import codec

    assert CRSF_ADDRESSES == {
        "module": codec.ADDRESS_MODULE,
        "flight_controller": codec.ADDRESS_FLIGHT_CONTROLLER,
    }
