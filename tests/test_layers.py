"""The house rules of nespm_cli, checked on its source (docs/architecture.md):

* layers import only downward: errors < plugins < nav < data < checks < vehicles < learn < sensors <
  filters < experiments < tuning < reports < api < cli (a module may import its own layer and any lower one);
* no import circle between modules (function-level imports count too);
* no private name (``_x``) imported from another module.
"""
from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "nespm_cli"
LAYERS = ["errors", "plugins", "nav", "data", "checks", "vehicles", "learn", "sensors", "filters", "experiments",
          "tuning", "reports", "api", "cli"]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer(mod: str) -> int:
    parts = mod.split(".")
    if len(parts) == 1:  # nespm_cli itself (__version__)
        return 0
    return LAYERS.index(parts[1])


def imports() -> dict[str, list[tuple[str, list[str], int]]]:
    """``{module: [(imported module, names, line)]}`` for every nespm_cli-internal import."""
    mods = {module_name(p): p for p in PKG.rglob("*.py")}
    out = {}
    for mod, path in mods.items():
        found = []
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("nespm_cli"):
                names = [a.name for a in node.names]
                # "from nespm_cli.pkg import module" imports a module, not a name
                sub = [f"{node.module}.{n}" for n in names if f"{node.module}.{n}" in mods]
                found += [(s, [], node.lineno) for s in sub]
                rest = [n for n in names if f"{node.module}.{n}" not in mods]
                if rest:
                    found.append((node.module, rest, node.lineno))
            elif isinstance(node, ast.Import):
                found += [(a.name, [], node.lineno) for a in node.names if a.name.startswith("nespm_cli")]
        out[mod] = found
    return out


def test_every_module_has_a_layer():
    for mod in imports():
        assert mod == "nespm_cli" or mod.split(".")[1] in LAYERS, mod


def test_layers_import_only_downward():
    bad = [f"{m} (layer {layer(m)}) imports {t} (layer {layer(t)}) at line {line}"
           for m, found in imports().items() for t, _, line in found if layer(t) > layer(m)]
    assert not bad, "\n".join(bad)


def test_no_private_names_across_modules():
    bad = [f"{m} imports {n} from {t} (line {line})" for m, found in imports().items()
           for t, names, line in found for n in names if n.startswith("_") and n != "__version__"]
    assert not bad, "\n".join(bad)


def test_no_import_circles():
    graph = {m: {t for t, _, _ in found if t != m} for m, found in imports().items()}
    # a package's __init__ re-exporting its own modules is not a circle through them
    cycles, state = [], {}

    def visit(m, stack):
        state[m] = 1
        for t in sorted(graph.get(m, ())):
            if t == m.rsplit(".", 1)[0] and m.startswith(t + "."):  # a module importing its package
                continue
            if state.get(t) == 1:
                cycles.append(" -> ".join(stack[stack.index(t):] + [t]))
            elif not state.get(t):
                visit(t, stack + [t])
        state[m] = 2

    for m in sorted(graph):
        if not state.get(m):
            visit(m, [m])
    assert not cycles, "\n".join(cycles)
