"""The import graph keeps its shape (docs/architecture.md): every import, also one inside a function, goes down
the layers components <- fmus <- emcosim.engine <- (emcosim.locations, emcosim.sweeps, emcosim.progress) <-
emcosim.devices <- emcosim.paper <- emcosim.api <- emcosim.cli; none goes up or sideways into a higher layer, so
there are no circles between layers, the engine imports no paper, and finding a scenario imports no paper."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAYERS = {                     # package or module -> layer (an import may only go to a lower or the same layer)
    "components": 0, "fmus": 1, "emcosim.engine": 2, "emcosim.progress": 2, "emcosim.locations": 3,
    "emcosim.sweeps": 3, "emcosim.devices": 4, "emcosim.paper": 5, "emcosim.api": 6, "emcosim": 6, "emcosim.cli": 7,
}


def layer(module: str) -> tuple[str, int] | None:
    parts = module.split(".")
    for n in range(len(parts), 0, -1):
        name = ".".join(parts[:n])
        if name in LAYERS:
            return name, LAYERS[name]
    return None


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module) of every import in the file, relative ones resolved."""
    package = module_name(path).split(".") if path.name == "__init__.py" else module_name(path).split(".")[:-1]
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            target = ".".join(base + ([node.module] if node.module else []))
            names = [f"{target}.{a.name}" for a in node.names] if node.module is None else [target]
            found += [(node.lineno, n) for n in names]
    return found


FILES = sorted(p for d in ("components", "fmus", "emcosim") for p in (ROOT / d).rglob("*.py")
               if "__pycache__" not in p.parts)


def test_imports_go_down_the_layers():
    up = []
    for path in FILES:
        own = layer(module_name(path))
        assert own is not None, path
        for line, target in imports(path):
            other = layer(target)
            if other is not None and other[1] > own[1]:
                up.append(f"{path.relative_to(ROOT)}:{line}: {target} (layer {other[0]}) from layer {own[0]}")
    assert not up, "\n".join(up)


def test_the_layers_cover_the_packages():
    assert len(FILES) > 50
    assert {layer(module_name(p))[0] for p in FILES} == set(LAYERS)
