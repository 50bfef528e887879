"""The shape of the package stays as docs/design.md draws it: each package imports only the packages its
arrows allow (a lazy import and an importlib call naming a module count too), no import circles, no long
files or functions, few loose modules at the top."""

from __future__ import annotations

import ast
import textwrap
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "walkdiff"
DESIGN = PACKAGE.parent / "docs" / "design.md"

# What each package (or loose module; `__init__` is `walkdiff` itself, the face) may import besides
# itself. Every arrow here is one a module uses; docs/design.md shows this list as it is.
ARROWS = {
    "common": (),
    "motion": ("common",),
    "diffusion": ("common",),
    "metrics": ("common",),
    "retarget": ("common", "motion"),
    "spec": ("motion",),
    "data": ("common", "motion", "spec"),
    "models": ("common", "motion", "retarget", "diffusion", "spec"),
    "preview": ("common", "motion", "retarget"),
    "streams": ("common", "diffusion"),
    "export": ("common", "diffusion", "models", "data"),
    "styled": ("common", "motion", "retarget", "diffusion", "models", "data", "preview"),
    "walker": ("common", "motion", "retarget", "diffusion", "models", "preview", "streams", "export"),
    "gestures": (
        "common", "motion", "retarget", "diffusion", "metrics", "models", "data", "preview", "streams",
        "export",
    ),
    "live": ("common", "motion", "retarget", "preview", "streams", "walker"),
    "evaluation": ("common", "motion", "diffusion", "metrics", "models", "data"),
    "callbacks": ("common", "motion", "retarget", "preview", "styled", "walker", "gestures", "evaluation"),
    "api": ("common", "styled", "walker", "gestures"),
    "bench": (
        "common", "motion", "retarget", "diffusion", "metrics", "models", "data", "preview", "styled",
        "walker", "gestures", "live", "export", "evaluation", "callbacks", "api",
    ),
    "cli": (
        "common", "motion", "retarget", "data", "preview", "styled", "walker", "gestures", "live", "export",
        "evaluation", "callbacks", "bench",
    ),
    "__init__": (
        "api", "motion", "retarget", "common", "styled", "walker", "gestures", "models", "diffusion",
    ),
}  # fmt: skip
# importlib call sites whose module is not written in their file (a class path read from a config or a
# checkpoint): each one is named here with what it may load.
DYNAMIC = {"walkdiff.callbacks.plan": "the model and data classes a training config names"}
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
    tree = ast.parse(path.read_text())
    found = importlib_targets(tree)
    for node in ast.walk(tree):
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


def importlib_calls(tree: ast.AST) -> int:
    return sum(
        isinstance(n, ast.Call) and getattr(n.func, "attr", getattr(n.func, "id", None)) == "import_module"
        for n in ast.walk(tree)
    )


def importlib_targets(tree: ast.AST) -> set[str]:
    """The walkdiff modules a file with importlib calls names in its string constants (a module, or a
    module's class as 'walkdiff.models.evaluator.MotionEvaluator'): the arrows its calls draw."""
    if not importlib_calls(tree):
        return set()
    found = set()
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and node.value.startswith("walkdiff.")
        ):
            name = node.value
            if name in MODULES or name.rpartition(".")[0] in MODULES:
                found.add(name if name in MODULES else name.rpartition(".")[0])
    return found


FILES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py")) if p.name != "__main__.py"}
MODULES = set(FILES)
GRAPH = {module: imports(path, module) for module, path in FILES.items()}


def part(module: str) -> str:
    """The layer name of a module: its top-level package, loose module, or `__init__` for `walkdiff`."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_every_package_has_its_arrows():
    assert {part(m) for m in MODULES} <= set(ARROWS), "add new packages to ARROWS (and docs/design.md)"


def test_imports_follow_the_arrows():
    stray = [
        f"{module} imports {target}"
        for module, targets in GRAPH.items()
        for target in targets
        if part(target) != part(module) and part(target) not in ARROWS[part(module)]
    ]
    assert not stray, "\n".join(sorted(stray))


def test_the_arrows_have_no_circle_and_each_is_used():
    """Packages stay in an order (each imports only packages before it), and no arrow stands unused."""
    placed: list[str] = []
    while len(placed) < len(ARROWS):
        ready = [p for p, to in ARROWS.items() if p not in placed and set(to) <= set(placed)]
        assert ready, f"a circle among {sorted(set(ARROWS) - set(placed))}"
        placed += ready
    used = {(part(m), part(t)) for m, ts in GRAPH.items() for t in ts if part(t) != part(m)}
    unused = [f"{p} -> {t}" for p, to in ARROWS.items() for t in to if (p, t) not in used]
    assert not unused, "arrows no module uses: " + ", ".join(unused)


def test_every_importlib_call_draws_its_arrows():
    """An importlib call is an import: its module is written in its file (and so an arrow above) or the
    file is one of the DYNAMIC few."""
    unnamed = [
        module
        for module, path in FILES.items()
        if importlib_calls(tree := ast.parse(path.read_text())) and not importlib_targets(tree)
    ]
    assert sorted(unnamed) == sorted(DYNAMIC), unnamed


def arrows_drawn() -> str:
    """The arrows as docs/design.md shows them: one package a line, with what it may import."""
    width = max(map(len, ARROWS)) + 1
    lines = (f"{p:<{width}}-> {', '.join(to) or '(nothing)'}" for p, to in ARROWS.items())
    return "\n".join(textwrap.fill(line, 104, subsequent_indent=" " * (width + 3)) for line in lines)


def test_design_page_draws_the_same_arrows():
    assert f"```\n{arrows_drawn()}\n```" in DESIGN.read_text(), (
        "docs/design.md: the arrows block must be exactly:\n" + arrows_drawn()
    )


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
            test_imports_follow_the_arrows()
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


MAX_HANDLER_LINES = 40


def test_command_handlers_only_hand_over():
    """A command's handler in cli/ reads its options and hands them to the function that makes and writes
    (which builds its request and calls the API): it stays short."""
    long = [
        f"{module}.{node.name}: {node.end_lineno - node.lineno + 1} lines"
        for module, path in FILES.items()
        if part(module) == "cli"
        for node in ast.parse(path.read_text()).body
        if isinstance(node, ast.FunctionDef) and node.name.startswith("run")
        and node.end_lineno - node.lineno + 1 > MAX_HANDLER_LINES
    ]  # fmt: skip
    assert not long, "\n".join(long)


def test_a_rig_is_built_in_one_place():
    """`TargetRig.of` is where a rig spec (--to, to=) becomes a TargetRig: nothing else calls the class."""
    calls = [
        f"{module}:{node.lineno}"
        for module, path in FILES.items()
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "TargetRig"
    ]
    assert not calls, f"TargetRig(...) called outside TargetRig.of: {calls}"
