"""The package's layering: import-linter's layers contract (pyproject.toml) and no import cycles."""
import subprocess
import sys
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]
SUBPACKAGES = ["core", "rf", "splat", "data", "sim", "models", "train", "eval", "experiments", "cli"]


def test_layers_contract_is_kept():
    exe = Path(sys.executable).with_name("lint-imports")
    r = subprocess.run([str(exe)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "1 kept, 0 broken" in r.stdout


def cycles(graph, modules) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, n = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = n[0]
        n[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.find_modules_directly_imported_by(v):
            if w not in modules:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for m in sorted(modules):
        if m not in index:
            visit(m)
    return out


def test_no_import_cycles_between_modules():
    graph = grimp.build_graph("rfmitsuba")
    modules = {m for m in graph.modules if m.startswith("rfmitsuba.") and m not in
               {f"rfmitsuba.{s}" for s in SUBPACKAGES}}
    assert cycles(graph, modules) == []


def test_cycle_finder_finds_a_cycle():
    class G:
        edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}

        def find_modules_directly_imported_by(self, m):
            return self.edges[m]

    assert cycles(G(), set(G.edges)) == [["a", "b", "c"]]


def test_every_subpackage_is_in_the_contract():
    text = (ROOT / "pyproject.toml").read_text()
    on_disk = {p.name for p in (ROOT / "rfmitsuba").iterdir() if (p / "__init__.py").is_file()}
    assert on_disk == set(SUBPACKAGES)
    for s in SUBPACKAGES:
        assert f"rfmitsuba.{s}" in text
