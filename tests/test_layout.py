"""The shape of the package stays as docs/design.md draws it: layers import only downwards, no import circles,
no long files or functions, few loose modules at the top."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "walkdiff"

# Lowest first. A module may import its own package (without circles) and any package of a lower layer;
# never a package of its own layer or above. `walkdiff` itself (__init__) is the face: the top.
LAYERS = (
    ("common",),
    ("motion", "diffusion", "metrics"),
    ("spec",),
    ("data", "models"),
    ("preview",),
    ("styled", "autoregressive"),
    ("evaluation",),
    ("callbacks",),
    ("api",),
    ("bench",),
    ("cli",),
    ("__init__",),
)
LEVEL = {name: level for level, names in enumerate(LAYERS) for name in names}
MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 120
MAX_LOOSE_MODULES = 4


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path, module: str) -> set[str]:
    """Every walkdiff module `path` imports, at the top or inside a function (a lazy import is an arrow
    too): for `from X import Y`, X.Y where that is a module, else X."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split(".")[0] == "walkdiff"}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            if base.split(".")[0] != "walkdiff":
                continue
            for alias in node.names:
                candidate = f"{base}.{alias.name}"
                found.add(candidate if candidate in MODULES else base)
    return found - {module}


FILES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py")) if p.name != "__main__.py"}
MODULES = set(FILES)
GRAPH = {module: imports(path, module) for module, path in FILES.items()}


def part(module: str) -> str:
    """The layer name of a module: its top-level package, loose module, or `__init__` for `walkdiff`."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_every_package_has_a_layer():
    assert {part(m) for m in MODULES} <= set(LEVEL), "add new packages to LAYERS (and docs/design.md)"


def test_imports_only_run_downwards():
    upward = [
        f"{module} imports {target}"
        for module, targets in GRAPH.items()
        for target in targets
        if part(target) != part(module) and LEVEL[part(target)] >= LEVEL[part(module)]
    ]
    assert not upward, "\n".join(sorted(upward))


def test_no_import_circles():
    seen, on_path, circles = set(), [], []

    def visit(module: str) -> None:
        if module in on_path:
            circles.append(" -> ".join(on_path[on_path.index(module) :] + [module]))
            return
        if module in seen:
            return
        on_path.append(module)
        for target in sorted(GRAPH.get(module, ())):
            if part(target) == part(module) or target == "walkdiff":
                visit(target)
        on_path.pop()
        seen.add(module)

    for module in sorted(GRAPH):
        visit(module)
    assert not circles, "\n".join(circles)


def test_the_checker_sees_circles_and_upward_arrows(tmp_path):
    """The walk above on a made-up graph: what it must refuse."""
    global GRAPH
    saved = GRAPH
    try:
        GRAPH = {"walkdiff.motion.a": {"walkdiff.motion.b"}, "walkdiff.motion.b": {"walkdiff.motion.a"}}
        try:
            test_no_import_circles()
        except AssertionError as error:
            assert "walkdiff.motion.a -> walkdiff.motion.b -> walkdiff.motion.a" in str(error)
        else:
            raise AssertionError("a circle went unseen")
        GRAPH = {"walkdiff.models.x": {"walkdiff.cli.main"}}
        try:
            test_imports_only_run_downwards()
        except AssertionError as error:
            assert "walkdiff.models.x imports walkdiff.cli.main" in str(error)
        else:
            raise AssertionError("an upward import went unseen")
    finally:
        GRAPH = saved


def test_files_and_functions_stay_short():
    long = []
    for path in FILES.values():
        text = path.read_text()
        name = path.relative_to(PACKAGE.parent)
        if len(text.splitlines()) > MAX_FILE_LINES:
            long.append(f"{name}: {len(text.splitlines())} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    long.append(f"{name}:{node.lineno} {node.name}: {lines} lines")
    assert not long, "\n".join(long)


def test_few_loose_modules_at_the_top():
    loose = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(loose) <= MAX_LOOSE_MODULES, loose
