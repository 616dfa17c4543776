"""No function of the package is longer than ``MAX_LINES`` lines, read from the source
(``ast``; a function's lines run from its ``def`` to its last line, docstring included,
decorators not). A longer function is split into named steps, each with its docstring.
"""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "sfs_ros"
MAX_LINES = 100

def function_lengths() -> dict[tuple[str, str], int]:
    """{(path under sfs_ros/, qualified name): lines} of every function and method."""
    lengths = {}

    def visit(node, prefix: str, path: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    lengths[(path, name)] = child.end_lineno - child.lineno + 1
                visit(child, f"{name}.", path)
            else:
                visit(child, prefix, path)

    for source in sorted(PACKAGE.rglob("*.py")):
        path = source.relative_to(PACKAGE).as_posix()
        visit(ast.parse(source.read_text(encoding="utf-8"), filename=str(source)), "", path)
    return lengths


def test_the_walk_finds_functions_methods_and_nested_ones():
    lengths = function_lengths()
    assert ("core/pipeline.py", "carve_scan") in lengths
    assert ("core/pipeline.py", "ReconstructionParams.__post_init__") in lengths
    assert ("core/stages.py", "resegment_views.read_rgb") in lengths


def test_no_function_is_longer_than_the_limit():
    long = {key: n for key, n in function_lengths().items() if n > MAX_LINES}
    assert not long, (f"functions over {MAX_LINES} lines (split them into named steps): "
                      + ", ".join(f"sfs_ros/{path}::{name} ({n})"
                                  for (path, name), n in sorted(long.items())))

