"""The package's layers point down and its modules import no circle (docs/architecture.md draws them).

Read from the source with ``ast`` (every import, function-level ones included), so nothing is imported.
"""

import ast
import functools
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "wrl_jax"

LAYERS = ("core", "envs", "wrappers", "agents", "training", "experiments", "cli")
"""Lowest first: a module may import its own layer and the ones before it, never one after."""

FOUNDATION = {"wrl_jax.stats", "wrl_jax._distributed"}
"""Dependency-free helpers at the package root, importable from every layer."""

ENTRY_POINTS = {"wrl_jax", "wrl_jax.evaluate", "wrl_jax.plan", "wrl_jax.sweep"}
"""``import wrl_jax`` (registrations) and the ``python -m`` commands: above every layer."""


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """The ``wrl_jax`` modules a file imports (``from a import b`` counts ``a.b`` when that is a module)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return {name for name in names if name == "wrl_jax" or name.startswith("wrl_jax.")}


MODULES = {_module_name(path): path for path in PACKAGE.rglob("*.py")}
@functools.cache
def import_graph() -> dict[str, set[str]]:
    """Module -> the package modules it imports (parsed on first use, not while pytest collects)."""
    return {name: {i for i in _imports(path) if i in MODULES and i != name} for name, path in MODULES.items()}


def _layer(module: str) -> int | None:
    parts = module.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else None


def test_every_module_has_a_place():
    unplaced = [m for m in MODULES if _layer(m) is None and m not in FOUNDATION | ENTRY_POINTS]
    assert not unplaced, f"modules outside the layers: {unplaced}"


def test_layers_point_down():
    upward = []
    for module, imported in import_graph().items():
        for target in imported:
            if module in ENTRY_POINTS:
                continue
            if target in ENTRY_POINTS - {"wrl_jax"}:
                upward.append(f"{module} -> {target}")
            elif target in FOUNDATION or target == "wrl_jax":
                continue
            elif module in FOUNDATION or _layer(target) > _layer(module):
                upward.append(f"{module} -> {target}")
    assert not upward, "imports that point up:\n" + "\n".join(sorted(upward))


def test_no_import_cycles():
    # Package __init__ modules are left out: importing ``a.b`` runs ``a/__init__`` first, which is no cycle.
    graph = {m: {t for t in targets if not MODULES[t].name == "__init__.py"} for m, targets in import_graph().items()}
    state: dict[str, int] = {}
    cycles = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(" -> ".join(stack[stack.index(nxt):] + [node, nxt]) if nxt in stack else f"{node} -> {nxt}")
            elif nxt not in state:
                visit(nxt, stack + [node])
        state[node] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module, [])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


@pytest.mark.parametrize("module", ["wrl_jax", "wrl_jax.cli", "wrl_jax.wrappers"])
def test_packages_a_command_imports_first_stay_light(module):
    # The commands import wrl_jax.cli.machine before JAX starts: these must not import JAX's users.
    heavy = {i for i in import_graph()[module] if _layer(i) is not None and _layer(i) >= LAYERS.index("agents")}
    assert not heavy, heavy


FAMILY_WORDS = ("deliver", "collision", "shelf", "shelves", "robot", "pibt", "warehouse", "fleet", "procedural")
"""Words of the environment families. The driver and the pieces every learner shares get a family's
metrics, rates and reports through core's contracts (``FamilyEvaluation``, ``event_metrics``), never by name."""

FAMILY_FREE = [*sorted(p for p in (PACKAGE / "training").glob("*.py")),
               *(PACKAGE / "agents" / f"{name}.py" for name in ("base", "common", "replay", "networks", "initializers"))]


def _code_strings(path: Path) -> list[tuple[int, str]]:
    """The string constants of a module's code (docstrings left out: they may explain with an example)."""
    tree = ast.parse(path.read_text())
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                  and node.body and isinstance(node.body[0], ast.Expr) and isinstance(node.body[0].value, ast.Constant)}
    return [(node.lineno, node.value) for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings]


@pytest.mark.parametrize("path", FAMILY_FREE, ids=lambda path: f"{path.parent.name}/{path.name}")
def test_the_driver_and_shared_learner_pieces_name_no_family(path):
    named = [f"{path.name}:{line}: {text!r}" for line, text in _code_strings(path)
             if any(word in text.lower() for word in FAMILY_WORDS)]
    assert not named, "family words in code:\n" + "\n".join(named)
