"""Structure counts of issue 40, read from the source with ``ast`` (reads files only).

Usage: ``python docs/structure_audit.py [ROOT]`` (ROOT: the checkout, default: the folder above
this file). Prints one JSON object: broad excepts, functions over 80 lines, imports of
``gprace`` inside functions (those that would close a cycle if hoisted, those on a cycle of
the whole import graph), upward imports against the layers of issue 40, and package cycles.
See docs/structure_audit.md for what the numbers mean.
"""

from __future__ import annotations

import ast
import configparser
import json
import sys
from collections import Counter, defaultdict
from pathlib import Path

LAYER_NAMES = ("core", "components", "workflows", "surfaces")  # lowest first: the four


def read_layers(root: Path) -> dict[str, list[str]]:
    """The layers of the import-linter contract in ``.importlinter`` (one source of truth: what CI
    checks is what this audit counts against), lowest first, named as in the issue."""
    cfg = configparser.ConfigParser()
    cfg.read(root / ".importlinter")
    lines = [ln.strip() for ln in cfg["importlinter:contract:layers"]["layers"].splitlines() if ln.strip()]
    return {name: [p.strip() for p in ln.split(":")] for name, ln in zip(LAYER_NAMES, reversed(lines))}


LAYERS = read_layers(Path(__file__).resolve().parent.parent)
RANK = {p: i for i, ps in enumerate(LAYERS.values()) for p in ps}
LAYER = {p: name for name, ps in LAYERS.items() for p in ps}
LONG = 80


def module_name(root: Path, f: Path) -> str:
    parts = list(f.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def package(mod: str) -> str | None:
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 else None


def prefixes(mod: str) -> list[str]:
    p = mod.split(".")
    return [".".join(p[:i]) for i in range(1, len(p) + 1)]


def scan(root: Path) -> tuple[list, list, list]:
    broad, long_fns, imports = [], [], []
    for f in sorted((root / "gprace").rglob("*.py")):
        src = f.read_text()
        tree = ast.parse(src)
        rel, me = str(f.relative_to(root)), module_name(root, f)
        parent = {c: n for n in ast.walk(tree) for c in ast.iter_child_nodes(n)}

        def up(n, test):
            while n in parent:
                n = parent[n]
                if test(n):
                    return n
            return None

        for node in ast.walk(tree):
            if isinstance(node, ast.ExceptHandler):
                names = ["<bare>"] if node.type is None else [
                    ast.unparse(e) for e in (node.type.elts if isinstance(node.type, ast.Tuple) else [node.type])]
                hit = [n for n in names if n in ("Exception", "BaseException", "<bare>")]
                if hit:
                    reraise = any(isinstance(x, ast.Raise) and x.exc is None for x in ast.walk(node))
                    broad.append({"at": f"{rel}:{node.lineno}", "type": ",".join(hit), "bare_reraise": reraise})
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > LONG:
                    owner = parent.get(node)
                    name = f"{owner.name}.{node.name}" if isinstance(owner, ast.ClassDef) else node.name
                    long_fns.append({"at": f"{rel}:{node.lineno}", "function": name, "lines": n})
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                if isinstance(node, ast.ImportFrom):
                    if node.level:
                        base = me.split(".")
                        base = base[: len(base) - node.level + (1 if f.name == "__init__.py" else 0)]
                        targets = [".".join(base + ([node.module] if node.module else []))]
                    else:
                        targets = [node.module or ""]
                else:
                    targets = [a.name for a in node.names]
                fn = up(node, lambda n: isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)))
                tc = up(node, lambda n: isinstance(n, ast.If) and "TYPE_CHECKING" in ast.unparse(n.test))
                for t in targets:
                    if t.startswith("gprace"):
                        imports.append({"file": rel, "line": node.lineno, "src": me, "dst": t,
                                        "function": fn.name if fn else "", "type_checking": tc is not None})
    return broad, long_fns, imports


