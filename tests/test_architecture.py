"""The layers hold: library <- tools <- drone system, no import cycles, no tool loaded by the library.

The import graph is read with ``ast`` from the source (module-level imports only: what runs
when a module loads; ``if TYPE_CHECKING:`` blocks and imports inside functions are left
out). A package's ``__init__`` counts as the package, so a package importing a submodule
that imports the package back is a cycle.
"""
from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("zenoh_robot", "px4_link", "px4_zenoh", "companion", "gcs", "drone_contract", "drone_lab")
# The drone wing: the contract, the apps, the lab and px4_link; none of it below the tools.
DRONE_WING = ("companion", "gcs", "px4_link", "px4_zenoh", "drone_contract", "drone_lab")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
        (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _runtime_imports(tree: ast.Module, module: str, is_package: bool) -> set[str]:
    """Absolute names a module imports when it loads: ``import a.b`` gives a.b; ``from a import x``
    gives a.x if that is a module, else a (the package's ``__init__``, whose names it reads)."""
    out: set[str] = set()
    package = module if is_package else module.rpartition(".")[0]

    def visit(stmts: list[ast.stmt]) -> None:
        for node in stmts:
            if isinstance(node, ast.Import):
                out.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[:len(base) - (node.level - 1)]
                    prefix = ".".join(base + ([node.module] if node.module else []))
                else:
                    prefix = node.module or ""
                for alias in node.names:
                    sub = f"{prefix}.{alias.name}"
                    out.add(sub if sub in MODULES else prefix)
            elif isinstance(node, ast.If):
                if not _is_type_checking(node.test):
                    visit(node.body)
                visit(node.orelse)
            elif isinstance(node, ast.Try):
                visit(node.body)
                for h in node.handlers:
                    visit(h.body)
                visit(node.orelse)
                visit(node.finalbody)
    visit(tree.body)
    return out


def _project_modules() -> dict[str, Path]:
    mods: dict[str, Path] = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            mods[_module_name(path)] = path
    return mods


MODULES = _project_modules()


def _import_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for name, path in MODULES.items():
        tree = ast.parse(path.read_text(), str(path))
        targets = set()
        for imported in _runtime_imports(tree, name, path.name == "__init__.py"):
            # Importing a.b.c loads a, a.b and a.b.c; from inside package a, a is already loading
            # (that is no cycle), so only the ancestors the importer is not part of count.
            parts = imported.split(".")
            for i in range(1, len(parts) + 1):
                candidate = ".".join(parts[:i])
                inside = name == candidate or name.startswith(candidate + ".")
                if candidate in MODULES and (i == len(parts) or not inside) and candidate != name:
                    targets.add(candidate)
        graph[name] = targets
    return graph


GRAPH = _import_graph()


def _all_imports(prefix: str) -> dict[str, set[str]]:
    """Every name each module under ``prefix`` imports at any level, TYPE_CHECKING included."""
    out: dict[str, set[str]] = {}
    for name, path in MODULES.items():
        if name != prefix and not name.startswith(prefix + "."):
            continue
        names: set[str] = set()
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[:len(base) - (node.level - 1)]
                    names.add(".".join(base + ([node.module] if node.module else [])))
                else:
                    names.add(node.module or "")
        out[name] = names
    return out


def _offenders(prefix: str, forbidden: tuple[str, ...], exclude: str | None = None) -> list[str]:
    bad = []
    for module, names in _all_imports(prefix).items():
        if exclude and (module == exclude or module.startswith(exclude + ".")):
            continue
        for n in names:
            if any(n == f or n.startswith(f + ".") for f in forbidden):
                bad.append(f"{module} imports {n}")
    return sorted(bad)


def test_the_graph_was_read() -> None:
    # Guards the test itself: the parser found the modules and their edges.
    assert "zenoh_robot.node" in GRAPH and "zenoh_robot.publisher" in GRAPH["zenoh_robot.node"]
    assert "zenoh_robot.context" in GRAPH["zenoh_robot.subscription"]
    assert "zenoh_robot.parameters.store" in GRAPH["zenoh_robot.parameters"]


def _find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    WHITE, GREY, BLACK = 0, 1, 2
    colour = dict.fromkeys(graph, WHITE)
    stack: list[str] = []

    def dfs(n: str) -> list[str] | None:
        colour[n] = GREY
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if colour.get(m) == GREY:
                return stack[stack.index(m):] + [m]
            if colour.get(m) == WHITE:
                found = dfs(m)
                if found:
                    return found
        stack.pop()
        colour[n] = BLACK
        return None

    for n in sorted(graph):
        if colour[n] == WHITE:
            found = dfs(n)
            if found:
                return found
    return None


def test_cycle_finder_finds_a_cycle() -> None:
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle_among_the_projects_modules() -> None:
    cycle = _find_cycle(GRAPH)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_px4_link_never_imports_zenoh() -> None:
    assert _offenders("px4_link", ("zenoh", "zenoh_robot", "px4_zenoh", "companion", "gcs", "drone_contract",
                                   "drone_lab")) == []


def test_px4_zenoh_is_a_backend_below_the_apps() -> None:
    """PX4 over Zenoh is a vehicle backend: the companion uses it, it never uses the apps, the lab or the
    contract, and it does not speak MAVLink (that is px4_link's job)."""
    assert _offenders("px4_zenoh", ("companion", "gcs", "drone_contract", "drone_lab", "pymavlink")) == []


def test_the_library_never_imports_mavlink_or_the_apps() -> None:
    assert _offenders("zenoh_robot", ("pymavlink", *DRONE_WING), exclude="zenoh_robot.tools") == []


def test_the_apps_never_import_each_other() -> None:
    assert _offenders("gcs", ("companion", "drone_lab")) == []
    assert _offenders("companion", ("gcs", "drone_lab")) == []


def test_the_contract_imports_only_the_library() -> None:
    # Both apps import it: it must not drag either one (or MAVLink, or a tool) into the other.
    assert _offenders("drone_contract", ("companion", "gcs", "px4_link", "drone_lab", "pymavlink",
                                         "zenoh_robot.tools")) == []


def test_no_message_imports_an_image_transport() -> None:
    # Image's JPEG decode comes from the codec the image modes use too (zenoh_robot.jpeg):
    # transports depend on messages, never the other way.
    assert _offenders("zenoh_robot.msgs", ("zenoh_robot.image",)) == []


def _image_mode_switches(prefix: str) -> list[str]:
    """``... image_mode == "sliced"`` and the like: a comparison of an image mode with a string."""
    found = []
    for name, path in MODULES.items():
        if name != prefix and not name.startswith(prefix + "."):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Compare):
                continue
            sides = [node.left, *node.comparators]
            names_mode = any(isinstance(s, (ast.Name, ast.Attribute)) and "image_mode" in ast.unparse(s) for s in sides)
            strings = any(isinstance(c, ast.Constant) and isinstance(c.value, str) for s in sides for c in ast.walk(s))
            if names_mode and strings:
                found.append(f"{name}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_the_apps_get_image_modes_from_the_registry() -> None:
    """The companion and the GCS ask zenoh_robot.image for a mode's sender and receiver: they import
    no mode's own module and compare no image mode with a string."""
    assert _image_mode_switches("drone_lab"), "the scan sees a switch (the lab reports by mode)"
    modes = tuple(f"zenoh_robot.image.{m}" for m in ("base", "whole", "sliced", "fec"))
    for app in ("companion", "gcs"):
        assert any("zenoh_robot.image" in names for names in _all_imports(app).values()), app
        assert _offenders(app, modes) == []
        assert _image_mode_switches(app) == []


def test_nothing_outside_the_library_imports_its_private_modules() -> None:
    bad = []
    for prefix in ("zenoh_robot.tools", *DRONE_WING):
        for module, names in _all_imports(prefix).items():
            bad += [f"{module} imports {n}" for n in names
                    if n.startswith("zenoh_robot.") and any(part.startswith("_") for part in n.split(".")[1:])]
    assert bad == []


def _started_modules(prefix: str) -> list[str]:
    """``python -m X`` argv literals under ``prefix``: a dependency an import scan cannot see."""
    found = []
    for name, path in MODULES.items():
        if name != prefix and not name.startswith(prefix + "."):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.List, ast.Tuple)):
                items = [e.value if isinstance(e, ast.Constant) else None for e in node.elts]
                found += [f"{name} starts {items[i + 1]}" for i, v in enumerate(items[:-1])
                          if v == "-m" and isinstance(items[i + 1], str)]
    return found


