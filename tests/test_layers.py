"""The package's layers (docs/design.md §2): nothing low imports anything high. Each module's imports of the package
(``from .x``, ``from ..x``, ``lerobot_instant_policy.x``; those under ``if TYPE_CHECKING:`` are annotations only)
stay within its layer or below; ``training`` never imports the policy, and the package never imports ``workbench``."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "lerobot_instant_policy"
# Lowest first: a subpackage or root module may import its own layer and those below it.
LAYERS = (
    {"contract", "geometry", "config_io", "video_backend"},
    {"data", "objects"},
    {"replay"},
    {"pseudo_demos", "perception", "sim", "model", "language"},
    {"policy", "configuration_instant_policy", "modeling_instant_policy", "processor_instant_policy", "training",
     "baselines", "pretraining"},
    {"evaluation", "benchmarks"},
    {"cli"},
)
RANK = {unit: rank for rank, units in enumerate(LAYERS) for unit in units}
POLICY = {"modeling_instant_policy", "processor_instant_policy"}


def imported_units(path: Path) -> set[str]:
    """The package's top-level units (subpackage or root module) that ``path`` imports at run time."""
    tree = ast.parse(path.read_text())
    annotations_only = {id(node) for block in ast.walk(tree) if isinstance(block, ast.If)
                        and ast.unparse(block.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING")
                        for statement in block.body for node in ast.walk(statement)}
    package = path.relative_to(PACKAGE.parent).parent.parts  # the importing module's package, as a relative import sees
    units = set()
    for node in ast.walk(tree):
        if id(node) in annotations_only:
            continue
        if isinstance(node, ast.ImportFrom):
            base = list(package[:len(package) - node.level + 1]) if node.level else []
            module = base + (node.module.split(".") if node.module else [])
            if module[0] != PACKAGE.name:
                continue
            units |= {module[1]} if len(module) > 1 else {alias.name for alias in node.names}
        elif isinstance(node, ast.Import):
            units |= {alias.name.split(".")[1] for alias in node.names
                      if alias.name.startswith(f"{PACKAGE.name}.")}
    return units


def test_every_unit_has_a_layer():
    units = {path.stem if path.is_file() else path.name for path in PACKAGE.iterdir()
             if (path.suffix == ".py" and path.name != "__init__.py") or (path / "__init__.py").is_file()}
    assert units == set(RANK)


def test_nothing_low_imports_anything_high():
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).parts
        if parts == ("__init__.py",):
            continue  # the package registers its policies and env on import: it sits above everything
        unit = parts[0].removesuffix(".py")
        for imported in sorted(imported_units(path) - {unit}):
            if RANK[imported] > RANK[unit] or (unit == "training" and imported in POLICY):
                wrong.append(f"{path.relative_to(PACKAGE.parent)} imports {imported}")
    assert not wrong, wrong


def test_the_package_never_imports_the_workbench():
    wrong = [str(path) for path in PACKAGE.rglob("*.py") if any(
        isinstance(node, (ast.Import, ast.ImportFrom)) and "workbench" in ast.unparse(node)
        for node in ast.walk(ast.parse(path.read_text())))]
    assert not wrong
