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


def test_the_registry_is_read_where_every_protocol_is_registered() -> None:
    """Each protocol's `output` module registers its row (`usb2rc.protocols.registry`) when
    it is imported, and `usb2rc.outputs` imports every one: the registry is read there.
    Anywhere else it could be read half filled, so only the protocols' `output` modules and
    `usb2rc.outputs` import it."""
    from usb2rc.outputs import PROTOCOLS

    mods = modules()
    readers = {
        name
        for name, path in mods.items()
        if "usb2rc.protocols.registry" in imports_of(path, set(mods))
    }
    rows = {name for name in readers if re.fullmatch(r"usb2rc\.protocols\.\w+\.output", name)}
    assert readers == rows | {"usb2rc.outputs"}
    assert imports_of(mods["usb2rc.outputs"], set(mods)) >= rows
    assert len(PROTOCOLS) == len(rows)


def test_the_config_model_reads_no_registry() -> None:
    """The config model sits below the codecs and sessions the registry's rows name: it
    finds a protocol's own keys' defaults in `config/output_options.py`, which registering a
    row fills, and imports nothing of the protocols, the registry or the running outputs."""
    above = ("usb2rc.protocols", "usb2rc.outputs", "usb2rc.wiring", "usb2rc.lines")
    for name in modules():
        if name.startswith("usb2rc.config."):
            assert not [dep for dep in reached_from(name) if dep.startswith(above)], name


IBUS = re.compile(r"(?<![a-z])ibus", re.IGNORECASE)  # not libusb


def names_in_code(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every name the code of `path` uses or defines, and of every string
    that is not prose (a key, a module path); docstrings and comments are not code."""
    tree = ast.parse(path.read_text())
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        line = getattr(node, "lineno", 0)
        if isinstance(node, ast.Name):
            found.append((line, node.id))
        elif isinstance(node, ast.Attribute | ast.FunctionDef | ast.ClassDef):
            found.append((line, node.attr if isinstance(node, ast.Attribute) else node.name))
        elif isinstance(node, ast.ImportFrom):
            found += [(line, f"{node.module}.{a.name} {a.asname or ''}") for a in node.names]
        elif isinstance(node, ast.Import):
            found += [(line, f"{a.name} {a.asname or ''}") for a in node.names]
        elif isinstance(node, ast.arg | ast.keyword) and node.arg:
            found.append((line, node.arg))
        elif (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and id(node) not in docstrings
            and not re.search(r"\s", node.value)
        ):
            found.append((line, node.value))
    return found


def test_outside_its_package_only_the_registering_import_names_ibus() -> None:
    """A protocol is its package plus one import line: outside `usb2rc/protocols/ibus/`, no
    code names iBus (a module, a class, a function, a key "ibus") but `usb2rc.outputs`'
    import of its row. Prose may name it."""
    own = PACKAGE / "protocols" / "ibus"
    named = [
        f"{module_name(path)}: {text.strip()}"
        for path in modules().values()
        if own not in path.parents
        for _line, text in names_in_code(path)
        if IBUS.search(text)
    ]
    assert named == ["usb2rc.outputs: usb2rc.protocols.ibus.output.IBUS"], named


def test_no_package_level_cycle_at_all() -> None:
    """Packages stack as the pipeline and no import runs back up: the config below the
    lines and the protocols, the registry's face (`usb2rc.outputs`) above the protocols, the
    config file reader (`usb2rc.configfile`) above it, the daemon above them all."""
    assert cycles(package_graph()) == []