def test_tools_never_start_the_drone_system() -> None:
    started = _started_modules("zenoh_robot")
    assert any("zenoh_robot.tools" in s for s in started)    # the scan sees the tools' own -m starts
    assert [s for s in started if s.split(" starts ")[1].split(".")[0] in DRONE_WING] == []
    assert any(s.split(" starts ")[1].split(".")[0] == "companion" for s in _started_modules("drone_lab"))


def test_the_library_never_imports_its_tools() -> None:
    assert _offenders("zenoh_robot", ("zenoh_robot.tools",), exclude="zenoh_robot.tools") == []


def test_tools_never_import_the_drone_system() -> None:
    assert _offenders("zenoh_robot.tools", DRONE_WING) == []


def test_no_self_any_in_the_library() -> None:
    bad = []
    for name, path in MODULES.items():
        if not name.startswith("zenoh_robot") or name.startswith("zenoh_robot.tools"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.args.args:
                first = node.args.args[0]
                if first.arg == "self" and first.annotation is not None:
                    bad.append(f"{name}.{node.name}")
    assert bad == []


def test_node_is_one_class_not_mixins() -> None:
    from zenoh_robot import Node
    assert Node.__mro__ == (Node, object)


FORBIDDEN_ON_IMPORT = ("zenoh_robot.tools", "rich", "matplotlib", "subprocess", "csv", "pymavlink",
                       *DRONE_WING, "PIL", "mcap", "foxglove", "cryptography")


def test_import_zenoh_robot_loads_no_tool() -> None:
    code = "import json, sys; import zenoh_robot; print(json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60,
                         check=True)
    loaded = json.loads(out.stdout)
    assert "zenoh_robot.node" in loaded        # the check can fail: it sees what was loaded
    bad = [m for m in loaded if any(m == f or m.startswith(f + ".") for f in FORBIDDEN_ON_IMPORT)
           or m.endswith((".launch", ".bench", ".experiment"))]
    assert bad == []