def graph(imports, mods, with_functions: bool):
    """Module graph: importing ``d`` also runs its parent packages (not the importer's own)."""
    def resolve(m):
        while m and m not in mods:
            m = m.rsplit(".", 1)[0] if "." in m else ""
        return m

    G = defaultdict(set)
    for im in imports:
        d = resolve(im["dst"])
        if not d or im["type_checking"] or (im["function"] and not with_functions):
            continue
        own = set(prefixes(im["src"]))
        G[im["src"]].update(x for x in prefixes(d) if x != im["src"] and x not in own)
    return G, resolve


def reach(G, a):
    seen, todo = set(), [a]
    while todo:
        for y in G[todo.pop()]:
            if y not in seen:
                seen.add(y)
                todo.append(y)
    return seen


def closes_cycle(G, R, resolve, im) -> bool:
    d = resolve(im["dst"])
    if not d or d == im["src"]:
        return False
    own = set(prefixes(im["src"]))
    starts = [x for x in prefixes(d) if x not in own] or [d]
    return any(im["src"] in R[x] | {x} for x in starts)


def package_cycles(imports, keep) -> list[list[str]]:
    P = defaultdict(set)
    for im in imports:
        a, b = package(im["src"]), package(im["dst"])
        if a and b and a != b and keep(im, a, b):
            P[a].add(b)
    nodes = set(P) | {y for v in P.values() for y in v}
    R = {n: reach(P, n) for n in nodes}
    out, done = [], set()
    for n in sorted(nodes):
        comp = sorted({n} | {m for m in nodes if m in R[n] and n in R[m]})
        if n not in done and len(comp) > 1:
            out.append(comp)
        done |= set(comp)
    return out


def main(root: Path) -> dict:
    global LAYERS, RANK, LAYER
    LAYERS = read_layers(root)  # the checkout audited
    RANK = {p: i for i, ps in enumerate(LAYERS.values()) for p in ps}
    LAYER = {p: name for name, ps in LAYERS.items() for p in ps}
    broad, long_fns, imports = scan(root)
    mods = {module_name(root, f) for f in (root / "gprace").rglob("*.py")}
    G0, resolve = graph(imports, mods, with_functions=False)
    GA, _ = graph(imports, mods, with_functions=True)
    R0 = defaultdict(set, {m: reach(G0, m) for m in mods})
    RA = defaultdict(set, {m: reach(GA, m) for m in mods})
    in_fn = [im for im in imports if im["function"]]
    dodge = [im for im in in_fn if closes_cycle(G0, R0, resolve, im)]
    on_cycle = [im for im in in_fn if closes_cycle(GA, RA, resolve, im)]
    upward = [im for im in imports if package(im["src"]) in RANK and package(im["dst"]) in RANK
              and RANK[package(im["dst"])] > RANK[package(im["src"])]]
    at = lambda im: f"{im['file']}:{im['line']} {im['function'] or '<module>'} -> {im['dst']}"  # noqa: E731
    return {
        "broad_excepts": {"count": len(broad), "without_bare_reraise": sum(not b["bare_reraise"] for b in broad),
                          "sites": broad},
        "functions_over_80_lines": sorted(long_fns, key=lambda r: -r["lines"]),
        "imports": {"gprace_imports": len(imports), "in_functions": len(in_fn),
                    "would_close_a_cycle_if_hoisted": [at(im) for im in dodge],
                    "on_a_cycle_of_all_imports": [at(im) for im in on_cycle]},
        "upward_imports": {"count": len(upward), "at_module_level": sum(not im["function"] for im in upward),
                           "pairs": sorted({f"{package(im['src'])} ({LAYER[package(im['src'])]}) -> "
                                            f"{package(im['dst'])} ({LAYER[package(im['dst'])]})" for im in upward}),
                           "sites": [at(im) for im in upward]},
        "package_cycles": {
            "all_imports": package_cycles(imports, lambda im, a, b: not im["type_checking"]),
            "module_level": package_cycles(imports, lambda im, a, b: not im["function"] and not im["type_checking"]),
            "without_upward": package_cycles(imports, lambda im, a, b: RANK.get(b, 9) <= RANK.get(a, 9)),
        },
        "unplaced_packages": sorted({p for im in imports for p in (package(im["src"]), package(im["dst"]))
                                     if p and p not in RANK}),
    }


if __name__ == "__main__":
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent
    print(json.dumps(main(root.resolve()), indent=1))
