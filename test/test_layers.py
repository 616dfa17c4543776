"""The package's layers, read from the source by static import analysis (``ast``).

``core`` (pure algorithms), ``hardware`` (drivers) and ``cell_logic`` (the cell's logic and
files) import nothing from ROS (rclpy, message packages, rosidl) nor from the layers
above them (``sfs_ros.ros``, ``sfs_ros.nodes``, ``sfs_ros.cli``); ``core`` imports
nothing of the package outside itself; and the core's parts (its sub-packages and
top-level modules) import each other without cycles. Every import statement counts,
also one inside a function.
"""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "sfs_ros"
ROS_FREE = ("core", "hardware", "cell_logic")
UPPER_LAYERS = ("sfs_ros.ros", "sfs_ros.nodes", "sfs_ros.cli")
#: Top-level ROS packages named explicitly; any ``*_msgs``, ``*_srvs``, ``*_interfaces``
#: and ``rosidl*`` package is ROS too.
ROS_PACKAGES = {"rclpy", "builtin_interfaces", "rosbag2_py", "launch", "launch_ros",
                "ament_index_python"}


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path) -> set[str]:
    """Absolute names of every module ``path`` imports (relative imports resolved)."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module
            found.add(module)
            # ``from package import module`` imports that module too
            found.update(f"{module}.{alias.name}" for alias in node.names)
    return found


def is_ros(module: str) -> bool:
    top = module.split(".")[0]
    return (top in ROS_PACKAGES or top.startswith("rosidl")
            or top.endswith(("_msgs", "_srvs", "_interfaces")))


def is_upper_layer(module: str) -> bool:
    return any(module == layer or module.startswith(f"{layer}.") for layer in UPPER_LAYERS)


MODULES = sorted(PACKAGE.rglob("*.py"))


def test_the_package_is_found():
    names = {module_name(p) for p in MODULES}
    assert {"sfs_ros.core.pipeline", "sfs_ros.cell_logic.live_reconstruction", "sfs_ros.ros.convert"} <= names


@pytest.mark.parametrize("layer", ROS_FREE)
def test_lower_layers_import_no_ros_and_no_upper_layer(layer):
    offences = []
    for path in MODULES:
        name = module_name(path)
        if not name.startswith(f"sfs_ros.{layer}"):
            continue
        for module in sorted(imported_modules(path)):
            if is_ros(module) or is_upper_layer(module):
                offences.append(f"{name} imports {module}")
    assert offences == []


def test_the_core_imports_nothing_of_the_package_outside_itself():
    offences = [f"{module_name(p)} imports {m}" for p in MODULES
                if module_name(p).startswith("sfs_ros.core")
                for m in sorted(imported_modules(p))
                if m.startswith("sfs_ros") and not m.startswith("sfs_ros.core")]
    assert offences == []


def core_part(module: str) -> str | None:
    """``sfs_ros.core.X...`` -> ``X`` (a sub-package or a top-level module); else None."""
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and parts[:2] == ["sfs_ros", "core"] else None


def core_graph() -> dict[str, set[str]]:
    """Part -> the other parts it imports (the core's ``__init__``, a lazy front door, aside)."""
    graph: dict[str, set[str]] = {}
    for path in MODULES:
        part = core_part(module_name(path))
        if part is None:
            continue
        targets = {core_part(m) for m in imported_modules(path)} - {None, part}
        graph.setdefault(part, set()).update(targets)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
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
    return found


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_the_cores_parts_import_each_other_without_cycles():
    graph = core_graph()
    assert {"geometry", "carving", "exchange", "pipeline"} <= set(graph)
    assert cycles(graph) == []