@pytest.mark.parametrize("name", ["Parameter", "ParameterClient", "ParameterType", "ParameterDescriptor",
                                  "SetParametersResult", "parse_param_args", "parse_param_value",
                                  "format_param_value", "add_param_argument", "params_from_args",
                                  "qos_from_parameters", "InvalidParameterTypeError",
                                  "InvalidParameterValueError", "ParameterNotDeclaredError",
                                  "ParameterAlreadyDeclaredError", "ParameterError", "PARAMETER_SERVICES"])
def test_parameters_package_keeps_every_name(name: str) -> None:
    import zenoh_robot.parameters as params
    assert hasattr(params, name)


# The GCS is built like the companion (docs/architecture.md): app.py wires the node and keeps each
# drone's state; planning, discovery, the mission's steps and the CLI's checks are parts of their own.
GCS_APP_MAX_LINES = 450      # it was 551 with the planning inside (companion/app.py: ~230)
GCS_FUNCTION_MAX_LINES = 60  # the mission's flight and the CLI's run were one 95- and one 105-line function


def test_gcs_planning_loads_no_session() -> None:
    """gcs/planner.py is what its tests drive without Zenoh: importing it loads neither Zenoh nor the library."""
    code = "import json, sys; import gcs.planner; print(json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60,
                         check=True)
    loaded = json.loads(out.stdout)
    assert "gcs.planner" in loaded and "gcs.formation" in loaded   # the check sees what was loaded
    assert [m for m in loaded if m.split(".")[0] in ("zenoh", "zenoh_robot", "numpy")] == []


def test_drone_discovery_is_written_once() -> None:
    """The GCS app and `gcs cmd all` find drones through gcs/discovery.py: no other GCS module listens on the
    raw session or spells a drone id's pattern."""
    from gcs.discovery import DRONE_ID
    found = {name: path.read_text() for name, path in MODULES.items() if name.split(".")[0] == "gcs"}
    assert "declare_subscriber(" in found["gcs.discovery"] and DRONE_ID.pattern in found["gcs.discovery"]
    assert [n for n, text in found.items() if n != "gcs.discovery"
            and ("declare_subscriber(" in text or DRONE_ID.pattern in text)] == []


def test_the_gcs_app_is_wiring() -> None:
    text = MODULES["gcs.app"].read_text()
    assert len(text.splitlines()) <= GCS_APP_MAX_LINES
    # Target maths stay in the planner: the app only feeds it the drone's position.
    names = {n.id for n in ast.walk(ast.parse(text)) if isinstance(n, ast.Name)}
    assert names & {"lead", "path_distance", "MAX_LEAD_M", "MAX_TARGET_SPEED", "PATH_JOIN_M"} == set()


def test_no_gcs_function_grows_long() -> None:
    """A mission, a CLI run or a target grows by a named step, not inside one long function; the CLI's
    argument lists are exempt."""
    long = []
    for name, path in MODULES.items():
        if name.split(".")[0] != "gcs":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and node.name not in ("register", "add_common"):
                lines = (node.end_lineno or node.lineno) - node.lineno + 1
                if lines > GCS_FUNCTION_MAX_LINES:
                    long.append(f"{name}.{node.name}: {lines} lines")
    assert long == []


TEST_LAYERS = ("library", "px4", "wing", "tools", "lab")   # tests mirror the layers (docs/testing.md)


def test_tests_mirror_the_layers_and_share_helpers_not_modules() -> None:
    """Every test module lives in its layer's folder (this file, about all of them, stays on top), and
    none imports another test module: shared rigs and helpers live in helper modules (rigs.py, ...)."""
    tests = ROOT / "tests"
    stray = [p.name for p in tests.glob("test_*.py") if p.name != "test_architecture.py"]
    assert stray == [], f"put these in one of {TEST_LAYERS}: {stray}"
    folders = {p.name for p in tests.iterdir() if p.is_dir() and any(p.glob("test_*.py"))}
    assert folders <= set(TEST_LAYERS), folders - set(TEST_LAYERS)
    modules = {p.stem for p in tests.rglob("test_*.py")}
    crossing = []
    for path in tests.rglob("test_*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            crossing += [f"{path.name} imports {n}" for n in names if n.split(".")[-1] in modules]
    assert crossing == []


# A drawn domain (ZR_DOMAIN, --domain, a ROS domain id) outside conftest.fresh_domain ignores the
# pytest-xdist workers' partition: two workers' tests then share a domain now and then, and a `gcs` or
# `companion` finding another of its name there refuses to start (CI, 2026-11-29: a GCS that never
# streamed while a test waited 20 s for its setpoints).
_DOMAIN_DRAW = re.compile(r"(?i)domain.*\b(randint|randbelow|randrange|choice)\(")


def test_every_domain_a_test_draws_is_its_workers_own() -> None:
    assert _DOMAIN_DRAW.search('env = {"ZR_DOMAIN": str(1 + secrets.randbelow(232))}')
    assert not _DOMAIN_DRAW.search('monkeypatch.setenv("ZR_DOMAIN", str(fresh_domain()))')
    own = [f"{path.relative_to(ROOT)}:{n}: {line.strip()}" for path in (ROOT / "tests").rglob("*.py")
           if path.name not in ("conftest.py", "test_architecture.py")
           for n, line in enumerate(path.read_text().splitlines(), 1) if _DOMAIN_DRAW.search(line)]
    assert own == [], "draw domains with conftest.fresh_domain():\n" + "\n".join(own)
